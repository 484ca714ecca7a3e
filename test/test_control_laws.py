"""Control laws: truth tables, passivity, command range, parameters, and closed-loop runs."""

import math

import numpy as np
import pytest

from mr_suspension.control import laws as L
from mr_suspension.control.laws import ControllerParams
from mr_suspension.core import road as rd
from mr_suspension.sim import config as cfg
from mr_suspension.sim.simulator import CornerConfig, simulate

CAR = cfg.load_vehicle('seed003_passenger')
DAMPER = cfg.load_damper('rd1005_bingham')
IDEAL = cfg.load_driver('ideal')


def _step(law, m, **gains):
    c = ControllerParams(law=law, estimation='ideal', **gains).with_plant(CAR, DAMPER)
    return L.controller_step(c.law_id, c.to_array(), np.zeros(L.N_CTRL_STATE),
                             np.asarray(m, dtype=float), 1e-3)


def _m(a_s=0.0, a_u=0.0, x=0.0, v=0.0, v_s=0.0, v_u=None, field=0.0):
    v_u = v_s - v if v_u is None else v_u
    return [a_s, a_u, x, v, v_s, v_u, field]


def test_layout_constants():
    assert L.N_MEAS == 7 and L.N_CTRL_STATE >= 48
    assert (L.M_ACC_S, L.M_ACC_U, L.M_STROKE, L.M_STROKE_RATE, L.M_VEL_S, L.M_VEL_U,
            L.M_FIELD) == tuple(range(7))


def test_skyhook_onoff_truth_table():
    # Karnopp 1974: i_max iff v_s (v_s - v_u) > 0.
    assert _step('skyhook_onoff', _m(v_s=0.2, v=0.1), i_max=0.7) == 0.7
    assert _step('skyhook_onoff', _m(v_s=-0.2, v=-0.1), i_max=0.7) == 0.7
    assert _step('skyhook_onoff', _m(v_s=0.2, v=-0.1), i_max=0.7) == 0.0
    assert _step('skyhook_onoff', _m(v_s=-0.2, v=0.1), i_min=0.1) == 0.1


def test_add_truth_table():
    # Savaresi et al. 2005: i_max iff a_s (v_s - v_u) > 0.
    assert _step('add', _m(a_s=1.0, v=0.1)) == 2.0
    assert _step('add', _m(a_s=-1.0, v=0.1)) == 0.0
    assert _step('add', _m(a_s=-1.0, v=-0.1)) == 2.0


def test_sh_add_switches_between_sh_and_add():
    # alpha = 1 / (2 pi f_cross); f_cross = 1 Hz -> alpha = 0.159 s.
    # Large acceleration (v_s^2 < alpha^2 a_s^2): ADD decides.
    assert _step('sh_add', _m(a_s=10.0, v_s=-0.1, v=0.1), f_cross=1.0) == 2.0
    assert _step('sh_add', _m(a_s=-10.0, v_s=0.1, v=0.1), f_cross=1.0) == 0.0
    # Large velocity: skyhook decides.
    assert _step('sh_add', _m(a_s=-0.1, v_s=0.5, v=0.1), f_cross=1.0) == 2.0
    assert _step('sh_add', _m(a_s=0.1, v_s=-0.5, v=0.1), f_cross=1.0) == 0.0


def _force(i, v, x=0.0):
    from mr_suspension.core.damper import bingham_force
    return bingham_force(DAMPER.to_array(), v, i)[0] - DAMPER.f0


def test_continuous_skyhook_tracks_c_sky_v_s():
    i = _step('skyhook', _m(v_s=0.2, v=0.1), c_sky=4000.0)
    assert 0.0 < i < 2.0
    assert _force(i, 0.1) == pytest.approx(4000.0 * 0.2, rel=1e-5)
    # Passivity: the force would push (F v < 0) -> minimum current.
    assert _step('skyhook', _m(v_s=0.2, v=-0.1), c_sky=4000.0) == 0.0


def test_groundhook_and_hybrid():
    i = _step('groundhook', _m(v_s=0.0, v=0.1, v_u=-0.2), c_ground=3000.0)
    assert _force(i, 0.1) == pytest.approx(600.0, rel=1e-5)
    assert _step('groundhook', _m(v=0.1, v_u=0.2)) == 0.0
    # Hybrid with alpha = 1 is skyhook, alpha = 0 is groundhook.
    m = _m(v_s=0.2, v=0.1, v_u=-0.15)
    assert _step('hybrid', m, alpha=1.0, c_sky=4000.0) == pytest.approx(
        _step('skyhook', m, c_sky=4000.0))
    assert _step('hybrid', m, alpha=0.0, c_ground=3000.0) == pytest.approx(
        _step('groundhook', m, c_ground=3000.0))


