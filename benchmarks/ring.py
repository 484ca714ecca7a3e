"""Ceiling reference for lock-step: the node set's message pattern with no work in the nodes.

Three processes play plant (``p``), controller (``c``) and actuator (``a``) on the contract's
topics, message types, QoS and serialized templates, in lock-step with the default one-sample
coupling, but do nothing else: the plant publishes sample ``k`` (``truth/state``, ``imu/body``,
``imu/wheel``, ``stroke``, ``truth/tyre_force``, ``/clock``) once the damper force of sample
``k - 1`` is in; the controller answers the three sensors of a sample with a
``current_command``; the actuator answers the ``k``-th motion and command with
``damper/force`` and ``coil_current``. Its steps per second are what any ``rclpy`` node set
with this contract can reach on this machine and middleware right now; the node set's lock-step
figure divided by it is the share of that ceiling the nodes' own work leaves.

Run by ``bench_nodes.ring_reference``; by hand, in three shells with the same
``ROS_DOMAIN_ID``: ``python benchmarks/ring.py a 5000``, ``... c 5000``, ``... p 5000``.
Prints one JSON line per process (the plant's has ``steps_per_s``).
"""

import json
import sys
import threading
import time

from mr_suspension.nodes import cdr, common, contract as c


class _Ring:
    """One role of the ring on its own node; ``done`` is set after ``n`` steps."""

    def __init__(self, node, role, n, dt_ns=1_000_000):
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import Imu, JointState
        from std_msgs.msg import Float64
        self.node, self.role, self.n, self.dt_ns = node, role, n, dt_ns
        self.done = threading.Event()
        self.k = 0
        self.count = 0
        self.t0 = None
        qos = common.qos
        imu, js = Imu(), JointState()
        js.name, js.position, js.velocity, js.effort = ['x'], [0.0], [0.0], [0.0, 0.0]
        self.tpl_imu = cdr.Template(imu, ('linear_acceleration.z',))
        self.tpl_js = cdr.Template(js, ('position[0]',))
        self.tpl_f64 = cdr.Template(Float64(), ('data',), stamped=False)
        self.tpl_clock = cdr.Template(Clock(), ())
        sub = node.create_subscription
        if role == 'p':
            self.pubs = [node.create_publisher(t, name, qos(name, True)) for t, name in (
                (JointState, c.TRUTH_STATE), (Imu, c.IMU_BODY), (Imu, c.IMU_WHEEL),
                (JointState, c.STROKE), (Float64, c.TRUTH_TYRE_FORCE), (Clock, c.CLOCK))]
            self.subs = [sub(JointState, c.DAMPER_FORCE, self._on_force,
                             qos(c.DAMPER_FORCE, True, loop_reader=True), raw=True)]
            self.outs = [(self.pubs[0], 1)]
        elif role == 'c':
            self.cmd = node.create_publisher(Float64, c.CURRENT_COMMAND,
                                             qos(c.CURRENT_COMMAND, True))
            self.seen = {}
            self.subs = [sub(t, name, self._on_sensor, qos(name, True, loop_reader=True),
                             raw=True)
                         for t, name in ((Imu, c.IMU_BODY), (Imu, c.IMU_WHEEL),
                                         (JointState, c.STROKE))]
            self.outs = [(self.cmd, 1)]
        else:
            self.force = node.create_publisher(JointState, c.DAMPER_FORCE,
                                               qos(c.DAMPER_FORCE, True))
            self.coil = node.create_publisher(Float64, c.COIL_CURRENT, qos(c.COIL_CURRENT, True))
            self.motion, self.commands = [], []
            self.subs = [sub(JointState, c.TRUTH_STATE, self._on_motion,
                             qos(c.TRUTH_STATE, True, loop_reader=True), raw=True),
                         sub(Float64, c.CURRENT_COMMAND, self._on_command,
                             qos(c.CURRENT_COMMAND, True), raw=True)]
            self.outs = [(self.force, 1)]

    def ready(self):
        """Return True once every own publisher and subscription is matched."""
        return all(p.get_subscription_count() >= m for p, m in self.outs) and \
            all(s.get_publisher_count() >= 1 for s in self.subs)

    def start(self):
        """Start the clock (and, as the plant, publish sample 0)."""
        self.t0 = (time.perf_counter(), common.cpu_time())
        if self.role == 'p':
            self._publish()

    def _publish(self):
        ns = self.k * self.dt_ns
        truth, imu_s, imu_u, stroke, tyre, clock = self.pubs
        truth.publish(self.tpl_js.pack(ns, 0.0))
        imu_s.publish(self.tpl_imu.pack(ns, 9.81))
        imu_u.publish(self.tpl_imu.pack(ns, 9.81))
        stroke.publish(self.tpl_js.pack(ns, 0.0))
        tyre.publish(self.tpl_f64.pack(0, 0.0))
        clock.publish(self.tpl_clock.pack(ns))

    def _on_force(self, raw):
        # Step k -> k + 1 needs the force of sample k - 1 (coupling delay 1); its answer to
        # sample k arrives while sample k + 1 is out.
        if cdr.stamp(raw) // self.dt_ns != max(self.k - 1, 0) or self.done.is_set():
            return
        self.k += 1
        if self.k >= self.n:
            self.done.set()
            return
        self._publish()
        if self.k == 1:  # sample 0's force also serves step 1 -> 2
            self._on_force(raw)

    def _on_sensor(self, raw):
        ns = cdr.stamp(raw)
        got = self.seen.get(ns, 0) + 1
        if got < 3:
            self.seen[ns] = got
            return
        self.seen.pop(ns, None)
        self.cmd.publish(self.tpl_f64.pack(0, 1.0))
        self._counted()

    def _on_motion(self, raw):
        self.motion.append(cdr.stamp(raw))
        self._answer()

    def _on_command(self, raw):
        self.commands.append(cdr.float64(raw))
        self._answer()

    def _answer(self):
        while self.motion and self.commands:
            ns = self.motion.pop(0)
            self.commands.pop(0)
            self.force.publish(self.tpl_js.pack(ns, 0.0))
            self.coil.publish(self.tpl_f64.pack(0, 1.0))
            self._counted()

    def _counted(self):
        self.count += 1
        if self.count >= self.n:
            self.done.set()

    def figures(self):
        """Return the wall and CPU time since :meth:`start`, per step."""
        wall, cpu = time.perf_counter() - self.t0[0], common.cpu_time() - self.t0[1]
        steps = self.k if self.role == 'p' else self.count
        out = {'role': self.role, 'steps': steps, 'cpu_per_step_s': cpu / max(steps, 1)}
        if self.role == 'p':
            out['steps_per_s'] = steps / wall
        return out


def main(argv=None):
    """Play role ``p``, ``c`` or ``a`` for ``n`` steps; print the figures as JSON."""
    role, n = (argv or sys.argv[1:])[:2]
    common.ensure_environment()
    import rclpy
    from rclpy.experimental import EventsExecutor
    from rclpy.node import Node
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = Node(f'ring_{role}', context=ctx)
    ring = _Ring(node, role, int(n))
    executor = EventsExecutor(context=ctx)
    executor.add_node(node)
    ok = common.spin_until(executor, ring.ready, 30.0)
    common.spin_until(executor, lambda: False, 0.5)  # everyone matched everyone
    ring.start()
    ok = ok and common.spin_until(executor, ring.done.is_set, 120.0)
    print(json.dumps(dict(ring.figures(), ok=ok)), flush=True)
    common.spin_until(executor, lambda: False, 0.3)  # let the others finish
    node.destroy_node()
    rclpy.try_shutdown(context=ctx)
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
