"""In-process helpers for the node tests (private context, finite spins, clean shutdown)."""

import contextlib
import os

import rclpy
from rclpy.experimental import EventsExecutor
from rclpy.parameter import Parameter

from mr_suspension.nodes import common


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
