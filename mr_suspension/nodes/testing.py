"""In-process helpers for the node tests (private context, finite spins, clean shutdown)."""

import contextlib
import os

import rclpy
from rclpy.experimental import EventsExecutor
from rclpy.parameter import Parameter

from mr_suspension.core.metrics import rms
from mr_suspension.nodes import common
from mr_suspension.nodes import contract as c
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


def full_car_in_process(ctx, ex, nodes, road, duration, controller=None, modal=False,
                        lockstep=True, coupling_delay=None, corner_params=None,
                        modal_params=None, **plant_params):
    """Build the full-car node set in one executor; return ``(plant, controllers, actuators)``.

    Full-car plant, four corner controllers (or with ``modal`` the modal controller, returned
    as the only controller) and four actuators in their corner namespaces, with the parameters
    ``mr-suspension nodes --full-car`` gives them. ``corner_params`` (controllers and
    actuators), ``modal_params`` and ``plant_params`` add parameters. The plant records its
    figures per step in ``plant.figures`` (see :func:`full_car_figures`).
    """
    from mr_suspension.nodes.full_car_plant import FullCarPlantNode
    from mr_suspension.nodes.modal_controller import ModalControllerNode
    if controller is None:
        controller = 'skyhook' if modal else 'skyhook_onoff'
    model = {'lockstep': lockstep, 'controller': controller}
    loop = {} if coupling_delay is None else {'coupling_delay': coupling_delay}
    plant = add(ex, nodes, FullCarPlantNode(context=ctx, parameter_overrides=params(
        road=road, duration=duration, start_delay=0.05, exit_at_end=False,
        body_imu_subscribers=int(modal), **model, **loop, **plant_params)))
    plant.figures = []

    def record(_step=plant._advance):
        _step()
        p = plant.plant
        plant.figures.append(p.imu() + tuple(
            v for i in range(4) for v in (p.a_s(i), p.stroke(i),
                                          p.f_t[i] - p.static_tyre_load[i])))

    plant._advance = record
    vehicle = plant.get_parameter('vehicle').value
    given = {k: plant.get_parameter(k).value for k in ('damper', 'driver')}
    sets = {k: common.corner_sets(v, k) for k, v in given.items()}
    ctls, acts = [], []
    if modal:
        ctls.append(add(ex, nodes, ModalControllerNode(context=ctx, parameter_overrides=params(
            **dict(model, **given, **(modal_params or {}))))))
    for i, corner in enumerate(c.CORNERS):
        corner_p = dict(model, vehicle=common.corner_vehicle(vehicle, corner),
                        damper=sets['damper'][i], driver=sets['driver'][i],
                        **(corner_params or {}))
        if not modal:
            ctls.append(add(ex, nodes, ControllerNode(
                context=ctx, namespace=corner, parameter_overrides=params(**corner_p))))
        acts.append(add(ex, nodes, ActuatorNode(
            context=ctx, namespace=corner, parameter_overrides=params(**dict(corner_p, **loop)))))
    return plant, ctls, acts


def full_car_figures(plant):
    """Figures of :func:`mr_suspension.nodes.launch.full_car_offline` from the plant's steps."""
    import numpy as np
    data = np.array(plant.figures)
    out = {'heave_acc_rms': rms(data[:, 0]), 'pitch_rate_rms': rms(data[:, 1]),
           'roll_rate_rms': rms(data[:, 2])}
    for i, tag in enumerate(('fl', 'fr', 'rl', 'rr')):
        for j, name in enumerate(('body_acc_rms', 'working_space_rms', 'tyre_load_rms')):
            out[f'{name}_{tag}'] = rms(data[:, 3 + 3 * i + j])
    return out
