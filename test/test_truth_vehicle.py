"""Independent vehicle truth: agrees with the core when nothing is hidden, effects show, schema."""

from dataclasses import replace

import numpy as np
import pytest

from mr_suspension.core import road as rd
from mr_suspension.sim.corner import build_corner
from mr_suspension.sim.simulator import simulate
from mr_suspension.truth import vehicle as V


def _rms(a):
    return float(np.sqrt(np.mean(np.square(a))))


@pytest.mark.parametrize('current,controller', [(0.0, 'passive_0A'), (1.0, 'passive_1A')])
@pytest.mark.parametrize('road_class', ['B', 'D'])
def test_truth_without_effects_agrees_with_core(current, controller, road_class):
    """Two implementations (RK4 truth, implicit core step) of the nominal corner agree."""
    road = rd.iso8608(road_class=road_class, speed=20.0, duration=20.0, seed=7)
    truth = V.simulate_truth(V.nominal_truth(), road, np.full(road.z.size, current))
    core = simulate(build_corner(controller), road)
    assert _rms(truth['body_acc']) == pytest.approx(_rms(core.a_s), rel=0.02)
    assert _rms(truth['stroke']) == pytest.approx(_rms(core.stroke), rel=0.02)
    assert _rms(truth['wheel_acc']) == pytest.approx(_rms(core.a_u), rel=0.05)


def test_each_effect_and_fault_contributes():
    for e in V.EFFECTS:
        case = V.make_vehicle_case(3, effects=(e,), duration=8.0, strength=0.5)
        assert case.effects == (e,)
        assert set(case.contributions) == {e}
        assert case.contributions[e] > 0.2, e
    for f in V.SENSOR_FAULTS:
        case = V.make_vehicle_case(3, sensor_faults=(f,), duration=8.0)
        assert case.contributions[f] > 0.5, f
    both = V.make_vehicle_case(4, effects=('top_mount', 'strut_friction'), command='skyhook',
                               duration=8.0)
    assert min(both.contributions.values()) > 0.0


def test_schema_units_and_unseen():
    case = V.make_vehicle_case(11, duration=5.0, with_road=True)
    cols = case.columns
    assert list(cols) == ['time', 'body_acc', 'wheel_acc', 'stroke', 'current_command',
                          'coil_current', 'road']
    n = cols['time'].size
    assert n == 5001 and all(c.shape == (n,) for c in cols.values())
    assert np.allclose(np.diff(cols['time']), 1e-3)
    # Specific force, z up: the acceleration plus g, and noise about it.
    assert np.mean(cols['body_acc'] - case.clean['body_acc']) == pytest.approx(9.81, abs=0.02)
    assert np.mean(cols['wheel_acc'] - case.clean['wheel_acc']) == pytest.approx(9.81, abs=0.02)
    assert np.mean(cols['body_acc']) == pytest.approx(9.81, abs=0.05)
    assert np.max(np.abs(cols['stroke'])) < 0.07
    assert 0.0 <= cols['current_command'].min() and cols['current_command'].max() <= 1.0
    assert 0.0 < case.noise_rms < 0.2 and case.contributions == {}
    again = V.make_vehicle_case(11, duration=5.0, with_road=True)
    assert all(np.array_equal(cols[k], again.columns[k]) for k in cols)
    other = case.unseen()
    assert other.truth == case.truth and other.record == 1
    assert not np.array_equal(other.columns['road'], cols['road'])
    spread = V.make_vehicle_case(11, duration=2.0, spread=0.2).truth
    assert spread.c1 != case.truth.c1 and abs(spread.c1 / case.truth.c1 - 1.0) <= 0.2
    assert spread.m_s == case.truth.m_s and spread.effects == ()
    assert 'coil_current' not in V.make_vehicle_case(11, duration=2.0,
                                                     measured_current=False).columns


def test_sprung_mass_sags_to_static_equilibrium():
    tr = V.nominal_truth()
    heavy = replace(tr, m_s=1.2 * tr.m_nom, effects=('sprung_mass',))
    road = rd.Road('flat', 1e-3, np.zeros(1001), np.zeros(1001))
    out = V.simulate_truth(heavy, road, np.zeros(road.z.size))
    sag = -0.2 * tr.m_nom * tr.g / tr.k_s
    assert out['stroke'][0] == pytest.approx(sag, rel=1e-6)
    assert np.max(np.abs(out['body_acc'])) < 1e-9  # starts and stays at rest
    assert np.ptp(out['stroke']) < 1e-9


def test_bad_input():
    with pytest.raises(ValueError, match='unknown'):
        V.make_vehicle_case(0, effects=('warp_drive',))
    with pytest.raises(ValueError, match='unknown sensor'):
        V.make_vehicle_case(0, sensor_faults=('gremlin',))
    with pytest.raises(ValueError, match='exclude'):
        V.make_vehicle_case(0, effects=('current_lag', 'current_lag_asymmetric'))
    with pytest.raises(ValueError, match='seed'):
        V.make_vehicle_case(-1)
    with pytest.raises(ValueError, match='duration'):
        V.make_vehicle_case(0, duration=0.1)
    with pytest.raises(ValueError, match='spread'):
        V.make_vehicle_case(0, spread=0.9)
    with pytest.raises(ValueError, match='i_max'):
        V.make_vehicle_case(0, i_max=5.0)
    with pytest.raises(ValueError, match='command'):
        V.make_vehicle_case(0, command='psychic')
    road = rd.iso8608(duration=1.0)
    with pytest.raises(ValueError, match='cmd'):
        V.simulate_truth(V.nominal_truth(), road, np.zeros(3))
    with pytest.raises(ValueError, match='NaN'):
        V.simulate_truth(V.nominal_truth(), road, np.full(road.z.size, np.nan))


