"""Full car: closed forms, an independent integrator, the quarter car as special case."""

from dataclasses import replace
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from mr_suspension.control.laws import ControllerParams
from mr_suspension.control.modal import distribution, ModalParams
from mr_suspension.core import car_road as cr
from mr_suspension.core import full_car as fc
from mr_suspension.core import road as rd
from mr_suspension.core.damper import LinearDamperParams
from mr_suspension.sim import config
from mr_suspension.sim import full_car_sim as fs
from mr_suspension.sim import simulator as sim

# One worker compiles the full-car kernels (about a minute from a cold cache), not two.
pytestmark = pytest.mark.xdist_group('full_car')

IDEAL = config.load_driver('ideal')


def full_car_files():
    """Names of the packaged full-car files (vehicles with front and rear corners)."""
    return [n for n in config.available('vehicles') if 'front' in config.load_yaml('vehicles', n)]


def lisa():
    return config.load_full_car('lisa_full_car')


def test_a_full_car_file_is_packaged_and_loads():
    names = full_car_files()
    assert names
    for name in names:
        car = config.load_full_car(name)
        assert car.front.m_s * 2 + car.rear.m_s * 2 == pytest.approx(car.m_b, rel=1e-12)
        # Static moment balance about the CG.
        assert car.front.m_s * car.a == pytest.approx(car.rear.m_s * car.b, rel=1e-12)


def test_closed_form_frequencies_with_rigid_tyres():
    """Springs with k_f a = k_r b: heave, pitch and roll decouple; tyres 1e3 x stiffer."""
    base = lisa()
    k_f = 12000.0
    k_r = k_f * base.a / base.b
    front = replace(base.front, k_s=k_f, k_t=1e8)
    rear = replace(base.rear, k_s=k_r, k_t=1e8)
    car = replace(base, front=front, rear=rear)
    f = car.natural_frequencies()
    two_pi = 2.0 * math.pi
    heave = math.sqrt(2.0 * (k_f + k_r) / car.m_b) / two_pi
    pitch = math.sqrt(2.0 * (k_f * car.a ** 2 + k_r * car.b ** 2) / car.i_yy) / two_pi
    roll_k = (0.5 * k_f * car.track_f ** 2 + 0.5 * k_r * car.track_r ** 2
              + car.k_arb_f * car.track_f ** 2 + car.k_arb_r * car.track_r ** 2)
    roll = math.sqrt(roll_k / car.i_xx) / two_pi
    assert f['heave'] == pytest.approx(heave, rel=3e-4)
    assert f['pitch'] == pytest.approx(pitch, rel=3e-4)
    assert f['roll'] == pytest.approx(roll, rel=3e-4)


def test_heave_and_pitch_couple_when_the_springs_are_unbalanced():
    base = lisa()
    car = replace(base, front=replace(base.front, k_s=2 * base.front.k_s))
    mass, _, stiff = car.linear_matrices()
    assert abs(stiff[0, 1]) > 0.0  # k_f a != k_r b: a heave force pitches the body
    mass, _, stiff = base.linear_matrices()
    assert abs(stiff[0, 2]) < 1e-12 * abs(stiff[0, 0])  # symmetric left-right: heave never rolls


def _linear_rhs(mass, damp, stiff, tyre_k, tyre_c, road, nb):
    """Linear full car as y' = f(t, y), the road interpolated (its own, not the package's)."""
    minv = np.linalg.inv(mass)
    n = mass.shape[0]
    t_grid = road.t

    def rhs(t, y):
        q, v = y[:n], y[n:]
        zr = np.array([np.interp(t, t_grid, road.z[i]) for i in range(4)])
        zrd = np.array([np.interp(t, t_grid, road.zdot[i]) for i in range(4)])
        force = -stiff @ q - damp @ v
        force[nb:] += tyre_k * zr + tyre_c * zrd
        return np.concatenate([v, minv @ force])
    return rhs


