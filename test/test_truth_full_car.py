"""Independent full-car truth: equilibrium, body frequencies, symmetry, effects, bag schema."""

from dataclasses import replace

import numpy as np
import pytest
from truthcases import write_full_car_bag

from mr_suspension.core import car_road as cr
from mr_suspension.truth import full_car as F
from mr_suspension.truth import vehicle as V

DT = 1e-3


def _flat(n, truth, dt=DT):
    z = np.zeros((4, n))
    return cr.CarRoad('flat', dt, z, z.copy(), 10.0, truth.wheelbase)


def _pulse(truth, wheels, height=0.005, width=0.1, t0=0.5, duration=21.0):
    """(1 - cos) pulse of ``width`` [s] under the ``wheels`` (indices), all at ``t0``."""
    t = np.arange(int(round(duration / DT)) + 1) * DT
    s = np.clip((t - t0) / width, 0.0, 1.0)
    on = (t >= t0) & (t <= t0 + width)
    z1 = 0.5 * height * (1.0 - np.cos(2.0 * np.pi * s))
    zd1 = np.where(on, 0.5 * height * 2.0 * np.pi / width * np.sin(2.0 * np.pi * s), 0.0)
    z = np.zeros((4, t.size))
    zd = np.zeros((4, t.size))
    for i in wheels:
        z[i], zd[i] = z1, zd1
    return cr.CarRoad('pulse', DT, z, zd, 10.0, truth.wheelbase)


def _undamped(truth):
    """Dampers (incl. yield and offset) and anti-roll bars off."""
    corners = tuple(replace(c, c0=0.0, c1=0.0, fc0=0.0, fc1=0.0, f0=0.0)
                    for c in truth.corners)
    return replace(truth, corners=corners, k_arb_f=0.0, k_arb_r=0.0)


def _closed_form(truth):
    """Body frequencies [Hz] from the 3x3 body stiffness and mass, wheels quasi-static.

    Series spring ``k_s k_t / (k_s + k_t)`` per corner, the corner at ``(x_i, y_i)`` moves as
    ``z - x_i theta + y_i phi``; each mode named after the coordinate with the largest share
    of its (mass-weighted) eigenvector.
    """
    pos = truth.positions()
    mass = np.diag([truth.m_b, truth.i_yy, truth.i_xx])
    stiff = np.zeros((3, 3))
    for i, c in enumerate(truth.corners):
        k = c.k_s * c.k_t / (c.k_s + c.k_t)
        row = np.array([1.0, -pos[i, 0], pos[i, 1]])
        stiff += k * np.outer(row, row)
    w2, vec = np.linalg.eig(np.linalg.solve(mass, stiff))
    energy = vec.real ** 2 * np.diag(mass)[:, None]
    hz = np.sqrt(w2.real) / (2.0 * np.pi)
    return {name: float(hz[np.argmax(energy[k])])
            for k, name in enumerate(('heave', 'pitch', 'roll'))}


def _peak(x, lo=0.5, hi=5.0):
    """Frequency [Hz] of the largest spectral peak in ``lo..hi`` (Hann, zero-padded)."""
    x = x - x.mean()
    n = 1 << 20
    spec = np.abs(np.fft.rfft(x * np.hanning(x.size), n))
    f = np.fft.rfftfreq(n, DT)
    band = (f >= lo) & (f <= hi)
    k = np.flatnonzero(band)[np.argmax(spec[band])]
    a, b, c = np.log(spec[k - 1:k + 2])
    return f[k] + 0.5 * (a - c) / (a - 2.0 * b + c) * (f[1] - f[0])


def test_zero_state_is_the_static_equilibrium():
    truth = F.nominal_full_car()
    shares = np.array([c.m_nom for c in truth.corners])
    pos = truth.positions()
    assert shares.sum() == pytest.approx(truth.m_b, rel=1e-12)
    assert abs(shares @ pos[:, 0]) < 1e-9 * truth.m_b  # the preloads carry no pitch moment
    assert abs(shares @ pos[:, 1]) < 1e-9 * truth.m_b
    hidden = F.draw_full_car(np.random.default_rng(4), 'front_right',
                             ('strut_friction', 'bump_stop', 'spring_nonlinearity',
                              'current_lag', 'current_saturation', 'direction_asymmetry'),
                             strength=1.0)
    for tr in (truth, hidden):
        n = 3001
        out = F.simulate_full_car(tr, _flat(n, tr), np.full((4, n), 0.7))
        for key in ('body_acc', 'wheel_acc', 'heave_acc', 'pitch_rate', 'roll_rate', 'stroke',
                    'stroke_rate'):
            assert np.abs(out[key]).max() < 1e-9, key
        assert out['coil_current'][:, -1] == pytest.approx(0.7, rel=1e-6)  # the chain ran


