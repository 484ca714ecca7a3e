"""Each node alone, spun in-process: publish its inputs, check its outputs."""

import math
import time

import pytest
from rclpy.node import Node
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Float64

from mr_suspension.core import road as rd
from mr_suspension.nodes import common, contract as c
from mr_suspension.nodes.actuator import ActuatorNode
from mr_suspension.nodes.controller import ControllerNode
from mr_suspension.nodes.launch import corner_config
from mr_suspension.nodes.plant import parse_road, PlantNode
from mr_suspension.nodes.testing import add, params, ros_context
from mr_suspension.sim.stepper import ActuatorStepper, ControllerStepper, PlantStepper


class Harness(Node):
    """Test peer: publishes and records any contract topics."""

    def __init__(self, context, pubs=(), subs=(), lockstep=False):
        super().__init__('harness', context=context)
        self.pubs = {t: self.create_publisher(_cls(t), t, common.qos(t, lockstep)) for t in pubs}
        self.got = {t: [] for t in subs}
        for t in subs:
            self.create_subscription(_cls(t), t, self.got[t].append, common.qos(t, lockstep))


def _cls(topic):
    return {c.IMU: Imu, c.JOINT_STATE: JointState, c.FLOAT64: Float64}[c.TOPICS[topic].type]


def _imu(ns, acc):
    m = Imu()
    common.set_stamp(m.header, ns)
    m.linear_acceleration.z = acc
    return m


def _joint(ns, pos, vel=None, names=None):
    m = JointState()
    common.set_stamp(m.header, ns)
    m.name = names or [c.JOINT_STROKE]
    m.position = list(pos)
    m.velocity = list(vel or [])
    return m


def test_plant_alone_lockstep_matches_stepper():
    """The plant answers each damper force with the next sample, as the core stepper does."""
    c_lin = 1500.0
    with ros_context() as (ctx, ex, nodes):
        plant = add(ex, nodes, PlantNode(context=ctx, parameter_overrides=params(
            lockstep=True, duration=0.2, start_delay=0.0, exit_at_end=False,
            road='{type: step, height: 0.03, t0: 0.01}')))
        # The harness stands in for controller and actuator (every link must be discovered).
        h = add(ex, nodes, Harness(ctx, pubs=(c.DAMPER_FORCE, c.CURRENT_COMMAND, c.COIL_CURRENT),
                                   subs=(c.IMU_BODY, c.TRUTH_STATE, c.CURRENT_COMMAND,
                                         c.STROKE, c.IMU_WHEEL, c.COIL_CURRENT),
                                   lockstep=True))

        def answer(msg):
            v = msg.velocity[3]
            out = _joint(common.stamp_to_ns(msg.header.stamp), [msg.position[3], 0.0], [v, 0.0],
                         list(c.JOINTS_DAMPER))
            out.effort = [c_lin * v, c_lin]
            h.pubs[c.DAMPER_FORCE].publish(out)

        h.create_subscription(JointState, c.TRUTH_STATE, answer,
                              common.qos(c.TRUTH_STATE, True))
        assert common.spin_until(ex, lambda: plant.plant.done, 20.0)
        common.spin_until(ex, lambda: len(h.got[c.IMU_BODY]) > 200, 2.0)
    ref = PlantStepper(plant.config, rd.step(height=0.03, t0=0.01, duration=0.2))
    acc = []
    while not ref.done:
        v = ref.stroke_rate
        ref.step(c_lin * v, c_lin)
        acc.append(ref.a_s)
    got = [m.linear_acceleration.z - plant.gravity for m in h.got[c.IMU_BODY]]
    assert len(got) == 201
    assert got[0] == 0.0
    assert max(abs(a - b) for a, b in zip(got[1:], acc)) < 1e-9
    assert h.got[c.IMU_BODY][0].header.frame_id == c.FRAME_BODY_IMU


