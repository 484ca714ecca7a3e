"""In-process helpers for the node tests (private context, finite spins, clean shutdown)."""

import contextlib
import os

import rclpy
from rclpy.experimental import EventsExecutor
from rclpy.parameter import Parameter

from mr_suspension.core.metrics import rms
from mr_suspension.nodes import common
from mr_suspension.nodes.actuator import ActuatorNode
from mr_suspension.nodes.controller import ControllerNode
from mr_suspension.nodes.plant import PlantNode


@contextlib.contextmanager
def ros_context():
    """Yield ``(context, executor)`` on a private context with discovery off (no cross-talk)."""
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'OFF'
    common.ensure_environment()
    context = rclpy.Context()
    rclpy.init(context=context)
    executor = EventsExecutor(context=context)
    nodes = []
    try:
        yield context, executor, nodes
    finally:
        for node in nodes:
            if hasattr(node, 'close'):
                node.close()
            node.destroy_node()
        rclpy.try_shutdown(context=context)


def params(**values):
    """Parameter overrides from keyword arguments."""
    return [Parameter(k, value=v) for k, v in values.items()]


def add(executor, nodes, node):
    """Add ``node`` to the executor and the list closed at the end; return it."""
    executor.add_node(node)
    nodes.append(node)
    return node


def run_in_process(road, duration, controller, lockstep, coupling_delay=None, damper=None,
                   watchdog_timeout=None, **plant_params):
    """Run plant, controller and actuator in one executor; return (summary, plant counters).

    The summary has the RMS body acceleration, working space and dynamic tyre load of the
    plant's samples, as :func:`mr_suspension.nodes.launch.offline_summary` has them; the
    counters are the plant's late forces, re-sends and repeated forces. ``coupling_delay``
    (plant and actuator; default from ``config/nodes``); ``damper`` (all nodes; default from
    ``config/nodes``); ``watchdog_timeout`` [s] replaces the controller's ``sensor_timeout``
    and the actuator's ``command_timeout`` (default from ``config/nodes``); ``plant_params``
    override further plant parameters (``resend_after``, ...).
    """
    common_p = {'lockstep': lockstep, 'controller': controller}
    if damper is not None:
        common_p['damper'] = damper
    if coupling_delay is not None:
        plant_params['coupling_delay'] = coupling_delay
    act_p = {} if coupling_delay is None else {'coupling_delay': coupling_delay}
    ctl_p = {}
    if watchdog_timeout is not None:
        ctl_p['sensor_timeout'] = watchdog_timeout
        act_p['command_timeout'] = watchdog_timeout
    with ros_context() as (ctx, ex, nodes):
        plant = add(ex, nodes, PlantNode(context=ctx, parameter_overrides=params(
            road=road, duration=duration, start_delay=0.05, exit_at_end=False, **common_p,
            **plant_params)))
        acc, stroke, tyre = [], [], []

        def record(_step=plant._advance):
            _step()
            p = plant.plant
            acc.append(p.a_s)
            stroke.append(p.stroke)
            tyre.append(p.f_t - p.static_tyre_load)

        plant._advance = record
        ctl_params = params(**common_p, **ctl_p)
        add(ex, nodes, ControllerNode(context=ctx, parameter_overrides=ctl_params))
        act_params = params(**common_p, **act_p)
        add(ex, nodes, ActuatorNode(context=ctx, parameter_overrides=act_params))
        if not common.spin_until(ex, lambda: plant.plant.done, 60.0):
            raise TimeoutError('node set did not finish within 60 s')
        counters = {'late_forces': plant.late_forces, 'resends': plant.n_resends,
                    'duplicate_forces': plant.n_duplicates}
    return {'body_acc_rms': rms(acc), 'working_space_rms': rms(stroke),
            'tyre_load_rms': rms(tyre)}, counters
