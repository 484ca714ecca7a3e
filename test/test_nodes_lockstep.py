"""Plant, controller and actuator together, in-process, against the offline simulator."""

import math

import pytest
import yaml

from mr_suspension.core import road as rd
from mr_suspension.core.metrics import rms
from mr_suspension.nodes.launch import agreement, corner_config, offline_summary
from mr_suspension.nodes.testing import run_in_process
from mr_suspension.sim.stepper import ActuatorStepper, ControllerStepper, PlantStepper

SCENARIOS = {
    'bump': '{type: bump, height: 0.05, length: 2.0, speed: 10.0}',
    'step': '{type: step, height: 0.05}',
    'iso8608': '{type: iso8608, road_class: C, speed: 20.0, seed: 1}',
}


def stepper_reference(road, duration, controller, delay=0):
    """Run the core steppers in the node set's order, with sensor-only measurements.

    Step ``k -> k + 1`` takes the force of sample ``max(k - delay, 0)`` moved along its tangent
    to the present stroke rate, as the lock-step plant node does with ``coupling_delay``; the
    actuator evaluates that force with the field current of the sample it is applied to.
    """
    cfg = corner_config(controller=controller)
    spec = yaml.safe_load(road)
    plant = PlantStepper(cfg, rd.from_spec(spec, duration=duration, dt=cfg.dt))
    ctl, act = ControllerStepper(cfg), ActuatorStepper(cfg)
    acc, stroke, tyre, forces = [], [], [], []
    coil = 0.0
    while not plant.done:
        # The IMU carries the specific force: gravity added by the plant, removed by the node.
        g = cfg.car.g
        i = ctl.step((plant.a_s + g) - g, (plant.a_u + g) - g, plant.stroke,
                     coil if plant.k else math.nan)
        coil, _, f, cd = act.force(plant.stroke, plant.stroke_rate, delay)
        act.command(i)
        forces.append((f, cd, plant.stroke_rate))
        f_m, c_m, v_m = forces[max(plant.k - delay, 0)]
        plant.step(plant.coupled(f_m, c_m, v_m), c_m)
        acc.append(plant.a_s)
        stroke.append(plant.stroke)
        tyre.append(plant.f_t - plant.static_tyre_load)
    return {'body_acc_rms': rms(acc), 'working_space_rms': rms(stroke),
            'tyre_load_rms': rms(tyre)}


@pytest.mark.parametrize('controller', ['passive_1A', 'skyhook_onoff'])
@pytest.mark.parametrize('scenario', sorted(SCENARIOS))
def test_lockstep_reproduces_offline_simulator(scenario, controller):
    """Exact lock-step (delay 0) has the simulator's step order: the figures agree to round-off.

    The default one-sample coupling (delay 1) agrees within 1 % (the requirement is 2 %).
    """
    road = SCENARIOS[scenario]
    offline = offline_summary(corner_config(controller=controller), road, 2.0)
    for delay, tol in ((0, 1e-6), (1, 1.0)):
        nodes, counters = run_in_process(road, 2.0, controller, True, coupling_delay=delay)
        assert counters['late_forces'] == 0
        diffs = agreement(nodes, offline)
        print(scenario, controller, 'lock-step, coupling delay', delay, diffs)
        for key, diff in diffs.items():
            assert abs(diff) < tol, (delay, key, diff)


@pytest.mark.parametrize('delay', [0, 1, 2])
@pytest.mark.parametrize('scenario', ['bump', 'step'])
def test_lockstep_skyhook_equals_core_steppers(scenario, delay):
    """The node set equals the core steppers fed the same sensor values, to rounding."""
    road = SCENARIOS[scenario]
    nodes, _ = run_in_process(road, 2.0, 'skyhook_onoff', True, coupling_delay=delay)
    ref = stepper_reference(road, 2.0, 'skyhook_onoff', delay)
    for key in ref:
        assert nodes[key] == pytest.approx(ref[key], rel=1e-9), key


def test_lockstep_recovers_lost_samples(monkeypatch):
    """A sample lost on a best-effort loop link is re-sent; the run equals an undisturbed one.

    Drops the first delivery of: the damper motion of sample 100 (plant -> actuator), the body
    IMU of sample 200 and the stroke of sample 0 (plant -> controller), the damper force of
    sample 300 (actuator -> plant).
    """
    from mr_suspension.nodes import cdr
    from mr_suspension.nodes.actuator import ActuatorNode
    from mr_suspension.nodes.controller import ControllerNode
    from mr_suspension.nodes.plant import PlantNode
    road = SCENARIOS['bump']
    ref, _ = run_in_process(road, 1.0, 'skyhook_onoff', True)
    drops = {('motion', 100), ('imu', 200), ('stroke', 0), ('force', 300)}

    def dropping(cls, name, label, read_stamp):
        method = getattr(cls, name)

        def wrapper(self, raw):
            key = (label, round(read_stamp(raw) / 1e6))
            if key in drops:
                drops.discard(key)
                return None
            return method(self, raw)
        monkeypatch.setattr(cls, name, wrapper)

    dropping(ActuatorNode, '_on_motion', 'motion', lambda raw: cdr.joint_state(raw)[0])
    dropping(ControllerNode, '_on_imu_s', 'imu', lambda raw: cdr.imu_acc_z(raw)[0])
    dropping(ControllerNode, '_on_stroke', 'stroke', lambda raw: cdr.joint_state(raw)[0])
    dropping(PlantNode, '_on_force', 'force', lambda raw: cdr.joint_state(raw)[0])
    got, counters = run_in_process(road, 1.0, 'skyhook_onoff', True, resend_after=0.01)
    assert not drops, drops
    assert counters['resends'] >= 4
    for key in ref:
        assert got[key] == pytest.approx(ref[key], rel=1e-12), key


@pytest.mark.parametrize('controller', ['passive_1A', 'skyhook_onoff'])
@pytest.mark.parametrize('scenario', ['bump', 'iso8608'])
def test_realtime_agrees_with_offline(scenario, controller):
    """Real time, one executor for all three nodes (the worst case for late forces).

    What real time changes: late forces (tangent coupling) and one sample of command latency.
    The watchdogs are widened to 0.5 s: a host that stalls the executor for tens of
    milliseconds would otherwise (correctly) put the node set into its fallback current, a
    change of control law that the fail-safe tests judge, not this one.
    """
    road = SCENARIOS[scenario]
    nodes, counters = run_in_process(road, 2.0, controller, False, watchdog_timeout=0.5)
    offline = offline_summary(corner_config(controller=controller), road, 2.0)
    diffs = agreement(nodes, offline)
    print(scenario, controller, 'real time, late forces', counters['late_forces'], diffs)
    for key, diff in diffs.items():
        assert abs(diff) < 2.0, (key, diff)


@pytest.mark.parametrize('after_force', [True, False])
def test_realtime_agrees_with_either_sensor_order(after_force):
    """Sensors held back until the force is in (default) or published at once: within 2 %.

    Watchdogs widened as in :func:`test_realtime_agrees_with_offline`.
    """
    road = SCENARIOS['bump']
    nodes, counters = run_in_process(road, 1.0, 'skyhook_onoff', False, watchdog_timeout=0.5,
                                     sensors_after_force=after_force)
    offline = offline_summary(corner_config(controller='skyhook_onoff'), road, 1.0)
    for key, diff in agreement(nodes, offline).items():
        assert abs(diff) < 2.0, (after_force, key, diff)