@pytest.mark.parametrize('side', ['left', 'both'])
def test_matches_an_independent_integrator_on_a_bump(side):
    """Viscous dampers, small bump (no stop, no lift-off): the step agrees with RK45."""
    car = lisa()
    c = 1200.0
    road = cr.bump(0.01, 1.0, 8.0, t0=0.2, side=side, duration=1.5, dt=1e-3,
                   track=car.track_f, wheelbase=car.wheelbase)
    cfg = fs.FullCarConfig(car=car, damper=LinearDamperParams(c=c), driver=IDEAL,
                           controller=ControllerParams(law='constant'))
    res = fs.simulate(cfg, road)
    mass, damp, stiff = car.linear_matrices(c)
    tyre_k = np.array([car.corner(i).k_t for i in range(4)])
    tyre_c = np.array([car.corner(i).c_t for i in range(4)])
    stiff_full = stiff.copy()
    # linear_matrices includes the tyres' own stiffness and damping on the wheel rows.
    sol = solve_ivp(_linear_rhs(mass, damp, stiff_full, tyre_k, tyre_c, road, 3),
                    (0.0, road.duration), np.zeros(14), t_eval=res.t, rtol=1e-9, atol=1e-12,
                    max_step=1e-3)
    for k, name in enumerate(('z', 'theta', 'phi')):
        ours = res.channel(name)
        ref = sol.y[k]
        scale = np.abs(ref).max()
        if scale < 1e-12:
            assert np.abs(ours).max() < 1e-12
            continue
        assert np.abs(ours - ref).max() < 2e-3 * scale, name
    if side == 'both':
        assert np.abs(res.channel('phi')).max() < 1e-12
    else:
        assert np.abs(res.channel('phi')).max() > 1e-4


@pytest.mark.parametrize('law', ['constant', 'skyhook_onoff', 'groundhook', 'add'])
def test_uncoupled_body_gives_the_quarter_car_to_round_off(law):
    car = lisa()
    left = rd.iso8608('C', 15.0, 3.0, 1e-3, seed=3)
    right = rd.iso8608('C', 15.0, 3.0, 1e-3, seed=4)
    road = cr.from_track(left, car.wheelbase, 15.0, right=right)
    cfg = fs.FullCarConfig(car=car, damper=config.load_damper('rd1005_bingham'),
                           controller=ControllerParams(law=law, current=0.6), coupled=False)
    res = fs.simulate(cfg, road)
    for i in range(4):
        quarter = sim.simulate(cfg.corner(i), road.corner(i))
        scale = np.abs(quarter.data).max(axis=0) + 1e-300
        assert (np.abs(quarter.data - res.corners[i]).max(axis=0) / scale).max() < 1e-9


def test_rear_wheels_meet_the_bump_a_wheelbase_later():
    car = lisa()
    speed = 10.0
    road = cr.bump(0.02, 0.5, speed, t0=0.3, side='left', duration=1.5,
                   track=car.track_f, wheelbase=car.wheelbase)
    cfg = fs.FullCarConfig(car=car, damper=config.load_damper('rd1005_bingham'))
    res = fs.simulate(cfg, road)
    t = res.t
    peak = [t[np.argmax(np.abs(res.channel('a_u', i)))] for i in range(4)]
    assert peak[2] - peak[0] == pytest.approx(car.wheelbase / speed, abs=5e-3)
    assert np.abs(res.channel('a_u', 1)).max() < np.abs(res.channel('a_u', 0)).max() / 5


def test_modal_distribution_reproduces_the_modal_forces():
    t, _, _ = lisa().body()
    g = distribution(t)
    np.testing.assert_allclose(t[:, :3].T @ g, np.eye(3), atol=1e-12)


def test_modal_skyhook_beats_every_passive_current_that_uses_no_more_stroke():
    """The semi-active promise on a two-track road.

    Comfort no passive setting reaches at the same working space, and less pitch and roll than
    the softest passive damper.
    """
    car = lisa()
    road = cr.iso8608_two_track('C', 15.0, 5.0, 1e-3, seed=5, track=car.track_f,
                                wheelbase=car.wheelbase)
    damper = config.load_damper('rd1005_bingham')
    cfgs = [fs.FullCarConfig(car=car, damper=damper,
                             controller=ControllerParams(law='constant', current=i))
            for i in (0.0, 0.2, 0.4, 0.7, 1.0)]
    cfgs.append(fs.FullCarConfig(car=car, damper=damper, modal=ModalParams(),
                                 controller=ControllerParams(law='skyhook')))
    m = fs.simulate_batch(cfgs, [road])
    space = m.corners['working_space_rms'].mean(axis=1)
    stiffer = [k for k in range(5) if space[k] <= space[5]]
    assert stiffer and m.comfort[5] < min(m.comfort[k] for k in stiffer)
    assert m.body['pitch_we_rms'][5] < m.body['pitch_we_rms'][0]
    assert m.body['roll_we_rms'][5] < m.body['roll_we_rms'][0]


