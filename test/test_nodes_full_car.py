"""The full-car node set in-process: equal to the offline full-car simulator, fail-safe per corner.

Full-car plant, four corner controllers (or the modal controller) and four actuators in their
corner namespaces, spun in one executor on a private context.
"""

import math
import time

import numpy as np
import pytest
from rclpy.exceptions import InvalidParameterValueException
from sensor_msgs.msg import Imu

from mr_suspension.control.modal import ModalParams
from mr_suspension.nodes import cdr, common, contract as c
from mr_suspension.nodes.full_car_plant import body_imu_template, FullCarPlantNode
from mr_suspension.nodes.launch import agreement, full_car_offline, full_car_road
from mr_suspension.nodes.modal_controller import ModalControllerNode
from mr_suspension.nodes.recorder import RecorderNode
from mr_suspension.nodes.testing import full_car_figures, full_car_in_process, params
from mr_suspension.nodes.testing import ros_context
from mr_suspension.sim.full_car_stepper import FullCarPlantStepper, ModalControllerStepper
from mr_suspension.sim.stepper import ActuatorStepper, ControllerStepper

ROAD = '{type: bump, height: 0.04, length: 1.0, speed: 10.0, t0: 0.1, side: left}'
ISO = '{type: iso8608, road_class: C, speed: 15.0, seed: 3}'
SAFE = 1.0


def _offline(modal, road, duration):
    cfg = common.full_car_config(controller='skyhook' if modal else 'skyhook_onoff',
                                 modal=ModalParams() if modal else None)
    return full_car_offline(cfg, road, duration)


def stepper_reference(modal, road, duration, delay):
    """Run the core steppers in the lock-step node set's order, ``coupling_delay`` ``delay``.

    Sensors as the nodes see them (gravity added by the plant, removed by the controller);
    step ``k -> k + 1`` takes each corner's force of sample ``max(k - delay, 0)`` moved along
    its tangent, evaluated with the field current of the sample it is applied to.
    """
    cfg = common.full_car_config(controller='skyhook' if modal else 'skyhook_onoff',
                                 modal=ModalParams() if modal else None)
    plant = FullCarPlantStepper(cfg, full_car_road(road, duration, cfg))
    acts = [ActuatorStepper(cfg.corner(i)) for i in range(4)]
    law = ModalControllerStepper(cfg) if modal else \
        [ControllerStepper(cfg.corner(i)) for i in range(4)]
    law_uses_field = law.uses_field if modal else law[0].uses_field
    g = cfg.car.front.g
    coil, history, rows = [math.nan] * 4, [], []
    while not plant.done:
        # (the field slot: the measured coil current, for laws whose model reads it)
        field = [coil[i] if plant.k and law_uses_field else math.nan for i in range(4)]
        meas = [((plant.a_s(i) + g) - g, (plant.a_u(i) + g) - g, plant.stroke(i), field[i])
                for i in range(4)]
        if modal:
            a_z, w_pitch, w_roll = plant.imu()
            cmds = law.step(((a_z + g) - g, w_pitch, w_roll), meas)
        else:
            cmds = [law[i].step(*meas[i]) for i in range(4)]
        forces = []
        for i in range(4):
            x, v = plant.motion(i)
            coil[i], _, f, c_d = acts[i].force(x, v, delay)
            acts[i].command(cmds[i])
            forces.append((f, c_d, v))
        history.append(forces)
        used = history[max(plant.k - delay, 0)]
        plant.step([plant.coupled(i, *used[i]) for i in range(4)], [u[1] for u in used])
        rows.append(plant.imu() + tuple(
            v for i in range(4) for v in (plant.a_s(i), plant.stroke(i),
                                          plant.f_t[i] - plant.static_tyre_load[i])))
    return rows


def _run(modal, road, duration, delay):
    with ros_context() as (ctx, ex, nodes):
        plant, _, _ = full_car_in_process(ctx, ex, nodes, road, duration, modal=modal,
                                          coupling_delay=delay)
        assert common.spin_until(ex, lambda: plant.plant.done, 60.0)
        assert plant.late_forces == 0
    return plant


@pytest.mark.parametrize('modal, road', [(False, ROAD), (True, ROAD), (False, ISO)])
def test_lockstep_full_car_equals_offline(modal, road):
    """Exact lock-step (coupling delay 0) is the offline full-car simulator to round-off."""
    plant = _run(modal, road, 1.0, 0)
    diffs = agreement(full_car_figures(plant), _offline(modal, road, 1.0))
    print('modal' if modal else 'corner controllers', road, max(abs(d) for d in diffs.values()))
    assert len(diffs) == 15
    for key, diff in diffs.items():
        assert abs(diff) < 1e-6, (key, diff)