def test_body_frequencies_match_the_closed_form():
    """Heave, pitch and roll of a 20 s free vibration (dampers, bars off) within 1 %.

    The nominal pitch inertia (dynamic index 1) puts pitch within 1 % of heave, too close to
    tell apart in 20 s; a smaller I_yy separates them.
    """
    from mr_suspension.core.full_car import FullCarParams
    from mr_suspension.core.paramsets import load_full_car

    truth = replace(_undamped(F.nominal_full_car()), i_yy=250.0)
    expected = _closed_form(truth)
    assert expected['pitch'] > 1.2 * expected['heave']
    core = replace(load_full_car('lisa_full_car'), k_arb_f=0.0, k_arb_r=0.0, i_yy=250.0)
    assert isinstance(core, FullCarParams)
    second = core.natural_frequencies()
    const = np.zeros((4, int(round(21.0 / DT)) + 1))
    runs = {'heave': ((0, 1, 2, 3), 'heave_acc'), 'pitch': ((0, 1), 'pitch_rate'),
            'roll': ((0, 2), 'roll_rate')}
    for mode, (wheels, key) in runs.items():
        out = F.simulate_full_car(truth, _pulse(truth, wheels), const)
        got = _peak(out[key][int(1.0 / DT):])
        assert got == pytest.approx(expected[mode], rel=0.01), mode
        assert got == pytest.approx(second[mode], rel=2e-3), mode


def test_full_width_bump_does_not_roll_the_body():
    truth = F.nominal_full_car()
    road = cr.bump(0.04, 1.0, 12.0, t0=0.3, side='both', duration=3.0, dt=DT,
                   track=truth.track_f, wheelbase=truth.wheelbase)
    n = road.z.shape[1]
    rng = np.random.default_rng(2)
    front, rear = (V._command(rng, n, DT, 'random', 1.0) for _ in range(2))
    out = F.simulate_full_car(truth, road, np.stack([front, front, rear, rear]))
    assert np.abs(out['pitch_rate']).max() > 0.05
    assert np.abs(out['roll_rate']).max() <= 1e-9 * np.abs(out['pitch_rate']).max()
    for left, right in ((0, 1), (2, 3)):
        for key in ('stroke', 'body_acc', 'wheel_acc', 'tyre_force'):
            scale = np.abs(out[key][left]).max()
            assert np.abs(out[key][left] - out[key][right]).max() <= 1e-12 * scale, key


def test_one_side_bump_rolls_the_body_and_meets_the_rear_a_wheelbase_later():
    truth = F.nominal_full_car()
    speed, t0 = 10.0, 0.5
    road = cr.bump(0.03, 1.0, speed, t0=t0, side='left', duration=3.0, dt=DT,
                   track=truth.track_f, wheelbase=truth.wheelbase)
    n = road.z.shape[1]
    out = F.simulate_full_car(truth, road, np.full((4, n), 0.3))
    t = np.arange(n) * DT
    roll = out['roll_rate']
    assert np.abs(roll).max() > 0.1
    first = np.flatnonzero(np.abs(roll) > 0.2 * np.abs(roll).max())[0]
    assert roll[first] > 0.0  # ISO 8855: the left side goes up first
    acc = np.abs(out['wheel_acc'])
    assert acc[1].max() < acc[0].max() / 5  # the right wheels only feel the body
    tau = truth.wheelbase / speed
    front = t[np.argmax(acc[0])]
    rear = t[np.argmax(acc[2])]
    assert rear - front == pytest.approx(tau, abs=3 * DT)
    onset = t[np.flatnonzero(acc[2] > 0.2 * acc[2].max())[0]]
    assert onset >= t0 + tau - DT


def test_hidden_effect_shows_on_its_corner_only():
    case = F.make_full_car_case(3, effects=('strut_friction',), corner='rear_left',
                                duration=4.0)
    assert case.corner == 'rear_left' and case.effects == ('strut_friction',)
    assert case.contributions['strut_friction'] > 1.0
    assert 0.0 <= case.leak['strut_friction'] < case.contributions['strut_friction']
    nominal = F.nominal_full_car()
    for i, name in enumerate(F.CORNERS):
        c = case.truth.corner(name)
        if name == 'rear_left':
            assert c.f_fric > 0.0 and c.effects == ('strut_friction',)
        else:
            assert c.effects == () and c == nominal.corners[i]
        assert set(case.columns[name]) == {'time', 'body_acc', 'wheel_acc', 'stroke',
                                           'current_command', 'coil_current'}
        assert np.mean(case.columns[name]['body_acc']) == pytest.approx(9.81, abs=0.1)
    assert set(case.body) == {'time', 'pitch_rate', 'roll_rate', 'acc_z'}
    again = F.make_full_car_case(3, effects=('strut_friction',), corner='rear_left',
                                 duration=4.0)
    for name in F.CORNERS:
        for key, col in case.columns[name].items():
            assert np.array_equal(col, again.columns[name][key]), (name, key)
    for key, col in case.body.items():
        assert np.array_equal(col, again.body[key]), key
    other = case.unseen(duration=2.0)
    assert other.record == 1 and other.truth == case.truth
    assert not np.array_equal(other.columns['front_left']['stroke'],
                              case.columns['front_left']['stroke'][:other.body['time'].size])


