"""Bouc-Wen hysteresis of the extended law against an independent integrator; properties."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from mr_suspension.core.extended import (EXT_NSTATE, extended_force, ExtendedDamperParams,
                                         simulate_extended)
from mr_suspension.identification import engine


def _sine(n=3000, dt=1e-3, amp=0.005, freq=1.5):
    t = np.arange(n) * dt
    w = 2 * np.pi * freq
    return t, amp * np.sin(w * t), amp * w * np.cos(w * t), dt


def _reference_state(t, rate, x_h, n, r):
    """Normalised Bouc-Wen state under the continuous stroke rate ``rate(t)``, by scipy's RK45."""
    def rhs(tt, zz):
        u = rate(tt)
        a = abs(zz[0]) ** n
        return [u / x_h * (1.0 - a * ((1.0 - r) * np.sign(u * zz[0]) + r))]
    return solve_ivp(rhs, (t[0], t[-1]), [0.0], t_eval=t, rtol=1e-10, atol=1e-12,
                     max_step=2e-4).y[0]


def _sine_rate(amp, freq):
    w = 2 * np.pi * freq
    return lambda tt: amp * w * np.cos(w * tt)


@pytest.mark.parametrize('n_h,r_h,x_h', [(1.0, 0.0, 5e-4), (2.0, 0.3, 5e-4), (3.0, -0.4, 2e-4),
                                         (1.5, 0.0, 1e-3), (1.0, 0.2, 3e-4)])
def test_state_matches_an_independent_integrator(n_h, r_h, x_h):
    t, x, v, dt = _sine(1200)
    p = ExtendedDamperParams(c0=0.0, c1=0.0, fy0=1.0, fy1=0.0, x_h=x_h, hyst_n=n_h,
                             hyst_r=r_h)
    y = simulate_extended(p.to_array(), x, v, np.zeros_like(t), dt)[2]
    ref = _reference_state(t, _sine_rate(0.005, 1.5), x_h, n_h, r_h)
    # The kernel starts from rest, the sine at full rate: compared once the loop has closed
    # (the state forgets its start at +-1). The rate held over each step instead of the
    # trapezoid's stroke ran the loop half a step early: errors of 0.013-0.033 here.
    k0 = int(np.argmax(np.abs(ref) > 0.99))
    assert np.max(np.abs(y[k0:] - ref[k0:])) < 3e-3
    assert np.max(np.abs(y)) <= 1.0
    # A closed loop: the state saturates at +-1 on each stroke of 5 mm >> x_h.
    assert np.max(y) > 0.99 and np.min(y) < -0.99


def test_shape_parameters_change_the_loop_and_dahl_is_the_default():
    t, x, v, dt = _sine(2000)
    i = np.zeros_like(t)
    base = {'c0': 500.0, 'c1': 0.0, 'fy0': 200.0, 'fy1': 0.0, 'x_h': 8e-4}
    dahl = simulate_extended(ExtendedDamperParams(**base).to_array(), x, v, i, dt)[0]
    same = simulate_extended(ExtendedDamperParams(**base, hyst_n=1.0, hyst_r=0.0,
                                                  hyst_weight=1.0).to_array(), x, v, i, dt)[0]
    np.testing.assert_array_equal(dahl, same)
    for kw in ({'hyst_n': 2.5}, {'hyst_r': 0.4}, {'hyst_r': -0.8}, {'hyst_weight': 0.3}):
        f = simulate_extended(ExtendedDamperParams(**base, **kw).to_array(), x, v, i, dt)[0]
        assert np.max(np.abs(f - dahl)) > 5.0, kw
    # A weight below 1 mixes the static tanh yield back in: half way at w = 0.5.
    tanh = simulate_extended(ExtendedDamperParams(**{**base, 'x_h': 0.0}).to_array(),
                             x, v, i, dt)[0]
    half = simulate_extended(ExtendedDamperParams(**base, hyst_weight=0.5).to_array(),
                             x, v, i, dt)[0]
    np.testing.assert_allclose(half, 0.5 * (tanh + dahl), atol=1e-6)


@pytest.mark.parametrize('kw', [{'hyst_n': 2.0, 'hyst_r': 0.3}, {'hyst_n': 3.0, 'hyst_r': -0.5},
                                {'hyst_n': 1.3, 'hyst_weight': 0.4, 'k_series': 3e5},
                                {'hyst_n': 2.0, 'rho': 0.45}, {'hyst_weight': 0.5, 'rho': -0.45}])
def test_bouc_wen_damper_only_dissipates(kw):
    """Work over whole cycles is positive, and the tangent matches a finite difference."""
    t, x, v, dt = _sine(4000, amp=0.01, freq=2.0)
    p = ExtendedDamperParams(c0=600.0, c1=800.0, fy0=150.0, fy1=400.0, x_h=1e-3, **kw)
    f = simulate_extended(p.to_array(), x, v, np.full_like(t, 0.7), dt)[0]
    cycle = int(round(1.0 / (2.0 * dt)))
    for k in range(0, t.size - cycle, cycle):
        assert np.sum(f[k:k + cycle] * v[k:k + cycle]) * dt > 0.0
    pa = p.to_array()
    s = np.zeros(EXT_NSTATE)
    for k in range(300):
        extended_force(pa, s, x[k], v[k], 0.7, dt)
    for dv in (-0.05, 0.0, 0.02):
        s1, s2 = s.copy(), s.copy()
        f1, df = extended_force(pa, s1, x[300], v[300] + dv, 0.7, dt)
        f2, _ = extended_force(pa, s2, x[300], v[300] + dv + 1e-7, 0.7, dt)
        assert df == pytest.approx((f2 - f1) / 1e-7, rel=2e-3, abs=1e-3)