@pytest.mark.parametrize('modal, road', [(True, ISO), (False, ROAD)])
def test_lockstep_one_sample_coupling_equals_core_steppers(modal, road):
    """Coupling delay 1 (plant and actuators concurrent) equals the steppers run so."""
    plant = _run(modal, road, 1.0, 1)
    ref = stepper_reference(modal, road, 1.0, 1)
    assert len(plant.figures) == len(ref)
    got = np.array(plant.figures)
    ref = np.array(ref)
    scale = np.abs(ref).max(axis=0) + 1e-300
    assert (np.abs(got - ref).max(axis=0) / scale).max() < 1e-9


class VirtualClock:
    """Fault clock of the nodes: advances one step per plant step (simulated time)."""

    def __init__(self):
        self.t = time.monotonic()

    def __call__(self):
        return self.t


def _virtual_time(plant, nodes, at_step=None, watchdogs=()):
    """Give ``nodes`` a fault clock that follows the plant's steps; call ``at_step[k](now)``.

    ``watchdogs`` are also called every 5 ms of that clock (their timers run on wall time).
    """
    clock = VirtualClock()
    for node in nodes:
        node.clock = clock

    def step(_advance=plant._advance):
        _advance()
        clock.t += plant.dt
        k = plant.plant.k
        action = (at_step or {}).get(k)
        if action is not None:
            action(clock())
        if k % 5 == 0:
            for watchdog in watchdogs:
                watchdog()

    plant._advance = step
    return clock


def test_silenced_corner_controller_gives_that_corner_its_safe_current():
    """Controllers and actuators in real time on the plant's simulated time (lock-step plant).

    The front-left controller stops publishing at sample 300: its actuator applies its safe
    current within command_timeout + 1 sample (26 ms), the other three corners keep their
    controllers' commands and the plant runs to the end of the road.
    """
    silenced = {}

    def silence(now):
        ctls[0]._publish = lambda i_cmd, now: None
        silenced['t'] = now
        silenced['commands'] = [a.n_commands for a in acts]

    with ros_context() as (ctx, ex, nodes):
        plant, ctls, acts = full_car_in_process(
            ctx, ex, nodes, ROAD, 0.6, coupling_delay=0,
            # (the controllers read the plant's /clock: stamp checks on simulated time)
            corner_params={'lockstep': False, 'use_sim_time': True},
            controller='skyhook_onoff')
        _virtual_time(plant, ctls + acts, {300: silence},
                      [n._on_tick for n in ctls] + [a._on_watchdog for a in acts])
        assert common.spin_until(ex, lambda: plant.plant.done, 60.0)
        front_left, others = acts[0], acts[1:]
        assert front_left.health.fallback and front_left.applied == SAFE
        assert 'command' in front_left.health.faults
        assert front_left.health.entered - silenced['t'] <= 0.026 + 1e-9
        assert front_left.health.episodes == 2  # start-up, then the silence
        for i, act in enumerate(others, start=1):
            assert not act.health.fallback and act.health.episodes == 1, c.CORNERS[i]
            assert act.n_commands - silenced['commands'][i] >= 290  # still commanded
            assert not ctls[i].fallback
        assert plant.plant.k == plant.road.n_steps and plant.late_forces == 0


def test_modal_controller_corner_fault_is_that_corners_alone(monkeypatch):
    """Real-time modal controller: front-left stroke sensor silent from sample 300.

    Front left goes to the fallback current (stale, within sensor_timeout + watchdog_period),
    the other corners keep the modal law (their commands are not the fallback current and keep
    changing) and the body IMU keeps them running.
    """
    cut = {'k': None}

    def drop_from(now):
        cut['k'] = 300
        cut['t'] = now

    stroke = ModalControllerNode._on_stroke

    def on_stroke(self, i, topic, raw):
        if cut['k'] is None or i != 0:
            stroke(self, i, topic, raw)

    monkeypatch.setattr(ModalControllerNode, '_on_stroke', on_stroke)
    with ros_context() as (ctx, ex, nodes):
        plant, ctls, acts = full_car_in_process(
            ctx, ex, nodes, ROAD, 0.6, modal=True, coupling_delay=0,
            corner_params={'lockstep': False, 'safe_current': SAFE},
            modal_params={'lockstep': False, 'use_sim_time': True,
                          'fallback_current': SAFE})
        modal = ctls[0]
        # The plant runs lock-step only to drive simulated time: no parameter check with it.
        modal.peers.clients.pop('full_car_plant')
        sent = []
        pub = modal._publish

        def record(i, i_cmd, now):
            sent.append((now, i, i_cmd))
            pub(i, i_cmd, now)

        modal._publish = record
        _virtual_time(plant, [modal] + acts, {300: drop_from},
                      [modal._on_tick] + [a._on_watchdog for a in acts])
        assert common.spin_until(ex, lambda: plant.plant.done, 60.0)
        h = modal.health
        assert h[0].fallback and 'stale' in h[0].faults
        assert h[0].entered - cut['t'] <= 0.020 + 0.005 + 0.001 + 1e-9
        assert not any(x.fallback for x in h[1:])
        late = [(i, v) for t, i, v in sent if t > cut['t'] + 0.05]
        assert late and all(v == SAFE for i, v in late if i == 0)
        for i in (1, 2, 3):
            values = {v for j, v in late if j == i}
            assert len(values) > 5, (i, values)  # the law, not a fixed current
        assert not any(a.health.fallback for a in acts)