def test_pdd_cancels_spring_force():
    # Morselli & Zanasi 2008: F = -k_s x when feasible.
    i = _step('pdd', _m(x=-0.05, v=0.1))
    assert _force(i, 0.1) == pytest.approx(CAR.k_s * 0.05, rel=1e-5)
    assert _step('pdd', _m(x=0.05, v=0.1)) == 0.0          # would need a pushing force


def test_clipped_optimal_uses_lq_gain():
    c = ControllerParams(law='clipped_optimal', estimation='ideal').with_plant(CAR, DAMPER)
    k = c.gains()
    m = _m(a_s=0.0, a_u=0.0, x=0.01, v=0.1, v_s=0.3)
    f_des = -(k[0] * 0.01 + k[1] * 0.3 + k[3] * (0.3 - 0.1))
    i = L.controller_step(c.law_id, c.to_array(), np.zeros(L.N_CTRL_STATE),
                          np.asarray(m), 1e-3)
    if f_des * 0.1 > 0.0 and f_des > _force(0.0, 0.1):
        assert _force(i, 0.1) == pytest.approx(min(f_des, _force(2.0, 0.1)), rel=1e-5)
    else:
        assert i == 0.0
    given = c.replace(lqr_gains=(0.0, -3000.0, 0.0, 0.0))
    i2 = L.controller_step(given.law_id, given.to_array(), np.zeros(L.N_CTRL_STATE),
                           np.asarray(m), 1e-3)
    assert _force(i2, 0.1) == pytest.approx(900.0, rel=1e-5)


@pytest.mark.parametrize('law', sorted(L.LAW_IDS))
@pytest.mark.parametrize('estimation', ['sensors', 'ideal'])
def test_commands_always_in_range(law, estimation):
    rng = np.random.default_rng(3)
    c = ControllerParams(law=law, i_min=0.2, i_max=1.3, current=0.7, estimation=estimation,
                         febc_i_body=0.5, febc_i_road=1.0).with_plant(CAR, DAMPER)
    p = c.to_array()
    s = np.zeros(L.N_CTRL_STATE)
    for k in range(400):
        m = rng.normal(0.0, [3.0, 30.0, 0.03, 0.3, 0.3, 0.5, 1.0])
        if k % 37 == 0:
            m[rng.integers(0, 7)] = math.nan
        i = L.controller_step(c.law_id, p, s, m, 1e-3)
        assert 0.2 <= i <= 1.3
    assert np.all(np.isfinite(s))


def test_clamp_current():
    p = ControllerParams(i_min=0.1, i_max=1.5).to_array()
    assert L.clamp_current(p, math.nan) == 0.1
    assert L.clamp_current(p, -3.0) == 0.1
    assert L.clamp_current(p, 9.0) == 1.5
    assert L.clamp_current(p, 0.4) == 0.4


def test_params_round_trip_and_yaml_sets():
    for name in cfg.available('controllers'):
        c = cfg.load_controller(name)
        again = ControllerParams.from_dict(c.to_dict())
        assert again == c
        assert np.array_equal(again.to_array(), c.to_array())
    assert {cfg.load_controller(n).law for n in cfg.available('controllers')} == set(L.LAW_IDS)


@pytest.mark.parametrize('bad', [
    {'law': 'magic'}, {'i_min': -0.1}, {'i_min': 2.0, 'i_max': 1.0}, {'alpha': 1.5},
    {'estimation': 'kalman'}, {'febc_f1': 8.0, 'febc_f2': 6.0}, {'lqr_gains': (1.0, 2.0)},
    {'lqr_weights': (1.0, 1.0, 1.0, 0.0)}, {'c_sky': math.nan}, {'k_s': 0.0},
    {'damper_model': {'law': 'unknown'}}, {'nonsense': 1.0},
])
def test_bad_parameters_raise(bad):
    with pytest.raises(ValueError):
        ControllerParams.from_dict({'law': 'skyhook', **bad})


def test_with_plant_and_configure():
    drv = cfg.load_driver('wonder_box')
    c = cfg.configure('skyhook', CAR, 'seed002_tanh', drv, c_sky=1234.0)
    assert c.c_sky == 1234.0 and c.k_s == CAR.k_s and c.m_s == CAR.m_s
    assert c.damper_model['law'] == 'tanh'
    assert c.i_max <= drv.i_range + 1e-12
    assert int(c.to_array()[L.P_DLAW]) == 2
    assert set(L.GAIN_DESCRIPTIONS) == set(c.to_dict())


