"""Damper force laws: seed reference values, closed forms, properties and bad parameters."""

import math

import numpy as np
import pytest

from mr_suspension.core import damper as dmp
from mr_suspension.core.fastmath import fast_tanh
from mr_suspension.sim import config

RNG = np.random.default_rng(20261122)


def _force(params, x, v, i, dt=1e-3, state=None):
    s = np.zeros(dmp.n_state_of(params) + 8) if state is None else state
    return dmp.damper_force(dmp.law_id_of(params), params.to_array(), s, x, v, i, dt)


def test_seed003_bingham_table2_forces():
    # Seed 003, Table 2 / eq. (5.2): F = Fc sgn(v) + C0 v + F0 with Fc = 670 N,
    # C0 = 50 N s/cm = 5000 N s/m, F0 = -95 N. Far from v = 0 the smooth sgn is exact.
    p = config.load_damper('seed003_bingham')
    for v in (0.1, 0.25, -0.1, -0.3):
        expected = 670.0 * math.copysign(1.0, v) + 5000.0 * v - 95.0
        assert _force(p, 0.0, v, 0.0)[0] == pytest.approx(expected, abs=1e-3)
    # At rest only the accumulator offset remains.
    assert _force(p, 0.0, 0.0, 0.0)[0] == pytest.approx(-95.0)


def test_seed002_tanh_model_equation():
    p = config.load_damper('seed002_tanh')
    x, v, i = 0.01, 0.05, 0.8
    expected = (p.y_mr * i * math.tanh(p.c_mr * v + p.k_mr * x) + p.c_p * v + p.k_p * x)
    assert _force(p, x, v, i)[0] == pytest.approx(expected, rel=1e-6)


@pytest.mark.parametrize('name', ['seed003_bingham', 'rd1005_bingham', 'seed002_tanh'])
def test_tangent_matches_numerical_derivative(name):
    p = config.load_damper(name)
    for _ in range(20):
        x, v, i = RNG.uniform(-0.02, 0.02), RNG.uniform(-0.5, 0.5), RNG.uniform(0, 2)
        h = 1e-7
        num = (_force(p, x, v + h, i)[0] - _force(p, x, v - h, i)[0]) / (2 * h)
        assert _force(p, x, v, i)[1] == pytest.approx(num, rel=1e-4, abs=1e-3)


def test_fast_tanh_accuracy():
    xs = np.linspace(-20, 20, 40001)
    approx = np.array([fast_tanh(x) for x in xs])
    assert np.max(np.abs(approx - np.tanh(xs))) < 3e-7
    small = np.linspace(-1e-3, 1e-3, 101)
    rel = np.abs(np.array([fast_tanh(x) for x in small]) - np.tanh(small))
    assert np.all(rel <= 3e-7 * np.abs(small) + 1e-300)


DISSIPATIVE = [
    dmp.LinearDamperParams(c=1500.0),
    dmp.BinghamParams(f0=0.0, c0=800.0, c1=1500.0, fc0=50.0, fc1=600.0, v_y=0.01),
    dmp.TanhParams(y_mr=900.0, c_mr=30.0, k_mr=0.0, c_p=1200.0, k_p=0.0),
    dmp.TanhMaxVelParams(c_mr=900.0, eps=0.02, c_p=1200.0, k_p=0.0, window=0.1),
]


@pytest.mark.parametrize('params', DISSIPATIVE, ids=lambda p: p.law)
def test_damper_only_dissipates(params):
    s = np.zeros(dmp.n_state_of(params) + 8)
    for _ in range(500):
        x, v, i = RNG.uniform(-0.05, 0.05), RNG.uniform(-1, 1), RNG.uniform(0, 2)
        f, c_t = _force(params, x, v, i, state=s)
        assert f * v >= -1e-9
        assert c_t >= 0.0


