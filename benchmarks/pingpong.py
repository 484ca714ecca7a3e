"""Middleware reference for the node-set benchmark: a Float64 ping-pong between two processes.

Each process answers every message it receives with one of its own (raw ``std_msgs/Float64``,
reliable writer, best-effort reader, the events executor: the node set's lock-step setup), so a
round trip is two message hops. Prints one JSON line per process with the wall time per round
trip and the CPU time per message (one received plus one published). That cost is what the
lock-step loop pays per message, so CPU per lock-step step divided by it says how many message
hops' worth of work a step takes, on a quiet machine or a loaded one.

Run by ``bench_nodes.middleware_reference``; by hand:
``python benchmarks/pingpong.py b 5000 & python benchmarks/pingpong.py a 5000``
(same ``ROS_DOMAIN_ID``).
"""

import json
import sys
import threading
import time

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from mr_suspension.nodes import cdr, common


def main(argv=None):
    """Play side ``a`` (serves first) or ``b`` for ``n`` messages; print the figures."""
    role, n = (argv or sys.argv[1:])[:2]
    n = int(n)
    common.ensure_environment()
    import rclpy
    from rclpy.experimental import EventsExecutor
    from rclpy.node import Node
    from std_msgs.msg import Float64
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = Node(f'pingpong_{role}', context=ctx)
    reader = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                        reliability=ReliabilityPolicy.BEST_EFFORT,
                        durability=DurabilityPolicy.VOLATILE)
    writer = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)
    topic_in, topic_out = ('ping', 'pong') if role == 'b' else ('pong', 'ping')
    pub = node.create_publisher(Float64, topic_out, writer)
    tpl = cdr.Template(Float64(), ('data',), stamped=False)
    count = [0]
    done = threading.Event()

    def answer(_raw):
        count[0] += 1
        if count[0] >= n:
            done.set()
        pub.publish(tpl.pack(0, float(count[0])))

    sub = node.create_subscription(Float64, topic_in, answer, reader, raw=True)
    executor = EventsExecutor(context=ctx)
    executor.add_node(node)
    common.spin_until(executor, lambda: pub.get_subscription_count() >= 1
                      and sub.get_publisher_count() >= 1, 30.0)
    common.spin_until(executor, lambda: False, 0.5)  # both sides matched both ways
    cpu0, wall0 = common.cpu_time(), time.perf_counter()
    if role == 'a':
        pub.publish(tpl.pack(0, 0.0))
    ok = common.spin_until(executor, done.is_set, 120.0)
    cpu, wall = common.cpu_time() - cpu0, time.perf_counter() - wall0
    print(json.dumps({'role': role, 'ok': ok, 'messages': count[0],
                      'round_trip_s': wall / max(count[0], 1),
                      'cpu_per_message_s': cpu / max(count[0], 1)}), flush=True)
    common.spin_until(executor, lambda: False, 0.2)
    node.destroy_node()
    rclpy.try_shutdown(context=ctx)
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
