"""ISO 2631-1 We weighting, k factors and full-car comfort at a body point."""

import dataclasses
import math

import numpy as np
import pytest
from scipy import signal

from mr_suspension.core import comfort as cf
from mr_suspension.core import metrics

# ISO 2631-1:1997 Table 4, We factors x 1000 at the nominal one-third-octave band centres.
WE_TABLE = {0.1: 62.5, 0.125: 97.5, 0.16: 159, 0.2: 245, 0.25: 368, 0.315: 536, 0.4: 723,
            0.5: 862, 0.63: 939, 0.8: 941, 1.0: 880, 1.25: 772, 1.6: 632, 2.0: 512,
            2.5: 409, 3.15: 323, 4.0: 253, 5.0: 202, 6.3: 160, 8.0: 125, 10.0: 100,
            12.5: 80.1, 16.0: 62.5, 20.0: 50.0, 25.0: 39.9, 31.5: 31.6, 40.0: 24.7,
            50.0: 19.4, 63.0: 14.8, 80.0: 10.5}

DT = 1e-3


def _we_closed_form(freq):
    """|H(j 2 pi f)| of We written out stage by stage, independently of the module."""
    s = 2j * np.pi * np.asarray(freq, dtype=float)
    w1, w2, w4 = 2 * np.pi * 0.4, 2 * np.pi * 100.0, 2 * np.pi * 1.0
    q = 1.0 / np.sqrt(2.0)
    high = 1.0 / (1.0 + w1 / (q * s) + (w1 / s) ** 2)
    low = 1.0 / (1.0 + s / (q * w2) + (s / w2) ** 2)
    transition = (1.0 + s / w4) / (1.0 + s / (0.63 * w4) + (s / w4) ** 2)
    return np.abs(high * low * transition)


def _sine(amplitude, freq, duration=20.0):
    t = np.arange(0.0, duration, DT)
    return t, amplitude * np.sin(2 * np.pi * freq * t)


def test_we_analogue_matches_the_iso_2631_table():
    freqs = np.array(list(WE_TABLE))
    expected = np.array(list(WE_TABLE.values())) / 1000.0
    # 3-digit table at nominal centres: agrees to 0.4 %; a wrong f3/f4 or Q4 is off by > 10 %.
    assert np.allclose(cf.we_gain(freqs), expected, rtol=0.01)
    assert cf.we_gain(1.0) == pytest.approx(0.880, rel=2e-3)


def test_we_analogue_matches_iso_8041_factors_and_closed_form():
    # ISO 8041-1 Table B.4 at the true centre 10^0.9 Hz; reference value at 100 rad/s.
    assert cf.we_gain(10 ** 0.9) == pytest.approx(0.1263, rel=1e-3)
    assert cf.we_gain(100.0 / (2 * np.pi)) == pytest.approx(0.06287, rel=1e-3)
    freqs = np.geomspace(0.05, 200.0, 60)
    assert np.allclose(cf.we_gain(freqs), _we_closed_form(freqs), rtol=1e-9)


def test_we_asymptotes():
    # Plateau ~1 just below the 1 Hz transition, a-v transition ~ f4 / f above it.
    assert np.all((cf.we_gain([0.5, 0.63, 0.8]) > 0.85) & (cf.we_gain([0.5, 0.63, 0.8]) < 0.95))
    f = np.array([5.0, 10.0, 20.0])
    assert np.allclose(cf.we_gain(f) * f, 1.0, rtol=0.03)
    # Band limiting: 40 dB/decade below 0.4 Hz.
    assert cf.we_gain(0.02) / cf.we_gain(0.04) == pytest.approx(0.25, rel=0.02)


def test_shared_helper_reproduces_the_wk_polynomials():
    num, den = cf.iso_weighting_analog(metrics.WK_F1, metrics.WK_F2, metrics.WK_F3,
                                       metrics.WK_F4, metrics.WK_Q4, metrics.WK_F5,
                                       metrics.WK_Q5, metrics.WK_F6, metrics.WK_Q6)
    wk_num, wk_den = metrics.wk_analog()
    assert np.allclose(num, wk_num, rtol=1e-12) and np.allclose(den, wk_den, rtol=1e-12)


def test_we_digital_filter_matches_analogue():
    freqs = np.geomspace(0.5, 50.0, 40)
    _, h = signal.sosfreqz(cf.we_sos(DT), worN=freqs, fs=1.0 / DT)
    assert np.allclose(np.abs(h), cf.we_gain(freqs), rtol=0.02)
    t, x = _sine(1.0, 2.0)
    gain = metrics.sine_gain(t, cf.we_filter(x, DT), 2.0, n_periods=20)
    assert gain == pytest.approx(cf.we_gain(2.0), rel=0.02)


def test_k_factors():
    assert (cf.K_Z, cf.K_RX, cf.K_RY, cf.K_RZ) == (1.0, 0.63, 0.40, 0.20)