def test_drawn_corner_and_sensor_faults():
    case = F.make_full_car_case(8, effects=('current_delay',), sensor_faults=('acc_bias',),
                                duration=2.0, command='skyhook', spread=0.2)
    hidden = case.corner
    assert hidden in F.CORNERS
    named = F.make_full_car_case(8, effects=('current_delay',), sensor_faults=('acc_bias',),
                                 corner=hidden, duration=2.0, command='skyhook', spread=0.2)
    assert named.truth == case.truth  # naming the drawn corner gives the same car
    for i, name in enumerate(F.CORNERS):
        assert case.sensors[i].faults == (('acc_bias',) if name == hidden else ())
        cmd = case.clean['current_command'][i]
        assert set(np.unique(cmd)) <= {0.0, 1.0}
    assert case.contributions['acc_bias'] > 1.0
    # spread: each corner has its own damper and tyre
    assert len({c.c0 for c in case.truth.corners}) == 4
    assert len({c.k_t for c in case.truth.corners}) == 4


def test_refused_and_unknown_arguments_are_clear():
    with pytest.raises(ValueError, match='top mount'):
        F.make_full_car_case(1, effects=('top_mount',), duration=2.0)
    with pytest.raises(ValueError, match='not available in the full car'):
        F.draw_full_car(np.random.default_rng(0), 'front_left', ('sprung_mass',))
    with pytest.raises(ValueError, match='unknown'):
        F.make_full_car_case(1, effects=('warped_frame',), duration=2.0)
    with pytest.raises(ValueError, match='corner'):
        F.make_full_car_case(1, effects=('bump_stop',), corner='middle', duration=2.0)
    with pytest.raises(ValueError, match='exclude'):
        F.make_full_car_case(1, effects=('current_lag', 'current_lag_asymmetric'))
    with pytest.raises(ValueError, match='sensor faults'):
        F.make_full_car_case(1, sensor_faults=('smoke',))
    with pytest.raises(ValueError, match='duration'):
        F.make_full_car_case(1, duration=0.1)
    with pytest.raises(ValueError, match='seed'):
        F.make_full_car_case(-1)
    truth = F.nominal_full_car()
    with pytest.raises(ValueError, match='top mount'):
        replace(truth, corners=(replace(truth.corners[0], k_tm=1e5),) + truth.corners[1:])
    with pytest.raises(ValueError, match='shape'):
        F.simulate_full_car(truth, _flat(100, truth), np.zeros(100))
    road = cr.bump(0.01, 1.0, 10.0, side='both', duration=1.0, track=1.3, wheelbase=2.3)
    with pytest.raises(ValueError, match='wheelbase'):
        F.simulate_full_car(truth, road, np.zeros(road.z.shape))


def test_bag_round_trip(tmp_path):
    """The bag of a case reads back through diagnose-vehicle's loader, corner by corner.

    The loader wants at least 5 s of data, so the record is 5.5 s.
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import get_typestore, Stores

    from mr_suspension.identification import vehicle_data

    case = F.make_full_car_case(11, effects=('current_lag',), corner='rear_right',
                                duration=5.5, road_class='C')
    bag = write_full_car_bag(case, tmp_path / 'bag')
    (rec,) = vehicle_data.load([bag], namespace='rear_right')
    cols = case.columns['rear_right']
    assert rec.n == cols['time'].size
    np.testing.assert_allclose(rec.body_acc, cols['body_acc'] - vehicle_data.G, atol=1e-6)
    np.testing.assert_allclose(rec.wheel_acc, cols['wheel_acc'] - vehicle_data.G, atol=1e-6)
    np.testing.assert_allclose(rec.stroke, cols['stroke'], atol=1e-12)
    np.testing.assert_allclose(rec.current_command, cols['current_command'], atol=1e-12)
    np.testing.assert_allclose(rec.coil_current, cols['coil_current'], atol=1e-12)
    got = {'t': [], 'pitch': [], 'roll': [], 'acc': []}
    with AnyReader([bag], default_typestore=get_typestore(Stores.LATEST)) as reader:
        conns = [c for c in reader.connections if c.topic == '/body/imu']
        assert len({c.topic for c in reader.connections}) == 4 * 5 + 1
        for conn, _, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            got['t'].append(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9 - 1.0)
            got['pitch'].append(msg.angular_velocity.y)
            got['roll'].append(msg.angular_velocity.x)
            got['acc'].append(msg.linear_acceleration.z)
    np.testing.assert_allclose(got['t'], case.body['time'], atol=1e-9)
    np.testing.assert_allclose(got['pitch'], case.body['pitch_rate'], atol=1e-12)
    np.testing.assert_allclose(got['roll'], case.body['roll_rate'], atol=1e-12)
    np.testing.assert_allclose(got['acc'], case.body['acc_z'], atol=1e-12)
