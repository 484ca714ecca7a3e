"""Plant, controller and actuator together, in-process, against the offline simulator."""

import math

import pytest
import yaml

from mr_suspension.core import road as rd
from mr_suspension.core.metrics import rms
from mr_suspension.core.stepper import ActuatorStepper, ControllerStepper, PlantStepper
from mr_suspension.nodes.launch import agreement, corner_config, offline_summary
from mr_suspension.nodes.testing import run_in_process

SCENARIOS = {
    'bump': '{type: bump, height: 0.05, length: 2.0, speed: 10.0}',
    'step': '{type: step, height: 0.05}',
    'iso8608': '{type: iso8608, road_class: C, speed: 20.0, seed: 1}',
}


def stepper_reference(road, duration, controller):
    """Run the core steppers in the node set's order, with sensor-only measurements."""
    cfg = corner_config(controller=controller)
    spec = yaml.safe_load(road)
    plant = PlantStepper(cfg, rd.from_spec(spec, duration=duration, dt=cfg.dt))
    ctl, act = ControllerStepper(cfg), ActuatorStepper(cfg)
    acc, stroke, tyre = [], [], []
    coil = 0.0
    while not plant.done:
        # The IMU carries the specific force: gravity added by the plant, removed by the node.
        g = cfg.car.g
        i = ctl.step((plant.a_s + g) - g, (plant.a_u + g) - g, plant.stroke,
                     coil if plant.k else math.nan)
        coil, _, f, cd = act.step(i, plant.stroke, plant.stroke_rate)
        plant.step(f, cd)
        acc.append(plant.a_s)
        stroke.append(plant.stroke)
        tyre.append(plant.f_t - plant.static_tyre_load)
    return {'body_acc_rms': rms(acc), 'working_space_rms': rms(stroke),
            'tyre_load_rms': rms(tyre)}


@pytest.mark.parametrize('controller', ['passive_1A', 'skyhook_onoff'])
@pytest.mark.parametrize('scenario', sorted(SCENARIOS))
def test_lockstep_reproduces_offline_simulator(scenario, controller):
    """Same step order as the simulator: the figures agree (requirement 2 %, measured 0)."""
    road = SCENARIOS[scenario]
    nodes, late = run_in_process(road, 2.0, controller, True)
    offline = offline_summary(corner_config(controller=controller), road, 2.0)
    assert late == 0
    diffs = agreement(nodes, offline)
    print(scenario, controller, 'lock-step', diffs)
    for key, diff in diffs.items():
        assert abs(diff) < 2.0, (key, diff)


@pytest.mark.parametrize('scenario', ['bump', 'step'])
def test_lockstep_skyhook_equals_core_steppers(scenario):
    """The node set equals the core steppers fed the same sensor values, to rounding."""
    road = SCENARIOS[scenario]
    nodes, _ = run_in_process(road, 2.0, 'skyhook_onoff', True)
    ref = stepper_reference(road, 2.0, 'skyhook_onoff')
    for key in ref:
        assert nodes[key] == pytest.approx(ref[key], rel=1e-9), key


@pytest.mark.parametrize('controller', ['passive_1A', 'skyhook_onoff'])
@pytest.mark.parametrize('scenario', ['bump', 'iso8608'])
def test_realtime_agrees_with_offline(scenario, controller):
    """Real time, one executor for all three nodes (the worst case for late forces).

    What real time changes: late forces (tangent coupling) and one sample of command latency.
    """
    road = SCENARIOS[scenario]
    nodes, late = run_in_process(road, 2.0, controller, False)
    offline = offline_summary(corner_config(controller=controller), road, 2.0)
    diffs = agreement(nodes, offline)
    print(scenario, controller, 'real time, late forces', late, diffs)
    for key, diff in diffs.items():
        assert abs(diff) < 2.0, (key, diff)