def test_point_acceleration_signs():
    # Nose-down pitch lowers the front, left-up roll raises the left side.
    assert cf.point_acceleration(1.0, 2.0, 3.0, 1.5, -0.5) == pytest.approx(1.0 - 3.0 - 1.5)
    p = np.sin(np.linspace(0.0, 6.0, 50))
    assert np.allclose(cf.point_acceleration(np.zeros(50), p, np.zeros(50), 1.2, 0.0), -1.2 * p)
    assert np.allclose(cf.point_acceleration(np.zeros(50), np.zeros(50), p, 0.0, 0.75), 0.75 * p)


def test_pure_heave_sine():
    amp = 1.5
    t, a_z = _sine(amp, 1.0)
    zero = np.zeros_like(a_z)
    res = cf.comfort(a_z, zero, zero, DT, t_start=5.0)
    assert res.heave_wk_rms == pytest.approx(amp / math.sqrt(2) * metrics.wk_gain(1.0), rel=0.01)
    assert res.pitch_we_rms == 0.0 and res.roll_we_rms == 0.0
    assert res.total == pytest.approx(res.heave_wk_rms, rel=1e-12)
    # VDV of a sine of amplitude B over T: B (3 T / 8)^(1/4).
    b = amp * metrics.wk_gain([1.0])[0]
    assert res.vdv_z == pytest.approx(b * (3 * 15.0 / 8) ** 0.25, rel=0.01)
    # Without rotations every point of the body heaves alike.
    off = cf.comfort(a_z, zero, zero, DT, x=1.2, y=-0.7, t_start=5.0)
    assert off.heave_wk_rms == pytest.approx(res.heave_wk_rms, rel=1e-12)


def test_pure_pitch_sine():
    amp = 0.8
    t, pitch = _sine(amp, 1.0)
    zero = np.zeros_like(pitch)
    res = cf.comfort(zero, pitch, zero, DT, t_start=5.0)
    assert res.heave_wk_rms == 0.0 and res.roll_we_rms == 0.0
    assert res.pitch_we_rms == pytest.approx(amp / math.sqrt(2) * cf.we_gain(1.0), rel=0.01)
    assert res.total == pytest.approx(0.40 * res.pitch_we_rms, rel=1e-12)
    seat = cf.comfort(zero, pitch, zero, DT, x=1.2, t_start=5.0)
    assert seat.heave_wk_rms == pytest.approx(
        1.2 * amp / math.sqrt(2) * metrics.wk_gain(1.0), rel=0.01)
    assert seat.pitch_we_rms == pytest.approx(res.pitch_we_rms, rel=1e-12)
    assert seat.total == pytest.approx(math.hypot(seat.heave_wk_rms, 0.40 * seat.pitch_we_rms))


def test_pure_roll_sine():
    t, roll = _sine(0.5, 2.0)
    zero = np.zeros_like(roll)
    res = cf.comfort(zero, zero, roll, DT, t_start=5.0)
    assert res.total == pytest.approx(0.63 * res.roll_we_rms, rel=1e-12)
    assert res.roll_we_rms == pytest.approx(0.5 / math.sqrt(2) * cf.we_gain(2.0), rel=0.01)


def test_result_is_a_frozen_typed_record():
    t, a_z = _sine(1.0, 3.0, duration=2.0)
    res = cf.comfort(a_z, 0.1 * a_z, 0.2 * a_z, DT, x=0.3, y=0.4)
    d = res.to_dict()
    assert list(d) == ['heave_wk_rms', 'pitch_we_rms', 'roll_we_rms', 'total', 'vdv_z']
    assert all(isinstance(v, float) and v > 0 for v in d.values())
    with pytest.raises(dataclasses.FrozenInstanceError):
        res.total = 0.0


@pytest.mark.parametrize('kwargs, match', [
    ({'a_z': np.zeros(9)}, 'length'),
    ({'roll_acc': np.r_[np.zeros(9), np.nan]}, 'non-finite'),
    ({'pitch_acc': np.r_[np.zeros(9), np.inf]}, 'non-finite'),
    ({'a_z': np.zeros((2, 5))}, '1-D'),
    ({'dt': 0.0}, 'dt'),
    ({'dt': -1e-3}, 'dt'),
    ({'dt': float('nan')}, 'dt'),
    ({'x': float('nan')}, 'finite'),
    ({'t_start': 1.0}, 'at least 2'),
    ({'t_start': -0.1}, 't_start'),
    ({'a_z': [0.0], 'pitch_acc': [0.0], 'roll_acc': [0.0]}, 'at least 2'),
])
def test_bad_inputs_raise(kwargs, match):
    args = {'a_z': np.zeros(10), 'pitch_acc': np.zeros(10), 'roll_acc': np.zeros(10),
            'dt': DT}
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        cf.comfort(**args)
