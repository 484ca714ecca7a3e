"""Inverse damper model: closed forms, round trips for every law, saturation, passivity."""

import math

import numpy as np
import pytest

from mr_suspension.control import inverse as inv
from mr_suspension.core import damper as dmp
from mr_suspension.core.extended import ExtendedDamperParams

LAWS = {
    'bingham': dmp.BinghamParams(f0=-95.0, c0=600.0, c1=1800.0, fc0=40.0, fc1=850.0, v_y=0.02),
    'tanh': dmp.TanhParams(),
    'tanh_maxvel': dmp.TanhMaxVelParams(),
    'mechanical': dmp.MechanicalParams(),
    'bouc_wen': dmp.BoucWenParams(),
    'extended': ExtendedDamperParams(f0=10.0, c0=800.0, c1=900.0, fy0=50.0, fy1=700.0,
                                     v_y=0.01, i_sat=0.8, k_series=2e6, k_gas1=300.0,
                                     rho=0.1),
    'extended_dahl': ExtendedDamperParams(x_h=0.002, kappa=1e-5),
}


def _force(params, x, v, i, state=None, dt=1e-3):
    law, p, n = inv.damper_model_array(params)
    s = np.zeros(max(n, 1)) if state is None else np.array(state, dtype=float)
    tmp = np.zeros(max(n, 1) + 8)
    return inv.force_at(law, p, s, tmp, x, v, i, dt) - inv.static_force(params, dt)


def test_bingham_matches_closed_form():
    # Seed 003 eq. 5.2 with current-affine c(i), Fc(i): i = (F - F0 - c0 v - fc0 th) / (...).
    p = LAWS['bingham']
    x, v, f = 0.01, 0.2, 900.0
    th = math.tanh(v / p.v_y)
    expected = (f - p.c0 * v - p.fc0 * th) / (p.c1 * v + p.fc1 * th)
    # The core evaluates tanh by a rational approximation (rel. error 2.6e-7).
    assert inv.inverse(p, x, v, f) == pytest.approx(expected, rel=1e-6)


def test_tanh_matches_closed_form():
    # Seed 002: F = y_MR I tanh(c_MR v + k_MR x) + c_p v + k_p x.
    p = LAWS['tanh']
    x, v, f = 0.005, 0.1, 800.0
    th = math.tanh(p.c_mr * v + p.k_mr * x)
    expected = (f - p.c_p * v - p.k_p * x) / (p.y_mr * th)
    assert inv.inverse(p, x, v, f) == pytest.approx(expected, rel=1e-6)


@pytest.mark.parametrize('name', sorted(LAWS))
@pytest.mark.parametrize('v', [-0.3, -0.05, 0.02, 0.4])
def test_round_trip_every_law(name, v):
    params = LAWS[name]
    x = 0.01
    f_lo = _force(params, x, v, 0.0)
    f_hi = _force(params, x, v, 2.0)
    assert abs(f_hi) > abs(f_lo)        # more current, more force (monotone in |F|)
    for frac in (0.1, 0.5, 0.9):
        f_des = f_lo + frac * (f_hi - f_lo)
        i = inv.inverse(params, x, v, f_des, 0.0, 2.0, passive=False)
        assert 0.0 < i < 2.0
        assert _force(params, x, v, i) == pytest.approx(f_des, rel=1e-5, abs=1e-3)


@pytest.mark.parametrize('name', sorted(LAWS))
def test_saturation_and_passivity(name):
    params = LAWS[name]
    x, v = 0.002, 0.2     # a loaded stroke, so series-stiffness laws carry force from rest
    assert inv.inverse(params, x, v, 1e7) == 2.0            # beyond the damper: i_max
    assert inv.inverse(params, x, v, 1e7, i_max=1.2) == 1.2
    f_zero = _force(params, x, v, 0.0)
    assert f_zero > 0.0
    assert inv.inverse(params, x, v, 0.5 * f_zero) == 0.0   # below the zero-field force
    assert inv.inverse(params, x, v, -500.0) == 0.0         # would inject power: i_min
    assert inv.inverse(params, x, -v, 500.0) == 0.0
    assert inv.inverse(params, x, v, -500.0, i_min=0.3) == 0.3


def test_linear_law_has_no_authority():
    assert inv.inverse(dmp.LinearDamperParams(c=1500.0), 0.0, 0.1, 300.0, 0.2, 1.5) == 0.2


def test_maxvel_uses_window_peak():
    p = LAWS['tanh_maxvel']
    # With a larger past peak the same force needs more current (F ~ i v / (peak + eps)).
    i_small = inv.inverse(p, 0.0, 0.1, 800.0, state=[0.1])
    i_large = inv.inverse(p, 0.0, 0.1, 800.0, state=[0.5])
    assert i_large > i_small


def test_bad_inputs_raise():
    p = LAWS['bingham']
    with pytest.raises(ValueError):
        inv.inverse(p, math.nan, 0.1, 100.0)
    with pytest.raises(ValueError):
        inv.inverse(p, 0.0, 0.1, math.inf)
    with pytest.raises(ValueError):
        inv.inverse(p, 0.0, 0.1, 100.0, i_min=1.0, i_max=0.5)
    with pytest.raises(ValueError):
        inv.inverse(p, 0.0, 0.1, 100.0, i_min=-0.1)


def test_jitted_inverse_nan_request_gives_i_min():
    law, p, _ = inv.damper_model_array(LAWS['bingham'])
    s = np.zeros(1)
    assert inv.inverse_current(law, p, s, np.zeros(8), 0.0, 0.1, math.nan, 0.0, 0.25, 2.0,
                               1e-3) == 0.25