def test_body_imu_wire_format():
    tpl = body_imu_template()
    raw = tpl.pack(1_234_000_000, 0.25, -0.5, 9.9)
    assert cdr.imu_body(raw) == (1_234_000_000, 0.25, -0.5, 9.9)
    msg = cdr.typestore().deserialize_cdr(raw, c.IMU)
    assert (msg.angular_velocity.x, msg.angular_velocity.y, msg.linear_acceleration.z) == \
        (0.25, -0.5, 9.9)
    assert msg.header.frame_id == c.FRAME_BODY_IMU_CG
    assert msg.orientation_covariance[0] == -1.0
    from rclpy.serialization import deserialize_message
    assert deserialize_message(raw, Imu).angular_velocity.y == -0.5


@pytest.mark.parametrize('node, overrides, error, match', [
    ('plant', {'vehicle': 'city_car'}, ValueError, 'is a quarter car'),
    ('plant', {'road': 'cobbles'}, ValueError, 'car road type'),
    ('plant', {'road': '{type: bump, side: middle}'}, ValueError, 'side'),
    ('plant', {'duration': -1.0}, InvalidParameterValueException, 'duration'),
    ('modal', {'c_heave': -5.0}, InvalidParameterValueException, 'c_heave'),
    ('modal', {'coil_feedback': 'maybe'}, ValueError, 'coil_feedback'),
    ('modal', {'law': 'nope'}, ValueError, 'unknown law'),
    ('modal', {'controller': 'no_such_law'}, ValueError, 'no_such_law'),
    ('recorder', {'namespaces': 'front_left,front_left'}, ValueError, 'repeat'),
    ('recorder', {'topics': 'body/imu,tyre'}, ValueError, 'unknown topics'),
])
def test_bad_parameters_are_clear(tmp_path, node, overrides, error, match):
    cls = {'plant': FullCarPlantNode, 'modal': ModalControllerNode, 'recorder': RecorderNode}
    if node == 'recorder':
        overrides = dict(overrides, output=str(tmp_path / 'bag'))
    with ros_context() as (ctx, _, _):
        with pytest.raises(error, match=match):
            cls[node](context=ctx, parameter_overrides=params(**overrides))


def test_corner_vehicle_of_a_full_car():
    from mr_suspension.sim.corner import load_vehicle
    cfg = common.full_car_config()
    for i, corner in enumerate(c.CORNERS):
        assert load_vehicle(common.corner_vehicle('lisa_full_car', corner)) == cfg.car.corner(i)
        assert common.corner_config(vehicle=f'lisa_full_car:{corner}') == cfg.corner(i)
    with pytest.raises(ValueError, match='unknown corner'):
        load_vehicle('lisa_full_car:middle')
    with pytest.raises(ValueError, match='name one corner'):
        load_vehicle('lisa_full_car')
    assert math.isclose(cfg.car.corner(0).m_s * 2 + cfg.car.corner(2).m_s * 2, cfg.car.m_b)


def test_lockstep_with_a_damper_and_driver_per_axle_equals_offline():
    """Front and rear on other dampers and drivers: each corner's nodes take their axle's."""
    sets = {'damper': 'rd1005_bingham, seed003_bingham', 'driver': 'wonder_box, ideal'}
    with ros_context() as (ctx, ex, nodes):
        plant, _, acts = full_car_in_process(ctx, ex, nodes, ROAD, 1.0, coupling_delay=0,
                                             **sets)
        assert [a.get_parameter('damper').value for a in acts] == \
            ['rd1005_bingham'] * 2 + ['seed003_bingham'] * 2
        assert common.spin_until(ex, lambda: plant.plant.done, 60.0)
    cfg = common.full_car_config(controller='skyhook_onoff', **sets)
    assert cfg.damper[0] is cfg.damper[1] and cfg.damper[2] != cfg.damper[0]
    diffs = agreement(full_car_figures(plant), full_car_offline(cfg, ROAD, 1.0))
    assert max(abs(d) for d in diffs.values()) < 1e-6
    same = agreement(full_car_figures(plant), _offline(False, ROAD, 1.0))
    assert max(abs(d) for d in same.values()) > 1e-3  # the rear dampers do matter


@pytest.mark.parametrize('value', ['a, b, c', 'a,,b,c', ''])
def test_a_set_per_corner_needs_one_two_or_four_names(value):
    with pytest.raises(ValueError, match='front, rear'):
        common.corner_sets(value)
    assert common.corner_sets('a , b') == ('a', 'a', 'b', 'b')
