"""Frequency-response gains of a corner measured like on a rig (seed 001, Figs 7-10).

At each frequency a harmonic road of amplitude ``A`` drives the full nonlinear corner (damper,
driver, controller); after ``settle`` seconds the first-harmonic amplitude of each output over
the last ``periods`` periods (:func:`~mr_suspension.core.metrics.sine_gain`) is divided by
``A``. For a linear corner this is ``|H(j 2 pi f)|`` of
:meth:`~mr_suspension.core.quarter_car.QuarterCarParams.transfer`.
"""

import math

import numpy as np

from mr_suspension.core import road as rd
from mr_suspension.core.metrics import sine_gain
from mr_suspension.sim.simulator import simulate

# Output, label: body acceleration, body displacement, working space, normalised tyre force.
RESPONSES = (('acc', 'body acceleration gain [1/s^2]'), ('z_s', 'body amplitude gain [-]'),
             ('stroke', 'working space gain [-]'), ('ntf', 'NTF gain [1/m]'))


def sine_dwell_gains(config, freqs, amplitude=0.01, periods=4, settle=3.0):
    """Return ``{output: gains}`` per unit road amplitude at ``freqs`` [Hz] (module doc)."""
    if not (amplitude > 0.0 and math.isfinite(amplitude)):
        raise ValueError('sine_dwell_gains: amplitude must be a finite number > 0')
    freqs = np.asarray(freqs, dtype=float)
    if freqs.size == 0 or not np.all(freqs > 0.0) or freqs.max() >= 0.25 / config.dt:
        raise ValueError('sine_dwell_gains: frequencies must be > 0 and below 1/(4 dt)')
    out = {k: np.empty(freqs.size) for k, _ in RESPONSES}
    f_t0 = config.car.static_tyre_load
    for n, f in enumerate(freqs):
        res = simulate(config, rd.harmonic(amplitude, f, duration=settle + periods / f,
                                           dt=config.dt))
        t = res.t
        for key, y in (('acc', res.a_s), ('z_s', res.z_s), ('stroke', res.stroke),
                       ('ntf', res.f_t / f_t0)):
            out[key][n] = sine_gain(t, y, f, periods) / amplitude
    return out