def test_controller_alone_lockstep_runs_the_law():
    cfg = corner_config()
    ref = ControllerStepper(cfg)
    with ros_context() as (ctx, ex, nodes):
        add(ex, nodes, ControllerNode(context=ctx, parameter_overrides=params(lockstep=True)))
        h = add(ex, nodes, Harness(ctx, pubs=(c.IMU_BODY, c.IMU_WHEEL, c.STROKE,
                                              c.COIL_CURRENT), subs=(c.CURRENT_COMMAND,),
                                   lockstep=True))
        assert common.spin_until(ex, lambda: h.pubs[c.STROKE].get_subscription_count(), 5.0)
        expect = []
        for k in range(50):
            ns = k * 1_000_000
            a_s, a_u, x = math.sin(0.3 * k), math.cos(0.2 * k), 0.01 * math.sin(0.1 * k)
            expect.append(ref.step(a_s + 9.81 - 9.81, a_u + 9.81 - 9.81, x,
                                   0.5 if k else math.nan))
            h.pubs[c.IMU_BODY].publish(_imu(ns, a_s + 9.81))
            h.pubs[c.IMU_WHEEL].publish(_imu(ns, a_u + 9.81))
            h.pubs[c.STROKE].publish(_joint(ns, [x]))
            h.pubs[c.COIL_CURRENT].publish(Float64(data=0.5))
        assert common.spin_until(ex, lambda: len(h.got[c.CURRENT_COMMAND]) >= 50, 10.0)
    got = [m.data for m in h.got[c.CURRENT_COMMAND]]
    assert got == expect
    assert len(set(got)) == 2  # on-off skyhook switched


def test_controller_falls_back_on_stale_sensors():
    with ros_context() as (ctx, ex, nodes):
        ctl = add(ex, nodes, ControllerNode(context=ctx, parameter_overrides=params(
            lockstep=False, sensor_timeout=0.02, fallback_current=1.25,
            controller='passive_0A')))
        h = add(ex, nodes, Harness(ctx, pubs=(c.IMU_BODY, c.IMU_WHEEL, c.STROKE),
                                   subs=(c.CURRENT_COMMAND,)))
        assert common.spin_until(ex, lambda: h.pubs[c.STROKE].get_subscription_count(), 5.0)
        # No sensors yet: fallback from the start.
        assert common.spin_until(ex, lambda: len(h.got[c.CURRENT_COMMAND]) > 5, 5.0)
        assert h.got[c.CURRENT_COMMAND][-1].data == 1.25
        assert ctl.fallback
        # Fresh sensors: the law (0 A) runs.
        end = time.monotonic() + 0.3
        k = 0
        while time.monotonic() < end:
            k = time.time_ns()  # real time: stamps are acquisition (wall) times
            for pub, msg in ((c.IMU_BODY, _imu(k, 9.81)), (c.IMU_WHEEL, _imu(k, 9.81)),
                             (c.STROKE, _joint(k, [0.0]))):
                h.pubs[pub].publish(msg)
            common.spin_until(ex, lambda: False, 0.002, step=0.002)
        assert not ctl.fallback
        assert h.got[c.CURRENT_COMMAND][-1].data == 0.0
        # Sensors stop: fallback within the timeout (plus scheduling slack).
        n0 = len(h.got[c.CURRENT_COMMAND])
        t_stop = time.monotonic()
        assert common.spin_until(ex, lambda: ctl.fallback, 2.0)
        assert time.monotonic() - t_stop < 0.02 + 0.1
        assert common.spin_until(ex, lambda: len(h.got[c.CURRENT_COMMAND]) > n0 + 30, 5.0)
        assert h.got[c.CURRENT_COMMAND][-1].data == 1.25
        # A NaN sensor value also gives the fallback, not a crash.
        k = time.time_ns()
        for pub, msg in ((c.IMU_BODY, _imu(k, math.nan)), (c.IMU_WHEEL, _imu(k, 9.81)),
                         (c.STROKE, _joint(k, [0.0]))):
            h.pubs[pub].publish(msg)
        common.spin_until(ex, lambda: False, 0.01)
        assert h.got[c.CURRENT_COMMAND][-1].data == 1.25
        # Samples that are older than the timeout by their stamp (a queue worked off late)
        # are dropped, not controlled on.
        old = time.time_ns() - 1_000_000_000
        for j in range(20):
            for pub, msg in ((c.IMU_BODY, _imu(old + j, 9.81)), (c.IMU_WHEEL, _imu(old + j, 9.81)),
                             (c.STROKE, _joint(old + j, [0.0]))):
                h.pubs[pub].publish(msg)
        assert common.spin_until(ex, lambda: ctl.n_dropped >= 60, 2.0)
        common.spin_until(ex, lambda: False, 0.03)
        assert ctl.fallback and h.got[c.CURRENT_COMMAND][-1].data == 1.25