@pytest.mark.parametrize('name', ['rd1005_bingham', 'seed002_tanh', 'seed000_mechanical'])
def test_force_grows_with_current(name):
    p = dmp.damper_from_dict({**config.load_yaml('dampers', name)})
    currents = np.linspace(0.0, 2.0, 9)
    for v in (0.02, 0.1, 0.4):
        if p.law == 'mechanical':
            forces = [dmp.force_series(dmp.law_id_of(p), p.to_array(),
                                       v * np.arange(400) * 1e-3, np.full(400, v),
                                       np.full(400, i), 1e-3)[-1] for i in currents]
            forces = np.array(forces) - forces[0] * 0  # accumulator adds the same offset
        else:
            forces = np.array([_force(p, 0.0, v, i)[0] for i in currents])
        assert np.all(np.diff(forces) > 0), (name, v, forces)


def test_mechanical_model_series_stiffness():
    # Seed 000 Fig. 7: at steady rate the series spring carries d(v); a rate step loads k1
    # with time constant d'/k1, so the force lags the motion by about d'/k1.
    p = config.load_damper('seed000_mechanical')
    dt = 1e-4
    n = 2000
    v = 0.1
    f = dmp.force_series(dmp.LAW_MECHANICAL, p.to_array(), v * np.arange(n) * dt,
                         np.full(n, v), np.full(n, 1.0), dt)
    x_end = v * (n - 1) * dt
    acc_force = -(p.a2 * x_end ** 2 + p.a1 * x_end + p.a0)
    d_expected = (p.c0 + p.c1) * v + (p.fy0 + p.fy1) * math.tanh(v / p.v_y)
    assert f[-1] - acc_force == pytest.approx(d_expected, rel=1e-4)
    assert f[1] - acc_force < 0.5 * d_expected  # the series spring is still loading


def test_bouc_wen_loop_dissipates_and_is_hysteretic():
    p = config.load_damper('spencer_bouc_wen')
    dt = 1e-3
    t = np.arange(4000) * dt
    x = 0.01 * np.sin(2 * np.pi * 2.0 * t)
    v = 0.01 * 2 * np.pi * 2.0 * np.cos(2 * np.pi * 2.0 * t)
    f = dmp.force_series(dmp.LAW_BOUC_WEN, p.to_array(), x, v, np.full_like(t, 1.0), dt)
    assert np.all(np.isfinite(f))
    last = t >= 1.0
    work = np.sum(f[last] * v[last]) * dt  # 3 cycles
    assert work > 0.0
    # Hysteresis: where the velocity changes sign the force jumps between two branches.
    vl, fl = v[last], f[last]
    top = np.nonzero((vl[:-1] > 0) & (vl[1:] <= 0))[0]
    bottom = np.nonzero((vl[:-1] < 0) & (vl[1:] >= 0))[0]
    assert np.mean(fl[top]) - np.mean(fl[bottom]) > 50.0
    assert 1e3 < dmp.work_diagram_damping(x[last], fl, 2.0) < 1e5


def test_work_diagram_of_linear_damper_gives_back_c():
    # Seed 001 eq. (1): C_eq = W / (pi omega X^2) equals c for a viscous damper.
    for c, f_hz, amp in [(1500.0, 1.2, 0.01), (4200.0, 3.6, 0.005)]:
        t = np.arange(0, 5.0 / f_hz, 1e-4)
        x = amp * np.sin(2 * np.pi * f_hz * t)
        force = c * amp * 2 * np.pi * f_hz * np.cos(2 * np.pi * f_hz * t)
        assert dmp.work_diagram_damping(x, force, f_hz) == pytest.approx(c, rel=2e-3)


def test_bad_damper_parameters_raise():
    with pytest.raises(ValueError, match='v_y'):
        dmp.BinghamParams(v_y=0.0)
    with pytest.raises(ValueError, match='c0'):
        dmp.BinghamParams(c0=-1.0)
    with pytest.raises(ValueError, match='unknown damper law'):
        dmp.damper_from_dict({'law': 'magic'})
    with pytest.raises(ValueError, match='unknown parameter'):
        dmp.damper_from_dict({'law': 'bingham', 'yield': 3.0})
    with pytest.raises(ValueError):
        dmp.work_diagram_damping([0.0, 1.0], [1.0, 2.0], 1.0)
    with pytest.raises(ValueError, match='finite'):
        dmp.work_diagram_damping(np.full(10, np.nan), np.ones(10), 1.0)
