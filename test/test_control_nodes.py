"""Every control law through the node set in lock-step against the offline simulator.

The plant, controller and actuator nodes run in one executor in exact lock-step (coupling delay
0: the simulator's step order); the controller node sees only the sensors (accelerations with
gravity removed, stroke, coil current) and the control core estimates the velocities. The
offline simulator runs the same corner configuration, so the ride figures must agree to
round-off for every law (laws with internal estimator state included).
"""

import pytest

from mr_suspension.control.laws import LAW_IDS
from mr_suspension.nodes.launch import agreement, corner_config, offline_summary
from mr_suspension.nodes.testing import run_in_process
from mr_suspension.sim import config as cfg
from mr_suspension.sim.stepper import ControllerStepper

ROAD = '{type: bump, height: 0.05, length: 2.0, speed: 10.0}'
DURATION = 1.0
SETS = [name for name in cfg.available('controllers')
        if name not in ('passive_1A',)]        # passive_1A: covered by test_nodes_lockstep


def test_every_law_has_a_set():
    assert {cfg.load_controller(n).law for n in SETS} == set(LAW_IDS)


@pytest.mark.parametrize('controller', SETS)
def test_law_through_node_set_matches_offline(controller):
    nodes, _ = run_in_process(ROAD, DURATION, controller, True, coupling_delay=0)
    offline = offline_summary(corner_config(controller=controller), ROAD, DURATION)
    for key, diff in agreement(nodes, offline).items():
        assert abs(diff) < 1e-6, (controller, key, diff)


@pytest.mark.parametrize('controller', ['skyhook', 'clipped_optimal'])
def test_coil_current_feedback_through_node_set_matches_offline(controller):
    """A law that reads the measured coil current (inverse of a Bouc-Wen model) in lock-step."""
    damper = 'spencer_bouc_wen'
    config = corner_config(controller=controller, damper=damper)
    assert ControllerStepper(config).uses_field
    nodes, _ = run_in_process(ROAD, DURATION, controller, True, coupling_delay=0, damper=damper)
    offline = offline_summary(config, ROAD, DURATION)
    for key, diff in agreement(nodes, offline).items():
        assert abs(diff) < 1e-6, (controller, key, diff)