def test_actuator_rejects_and_clamps_invalid_commands():
    cfg = corner_config()
    with ros_context() as (ctx, ex, nodes):
        act = add(ex, nodes, ActuatorNode(context=ctx, parameter_overrides=params(
            lockstep=True, current_max=2.0, coupling_delay=0)))
        h = add(ex, nodes, Harness(ctx, pubs=(c.CURRENT_COMMAND, c.TRUTH_STATE),
                                   subs=(c.DAMPER_FORCE, c.COIL_CURRENT), lockstep=True))
        assert common.spin_until(
            ex, lambda: h.pubs[c.CURRENT_COMMAND].get_subscription_count(), 5.0)
        commands = [0.5, math.nan, 5.0, -1.0, math.inf, 1.0]
        applied = [0.5, 0.5, 2.0, 0.0, 0.0, 1.0]
        ref = ActuatorStepper(cfg)
        expect = []
        for k, cmd in enumerate(commands):
            x, v = 0.001 * k, 0.05 * (-1) ** k
            expect.append(ref.step(applied[k], x, v))
            h.pubs[c.CURRENT_COMMAND].publish(Float64(data=cmd))
            h.pubs[c.TRUTH_STATE].publish(_joint(k * 1_000_000, [0, 0, 0, x], [0, 0, 0, v],
                                                 list(c.JOINTS_TRUTH)))
        assert common.spin_until(ex, lambda: len(h.got[c.DAMPER_FORCE]) >= 6, 10.0)
        assert act.n_rejected == 2 and act.n_clamped == 2
    forces = h.got[c.DAMPER_FORCE]
    for k, (msg, (coil, _, force, tangent)) in enumerate(zip(forces, expect)):
        assert list(msg.name) == list(c.JOINTS_DAMPER)
        assert common.stamp_to_ns(msg.header.stamp) == k * 1_000_000
        assert msg.effort[0] == force and msg.effort[1] == tangent
        assert h.got[c.COIL_CURRENT][k].data == coil


@pytest.mark.parametrize('trigger', ['sample', 'timer'])
def test_controller_with_unsynchronised_sensor_stamps(trigger):
    """Stamps that never match: the sample trigger falls back, the timer trigger runs the law."""
    with ros_context() as (ctx, ex, nodes):
        ctl = add(ex, nodes, ControllerNode(context=ctx, parameter_overrides=params(
            lockstep=False, trigger=trigger, sensor_timeout=0.02, fallback_current=1.25,
            controller='passive_0A')))
        h = add(ex, nodes, Harness(ctx, pubs=(c.IMU_BODY, c.IMU_WHEEL, c.STROKE),
                                   subs=(c.CURRENT_COMMAND,)))
        assert common.spin_until(ex, lambda: h.pubs[c.STROKE].get_subscription_count(), 5.0)
        end = time.monotonic() + 0.3
        k = 0
        while time.monotonic() < end:
            k = time.time_ns()
            h.pubs[c.IMU_BODY].publish(_imu(k, 9.81))
            h.pubs[c.IMU_WHEEL].publish(_imu(k + 300_000, 9.81))
            h.pubs[c.STROKE].publish(_joint(k + 600_000, [0.0]))
            common.spin_until(ex, lambda: False, 0.002, step=0.002)
        assert ctl.fallback == (trigger == 'sample')
        assert h.got[c.CURRENT_COMMAND][-1].data == (1.25 if trigger == 'sample' else 0.0)


def test_plant_road_parameter_forms():
    assert parse_road('bump') == {'type': 'bump'}
    assert parse_road('iso8608:road_class=C,speed=20') == {
        'type': 'iso8608', 'road_class': 'C', 'speed': 20}
    assert parse_road('{type: step, height: 0.05}') == {'type': 'step', 'height': 0.05}
    with pytest.raises(ValueError):
        parse_road('step:height')