def test_batch_metrics_equal_the_recorded_run():
    car = lisa()
    road = cr.iso8608_two_track('C', 15.0, 2.0, 1e-3, seed=6, track=car.track_f,
                                wheelbase=car.wheelbase)
    damper = config.load_damper('rd1005_bingham')
    cfgs = [fs.FullCarConfig(car=car, damper=damper, controller=ControllerParams(law=law))
            for law in ('constant', 'skyhook_onoff')]
    cfgs.append(fs.FullCarConfig(car=car, damper=damper, modal=ModalParams(),
                                 controller=ControllerParams(law='skyhook')))
    m = fs.simulate_batch(cfgs, [road])
    for k, cfg in enumerate(cfgs):
        res = fs.simulate(cfg, road)
        seat = res.comfort('seat')
        assert m.body['seat_wk_rms'][k] == pytest.approx(seat.heave_wk_rms, rel=1e-9)
        assert m.body['pitch_we_rms'][k] == pytest.approx(seat.pitch_we_rms, rel=1e-9)
        assert m.comfort[k] == pytest.approx(seat.total, rel=1e-9)
        ws = np.sqrt(np.mean(res.corners[:, :, sim.CHANNELS.index('stroke')] ** 2, axis=1))
        np.testing.assert_allclose(m.corners['working_space_rms'][k], ws, rtol=1e-9)


def test_bad_inputs_are_clear():
    car = lisa()
    with pytest.raises(ValueError, match='top mount'):
        replace(car, front=replace(car.front, k_tm=5e4))
    with pytest.raises(ValueError, match='m_s'):
        fc.FullCarParams.from_dict({**car.to_dict(), 'front': {**car.to_dict()['front'],
                                                               'm_s': 100.0}})
    with pytest.raises(ValueError, match='coupled'):
        fs.FullCarConfig(car=car, modal=ModalParams(), coupled=False)
    with pytest.raises(ValueError, match='four'):
        fs.FullCarConfig(car=car, damper=(LinearDamperParams(),) * 3)
    with pytest.raises(ValueError, match='CarRoad'):
        fs.simulate(fs.FullCarConfig(car=car), rd.bump(duration=0.5))
    with pytest.raises(ValueError, match='full car'):
        config.load_vehicle('lisa_full_car')
    with pytest.raises(ValueError, match='not plausible'):
        replace(car, i_yy=-1.0)
    with pytest.raises(ValueError, match='unknown law'):
        ModalParams(law='nope')


def test_lq_state_model_has_the_modes_of_the_second_order_car():
    """With u = c (stroke rate) the LQ state model has the poles of linear_matrices(c)."""
    from mr_suspension.control.modal import full_car_matrices
    car = lisa()
    c = 1500.0
    a, b, _, _, _ = full_car_matrices(car)
    # Stroke rate x' = T r' - v_u is row block 0:4 of A (the velocity part of the state).
    closed = a + b @ (c * a[:4, :])
    mass, damp, stiff = car.linear_matrices(c)
    n = mass.shape[0]
    first = np.block([[np.zeros((n, n)), np.eye(n)],
                      [-np.linalg.solve(mass, stiff), -np.linalg.solve(mass, damp)]])
    want = np.sort_complex(np.linalg.eigvals(first))
    got = np.linalg.eigvals(closed)
    got = np.sort_complex(got[np.abs(got) > 1e-6])  # one rigid mode: x + d = T r - z_r
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6)


def test_full_car_clipped_optimal_runs_and_is_left_right_symmetric():
    from mr_suspension.control.modal import full_car_lqr_gain
    car = lisa()
    k = full_car_lqr_gain(car)
    # Mirror left and right: strokes, deflections, wheels swap; roll rate changes sign.
    perm = [1, 0, 3, 2]
    mirror = np.concatenate([perm, [4 + p for p in perm], [8, 9, 10], [11 + p for p in perm]])
    sign = np.ones(15)
    sign[10] = -1.0
    np.testing.assert_allclose(k[perm][:, mirror] * sign, k, rtol=1e-6, atol=1e-6 * abs(k).max())
    road = cr.bump(0.03, 1.0, 10.0, side='left', duration=1.5, track=car.track_f,
                   wheelbase=car.wheelbase)
    res = fs.simulate(fs.FullCarConfig(car=car, damper=config.load_damper('rd1005_bingham'),
                                       controller=ControllerParams(law='skyhook'),
                                       modal=ModalParams(law='modal_clipped_optimal')), road)
    assert np.all(np.isfinite(res.body))
    assert res.channel('i_cmd', 0).max() > res.channel('i_cmd', 0).min()
