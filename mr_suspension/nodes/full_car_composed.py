"""The full-car node set composed into one process: one events executor for all its nodes.

``full_car_composed [--modal] --ros-args --params-file <file>`` builds the full-car plant, the
four corner controllers (or with ``--modal`` the modal controller) and the four actuators in
their namespaces (as ``launch/full_car.launch.py`` places them) in one process and spins them
in one events executor, until the plant has finished the road. The nodes, topics and parameters
are those of the separate processes (a parameter file keyed by the nodes' full names, e.g.
``/front_left/controller``, reaches each node); what changes is that no message crosses a
process boundary and one interpreter does all the work, which is what keeps 1 kHz real time
on a small machine (``docs/nodes.md``, Full car). Run the recorder as a process of its own
beside it (it takes its messages in batches at a lower priority).
"""

import sys

from rclpy.utilities import remove_ros_args

from mr_suspension.nodes import common, contract as c

NODE = 'full_car_plant'  # the node whose end ends the process


def builders(modal=False):
    """Return the builders of the nodes, callables of a context, in the order they are built.

    The plant first (its end ends the process), then the controllers and the actuators.
    """
    from mr_suspension.nodes.actuator import ActuatorNode
    from mr_suspension.nodes.controller import ControllerNode
    from mr_suspension.nodes.full_car_plant import FullCarPlantNode
    from mr_suspension.nodes.modal_controller import ModalControllerNode
    out = [lambda ctx: FullCarPlantNode(context=ctx)]
    if modal:
        out.append(lambda ctx: ModalControllerNode(context=ctx))
    else:
        out += [lambda ctx, ns=corner: ControllerNode(context=ctx, namespace=ns)
                for corner in c.CORNERS]
    out += [lambda ctx, ns=corner: ActuatorNode(context=ctx, namespace=ns)
            for corner in c.CORNERS]
    return out


def main(args=None):
    """Console script ``full_car_composed``."""
    args = list(sys.argv if args is None else args)
    own = remove_ros_args(args)[1:]
    unknown = [a for a in own if a != '--modal']
    if unknown:
        raise SystemExit(f'full_car_composed: unknown arguments {unknown}; usage: '
                         'full_car_composed [--modal] --ros-args ...')
    return common.run_composed(builders('--modal' in own), args)


if __name__ == '__main__':
    main()