@pytest.mark.parametrize('law', sorted(L.LAW_IDS))
def test_closed_loop_runs_are_passive_and_law_specific(law):
    """Every law through the offline simulator: finite, dissipative, its own commands."""
    road = rd.bump(0.05, 2.0, 10.0, t0=0.2, duration=2.0)
    conf = CornerConfig(car=CAR, damper=DAMPER, driver=IDEAL, controller=cfg.configure(
        law, CAR, DAMPER, IDEAL, current=0.4, febc_i_body=0.4, i_max=1.0))
    res = simulate(conf, road)
    assert np.all((res.i_cmd >= 0.0) & (res.i_cmd <= 1.0))
    # Semi-active: the damper dissipates (its law is passive at any current).
    assert np.sum(res.f_d * res.stroke_rate) * conf.dt > 0.0
    if law == 'constant':
        assert np.all(res.i_cmd == 0.4)
    else:
        # A stale numba cache of the simulator would silently run another law: catch it.
        assert np.ptp(res.i_cmd) > 0.05


def test_sensor_noise_is_reproducible_standard_normal():
    p = ControllerParams(noise_acc=0.1, noise_seed=7).to_array()
    draws = []
    for _ in range(2):
        s = np.zeros(L.N_CTRL_STATE)
        draws.append(np.array([L.sensor_noise(p, s) for _ in range(20000)]))
    assert np.array_equal(draws[0], draws[1])
    assert abs(draws[0].mean()) < 0.03 and draws[0].std() == pytest.approx(1.0, abs=0.03)
    other = ControllerParams(noise_acc=0.1, noise_seed=8).to_array()
    s = np.zeros(L.N_CTRL_STATE)
    assert L.sensor_noise(other, s) != draws[0][0]
    with pytest.raises(ValueError):
        ControllerParams(noise_seed=-1)
    with pytest.raises(ValueError):
        ControllerParams(noise_acc=-0.1)


def test_noise_reaches_the_law():
    # Constant law: noise never changes the command; skyhook at rest: it does.
    road = rd.step(0.0, t0=0.1, duration=0.5)
    runs = {}
    for noise in (0.0, 0.5):
        conf = CornerConfig(car=CAR, damper=DAMPER, driver=IDEAL, controller=cfg.configure(
            'skyhook', CAR, DAMPER, IDEAL, noise_acc=noise, noise_stroke=noise * 1e-3))
        runs[noise] = simulate(conf, road).i_cmd
    assert np.all(runs[0.0] == 0.0)
    assert np.ptp(runs[0.5]) > 0.0


def _commands_with_and_without_field(law, damper):
    c = ControllerParams(law=law).with_plant(CAR, cfg.load_damper(damper))
    p = c.to_array()
    rng = np.random.default_rng(11)
    meas = rng.normal(0.0, [3.0, 30.0, 0.02, 0.0, 0.0, 0.0, 0.0], size=(300, 7))
    meas[:, 3:6] = math.nan       # velocities estimated from the sensors
    runs = []
    for field in (np.full(300, math.nan), rng.uniform(0.0, 2.0, 300)):
        s = np.zeros(L.N_CTRL_STATE)
        out = []
        for k in range(300):
            m = meas[k].copy()
            m[L.M_FIELD] = field[k]
            out.append(L.controller_step(c.law_id, p, s, m, 1e-3))
        runs.append(np.array(out))
    return L.uses_field(c.law_id, p), runs[0], runs[1]


@pytest.mark.parametrize('law', sorted(L.LAW_IDS))
@pytest.mark.parametrize('damper', ['rd1005_bingham', 'spencer_bouc_wen', 'seed000_mechanical'])
def test_field_slot_ignored_unless_uses_field(law, damper):
    """Without uses_field() the commands are the same whatever the measured field current."""
    uses, without, with_field = _commands_with_and_without_field(law, damper)
    if not uses:
        assert np.array_equal(without, with_field), (law, damper)


@pytest.mark.parametrize('law', L.INVERSE_LAWS)
def test_field_slot_read_by_inverse_laws_on_stateful_models(law):
    uses, without, with_field = _commands_with_and_without_field(law, 'spencer_bouc_wen')
    assert uses and not np.array_equal(without, with_field), law
