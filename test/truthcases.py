"""Truth records for the tests: ``mr_suspension.truth`` cases from a seed range of their own.

The diagnosis benchmark draws its cases from seeds below one million (its seed set times a
prime near 1e5, plus the case number); a test drawn from those seeds would judge the code
on the very cases it was tuned on. Tests draw their truths here instead, from ``BASE + n``,
and name the physical situation by the arguments (shape, effects, strengths, sensor faults)
and by asserts on the drawn truth.
"""

import warnings

import numpy as np

from mr_suspension.identification import data as dataio
from mr_suspension.truth import cases, rig

BASE = 7_000_000
SPAN = 1_000_000


def case(n, effects=(), **kwargs):
    """Draw the truth case of seed ``BASE + n`` (``0 <= n < SPAN``): ``cases.make_case``."""
    if not 0 <= n < SPAN:
        raise ValueError(f'truthcases.case: n must be in [0, {SPAN}), got {n}')
    return cases.make_case(BASE + n, effects, **kwargs)


def record(columns, name='case'):
    """Build a ``data.Record`` from a case's columns (input warnings silenced)."""
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        return dataio.build_record(name, columns)


def sine(freq=2.0, amp=0.01, duration=3.0, rate=1000.0):
    """Return ``(t, x)``: a displacement sine of ``freq`` [Hz] and ``amp`` [m]."""
    t = np.arange(int(round(duration * rate))) / rate
    return t, amp * np.sin(2 * np.pi * freq * t)


def linear_truth(**kw):
    """Return a purely viscous rig truth: no yield, no current dependence, no driver lag."""
    base = {'f0': 0.0, 'c0': 1500.0, 'c1': 0.0, 'fy0': 0.0, 'fy1': 0.0, 'driver_tau': 0.0}
    base.update(kw)
    return rig.RigTruth(**base)