@pytest.mark.parametrize('truth_kw,core_kw', [
    ({'k_tm': 1.0e5, 'c_tm': 200.0}, {'k_tm': 1.0e5, 'c_tm': 200.0}),
    ({'f_fric': 60.0, 'x_pre': 1e-4}, {'f_fric': 60.0, 'v_fric': 0.002}),
    ({'m_s': 140.0}, {'m_s': 140.0})])
def test_truth_effects_agree_with_core_options(truth_kw, core_kw):
    """The core's model options and the truth's own shapes (Dahl friction, 2 kg strut top)."""
    road = rd.iso8608(road_class='C', speed=20.0, duration=20.0, seed=7)
    truth = V.simulate_truth(replace(V.nominal_truth(), **truth_kw), road,
                             np.full(road.z.size, 1.0))
    base = build_corner('passive_1A')
    core = simulate(base.replace(car=replace(base.car, **core_kw)), road)
    plain = simulate(base, road)
    assert _rms(truth['body_acc']) == pytest.approx(_rms(core.a_s), rel=0.04)
    assert abs(_rms(core.a_s) / _rms(plain.a_s) - 1.0) > 0.01  # the option matters


@pytest.mark.parametrize('effects', [(), ('strut_friction', 'bump_stop'),
                                     ('current_saturation', 'direction_asymmetry')])
def test_truth_fed_its_own_motion_gives_its_body_acceleration(effects):
    """The truth as a predictor (its strut law on a given motion) closes on the true motion."""
    case = V.make_vehicle_case(21, effects=effects, duration=6.0, strength=0.8)
    a = V.body_acc_from_inputs(case, case.clean['stroke'], case.clean['stroke_rate'])
    ref = case.clean['body_acc'] + case.truth.g
    # RK4 within samples on linearly interpolated motion vs the truth's own state: the Dahl
    # bristle state is the only path-dependent part.
    assert _rms(a - ref) < 2e-3 * _rms(case.clean['body_acc'])


def test_truth_predictor_with_a_top_mount_integrates_the_mount():
    """With a mount the given rate is the body-wheel rate; the mount's motion is integrated."""
    case = V.make_vehicle_case(22, effects=('top_mount',), duration=6.0, strength=0.8)
    dt = 1e-3
    zs, zu = case.clean['z_s'], case.clean['z_u']
    v_bw = np.gradient(zs - zu, dt)
    a = V.body_acc_from_inputs(case, case.clean['stroke'], v_bw)
    ref = case.clean['body_acc'] + case.truth.g
    assert _rms(a - ref) < 0.05 * _rms(case.clean['body_acc'])
    # Without the mount dynamics (the strut's rate as the body's) the error is far larger.
    flat = V.body_acc_from_inputs(replace(case, truth=replace(case.truth, k_tm=0.0, c_tm=0.0)),
                                  case.clean['stroke'], case.clean['stroke_rate'])
    assert _rms(flat - ref) > 3 * _rms(a - ref)


def test_truth_predictor_bad_input():
    case = V.make_vehicle_case(23, duration=2.0)
    with pytest.raises(ValueError, match='one value per sample'):
        V.body_acc_from_inputs(case, case.clean['stroke'][:-1], case.clean['stroke_rate'])


def test_truth_predictor_starts_at_the_loaded_equilibrium():
    """A heavier body on a top mount: the predictor starts at rest at the sagged mount."""
    case = V.make_vehicle_case(24, effects=('top_mount', 'sprung_mass'), duration=2.0,
                               strength=0.9)
    still = np.zeros(case.clean['stroke'].size)
    a = V.body_acc_from_inputs(replace(case, clean=dict(case.clean, field_current=still)),
                               still + case.clean['stroke'][0], still)
    assert np.max(np.abs(a - case.truth.g)) < 1e-9 * case.truth.g + 1e-9


def test_truth_predictor_from_its_coil_current_gives_its_field():
    """Fed its own clean coil current, the truth's field-lag chain reproduces its field."""
    case = V.make_vehicle_case(25, effects=('current_lag_asymmetric',), duration=4.0)
    coil = case.clean['coil_current']
    field = V._field_from_coil(case.truth.array(), coil, 1e-3)
    # exact exponential steps on a coil current held per sample vs the RK4 state
    assert _rms(field - case.clean['field_current']) < 0.02 * _rms(case.clean['field_current'])
    a = V.body_acc_from_inputs(case, case.clean['stroke'], case.clean['stroke_rate'], coil)
    assert _rms(a - case.clean['body_acc'] - case.truth.g) < 0.02 * _rms(case.clean['body_acc'])