@pytest.mark.parametrize('rho', [0.35, -0.3])
def test_direction_asymmetry_scales_the_yield_force_by_its_state(rho):
    """``F_d = c u (1 + rho tanh(u/v_y)) + Fy z (1 + rho z)``, ``z`` from scipy's integrator.

    Without a loop the law is the old ``(1 + rho tanh(u/v_y)) (c u + Fy y)``; with one the
    yield force's scale follows the loop state through a reversal, not the rate.
    """
    t, x, v, dt = _sine(1500, amp=0.006, freq=1.5)
    c, fy, vy, x_h = 700.0, 250.0, 0.004, 6e-4
    i = np.zeros_like(t)
    p = ExtendedDamperParams(c0=c, c1=0.0, fy0=fy, fy1=0.0, v_y=vy, x_h=x_h, hyst_n=2.0,
                             hyst_r=0.2, rho=rho)
    f = simulate_extended(p.to_array(), x, v, i, dt)[0]
    z = _reference_state(t, _sine_rate(0.006, 1.5), x_h, 2.0, 0.2)
    ref = c * v * (1.0 + rho * np.tanh(v / vy)) + fy * z * (1.0 + rho * z)
    k0 = int(np.argmax(np.abs(z) > 0.99))  # the kernel starts from rest: once the loop closed
    assert np.max(np.abs(f[k0:] - ref[k0:])) < 0.5  # 0.2 % of fy
    static = ExtendedDamperParams(c0=c, c1=0.0, fy0=fy, fy1=0.0, v_y=vy, rho=rho)
    f = simulate_extended(static.to_array(), x, v, i, dt)[0]
    y = np.tanh(v / vy)
    np.testing.assert_allclose(f, (1.0 + rho * y) * (c * v + fy * y), rtol=1e-6, atol=1e-6)


def test_parameter_checks_and_old_model_files():
    for bad in ({'hyst_n': 0.5}, {'hyst_r': 0.7}, {'hyst_weight': 0.0}, {'hyst_weight': 1.5}):
        with pytest.raises(ValueError):
            ExtendedDamperParams(x_h=1e-3, **bad)
    # A model file written before the Bouc-Wen shape (x_h only) still loads, as Dahl.
    old = {k: v for k, v in ExtendedDamperParams(x_h=1e-3).to_dict().items()
           if not k.startswith('hyst_')}
    p = ExtendedDamperParams.from_dict(old, source='old_model.json')
    assert (p.hyst_weight, p.hyst_n, p.hyst_r) == (1.0, 1.0, 0.0)
    q = ExtendedDamperParams(x_h=1e-3, hyst_n=2.0, hyst_r=0.2, hyst_weight=0.6)
    assert ExtendedDamperParams.from_array(q.to_array()) == q
    assert ExtendedDamperParams.from_dict(q.to_dict()) == q


def test_fit_recovers_a_bouc_wen_loop_written_apart():
    """A Bouc-Wen damper integrated here (RK45, not the law's table) is fitted by the engine."""
    rng = np.random.default_rng(4)
    dt = 2e-3
    t = np.arange(0, 16.0, dt)
    parts = ((0.006, 1.1, 0.0), (0.003, 2.9, 1.0), (0.0015, 0.43, 0.0))
    x = sum(a * np.sin(2 * np.pi * f * t + ph) for a, f, ph in parts)
    v = np.gradient(x, dt)
    cur = np.repeat(rng.choice([0.1, 0.5, 0.9], size=t.size // 500 + 1), 500)[:t.size]
    n_h, r_h, x_h = 2.2, 0.25, 6e-4
    z = _reference_state(t, lambda tt: sum(a * 2 * np.pi * f * np.cos(2 * np.pi * f * tt + ph)
                                           for a, f, ph in parts), x_h, n_h, r_h)
    force = 5.0 + (700.0 + 900.0 * cur) * v + (120.0 + 600.0 * cur) * z
    force = force + rng.normal(0.0, 1.0, t.size)

    class Rec:
        pass

    rec = Rec()
    rec.time, rec.displacement, rec.velocity, rec.force, rec.i_in = t, x, v, force, cur
    rec.dt, rec.n, rec.duration, rec.mask = dt, t.size, t[-1], None
    ds = engine.Dataset([rec], n_folds=5)
    dahl = engine.fit(ds, ('hysteresis',), new=('hysteresis',),
                      fixed=('hyst_weight', 'hyst_n', 'hyst_r'))
    bw = engine.fit(ds, ('hysteresis',), new=('hysteresis',), joint=40)
    assert bw.heldout_mse < 0.5 * dahl.heldout_mse
    assert bw.heldout_mse < 4.0  # noise variance 1 N^2
    assert bw.eta['x_h'] == pytest.approx(x_h, rel=0.25)
    assert bw.eta['hyst_n'] == pytest.approx(n_h, rel=0.25)
    assert bw.eta['hyst_weight'] > 0.8
