"""Truth records for the tests: ``mr_suspension.truth`` cases from a seed range of their own.

The diagnosis benchmark draws its cases from seeds below one million (its seed set times a
prime near 1e5, plus the case number); a test drawn from those seeds would judge the code
on the very cases it was tuned on. Tests draw their truths here instead, from ``BASE + n``,
and name the physical situation by the arguments (shape, effects, strengths, sensor faults)
and by asserts on the drawn truth.
"""

import warnings

from mr_suspension.identification import data as dataio
from mr_suspension.truth import cases

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
