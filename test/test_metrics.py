"""ISO 2631-1 weighting, VDV, RMS, settling time and sine fitting."""

import numpy as np
import pytest

from mr_suspension.core import metrics

# ISO 2631-1:1997 Table 3, Wk factors x 1000 at the one-third-octave band centres.
WK_TABLE = {0.5: 418, 0.63: 459, 0.8: 477, 1.0: 482, 1.25: 484, 1.6: 494, 2.0: 531,
            2.5: 631, 3.15: 804, 4.0: 967, 5.0: 1039, 6.3: 1054, 8.0: 1036, 10.0: 988,
            12.5: 902, 16.0: 768, 20.0: 636, 25.0: 513, 31.5: 405, 40.0: 314, 50.0: 246,
            63.0: 186, 80.0: 132}


def test_wk_analogue_matches_the_standard_table():
    freqs = np.array(list(WK_TABLE))
    expected = np.array(list(WK_TABLE.values())) / 1000.0
    # Table values are rounded to 3 digits and given at nominal band centres.
    assert np.allclose(metrics.wk_gain(freqs), expected, rtol=0.02)


def test_wk_digital_filter_matches_analogue_below_30_hz():
    dt = 1e-3
    t = np.arange(0, 20.0, dt)
    for f in (0.8, 2.0, 5.0, 10.0, 25.0):
        y = metrics.wk_filter(np.sin(2 * np.pi * f * t), dt)
        gain = metrics.sine_gain(t, y, f, n_periods=int(5 * f) + 2)
        assert gain == pytest.approx(metrics.wk_gain(f), rel=0.02)


def test_vdv_and_rms_of_a_sinusoid():
    dt = 1e-3
    t = np.arange(0, 10.0, dt)
    a = 2.0 * np.sin(2 * np.pi * 4.0 * t)
    assert metrics.rms(a) == pytest.approx(2.0 / np.sqrt(2.0), rel=1e-4)
    # integral of A^4 sin^4 over T is 3 A^4 T / 8.
    assert metrics.vdv(a, dt) == pytest.approx(2.0 * (3.0 * 10.0 / 8.0) ** 0.25, rel=1e-3)


def test_settling_time_of_exponential_decay():
    t = np.arange(0, 10.0, 1e-3)
    y = np.exp(-(t - 1.0).clip(0) / 0.5)
    # Within 2 % of the peak deviation after ln(50) * tau.
    assert metrics.settling_time(t, y - 0.0, band=0.02, t_start=1.0, floor=1e-9) == \
        pytest.approx(0.5 * np.log(50.0), abs=2e-3)
    assert metrics.settling_time(t, np.sin(t), band=0.02, floor=1e-9) == float('inf')


def test_sine_gain_ignores_offset_and_phase():
    t = np.arange(0, 5.0, 1e-3)
    y = 0.3 + 1.7 * np.sin(2 * np.pi * 3.0 * t + 0.7)
    assert metrics.sine_gain(t, y, 3.0) == pytest.approx(1.7, rel=1e-9)


def test_jitted_sos_step_equals_scipy_sosfilt():
    dt = 1e-3
    x = np.random.default_rng(4).normal(size=3000)
    sos = metrics.wk_sos(dt)
    zi = np.zeros((sos.shape[0], 2))
    y = np.array([metrics.sos_step(sos, zi, v) for v in x])
    assert np.allclose(y, metrics.wk_filter(x, dt), rtol=1e-12, atol=1e-12)
