"""Sensor-based estimation and FEBC: closed-form phase/gain, bounded drift, frequency bands."""

import math

import numpy as np
import pytest

from mr_suspension.control import estimation as est
from mr_suspension.control.febc import febc_step
from mr_suspension.evaluation import studies

DT = 1e-3


def _phase(t, y, f):
    w = 2.0 * math.pi * f
    a = np.column_stack([np.sin(w * t), np.cos(w * t), np.ones_like(t)])
    c, *_ = np.linalg.lstsq(a, y, rcond=None)
    return math.atan2(c[1], c[0]), math.hypot(c[0], c[1])


def _run(f, f_hp=0.1, f_cr=2.0, f_lp=40.0, wheel=True):
    """Body and stroke velocity sin(w t); accelerations as step averages, stroke sampled."""
    n = int(round((8.0 + 6.0 / f) / DT))
    t = np.arange(1, n + 1) * DT
    w = 2.0 * math.pi * f
    v_true = np.sin(w * t)
    x = (1.0 - np.cos(w * t)) / w
    acc = np.diff(np.concatenate([[0.0], v_true])) / DT      # (v_k - v_{k-1}) / dt
    s = np.zeros(4)
    vs_hat = np.empty(n)
    v_hat = np.empty(n)
    for k in range(n):
        a_prev = acc[k]
        vs_hat[k], v_hat[k] = est.estimate_step(s, a_prev, 0.0 if wheel else math.nan, x[k],
                                                DT, f_hp, f_cr, f_lp)
    sel = t >= t[-1] - 6.0 / f
    return t[sel], v_true[sel], vs_hat[sel], v_hat[sel]


@pytest.mark.parametrize('f', [0.5, 1.5, 8.0])
def test_body_velocity_is_leaky_integrator(f):
    # V_s = A / (s + w_hp): gain 1/sqrt(1 + (f_hp/f)^2), phase lead atan(f_hp / f).
    t, v, vs_hat, _ = _run(f, f_hp=0.2)
    ph_true, a_true = _phase(t, v, f)
    ph_est, a_est = _phase(t, vs_hat, f)
    assert a_est / a_true == pytest.approx(1.0 / math.hypot(1.0, 0.2 / f), rel=2e-3)
    assert ph_est - ph_true == pytest.approx(math.atan(0.2 / f), abs=3e-3)


@pytest.mark.parametrize('f', [1.0, 10.0])
def test_stroke_rate_complementary_has_no_filter_lag(f):
    t, v, _, v_hat = _run(f)
    ph_true, a_true = _phase(t, v, f)
    ph_est, a_est = _phase(t, v_hat, f)
    delay = (ph_true - ph_est) / (2.0 * math.pi * f)
    assert abs(delay) < 1e-3                   # under one sample
    assert a_est / a_true == pytest.approx(1.0, abs=0.02)


def test_stroke_rate_without_wheel_accelerometer_lags_by_filter():
    # Backward difference (dt / 2) through y += L (u - y), L = 1 - exp(-w dt), whose low-
    # frequency delay is dt exp(-w dt) / L ~ 1 / w - dt / 2: in total 1 / (2 pi f_lp).
    f = 1.0
    t, v, _, v_hat = _run(f, f_lp=40.0, wheel=False)
    ph_true, _ = _phase(t, v, f)
    ph_est, _ = _phase(t, v_hat, f)
    delay = (ph_true - ph_est) / (2.0 * math.pi * f)
    assert delay == pytest.approx(1.0 / (2.0 * math.pi * 40.0), rel=0.02)


def test_bias_drift_is_bounded():
    bound = 0.05 / (2.0 * math.pi * 0.1)
    assert studies.bias_drift(0.05, 120.0, DT, 0.1) == pytest.approx(bound, rel=1e-3)


def test_estimator_handles_nan_samples():
    s = np.zeros(4)
    for k in range(50):
        vs, v = est.estimate_step(s, math.nan if k % 7 == 0 else 1.0, math.nan,
                                  math.nan if k % 5 == 0 else 0.001 * k, DT, 0.1, 2.0, 40.0)
        assert math.isfinite(vs) and math.isfinite(v)


@pytest.mark.parametrize('f, expected', [(1.0, 0.5), (4.0, 0.0), (12.0, 1.2)])
def test_febc_schedules_current_by_frequency(f, expected):
    s = np.zeros(4)
    i = None
    for k in range(5000):
        x = 0.003 * math.sin(2.0 * math.pi * f * k * DT)
        i = febc_step(s, x, DT, 2.0, 6.0, 0.5, 0.0, 1.2, 0.3, 5e-4)
    assert s[3] == pytest.approx(f, rel=0.05)
    assert i == expected


def test_estimator_delays_study_matches_filters():
    rows = studies.estimator_delays(freqs=(1.0, 5.0))
    for row in rows:
        assert abs(row['stroke_rate_ms']) < 1.5
        assert row['stroke_rate_no_wheel_acc_ms'] == pytest.approx(4.0, abs=0.3)
    # The leaky integrator leads at low frequency: -atan(f_hp / f) / w.
    assert rows[0]['body_velocity_ms'] == pytest.approx(
        -1e3 * math.atan(0.1 / 1.0) / (2.0 * math.pi), abs=1.5)
