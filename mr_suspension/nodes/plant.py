"""Plant node: integrates the corner over a road and publishes the sensors and ground truth.

Publishes (relative names, see ``msg_defs/topics.yaml``) ``imu/body``, ``imu/wheel``, ``stroke``,
``truth/state``, ``truth/tyre_force`` and, in lock-step mode, ``/clock``; subscribes to
``damper/force``. Sample ``k`` carries the state at ``t_k = k dt`` and the accelerations and tyre
force of the step that ended there.

* Real time (``lockstep: false``): a wall timer at ``rate``; each tick advances one step with the
  newest damper force, moved to the present stroke rate along its tangent
  (:meth:`~mr_suspension.core.stepper.PlantStepper.coupled`). If the force of the present sample
  has not arrived yet the force of the sample before is used: one sample of coupling latency,
  stable because the stiff part acts through the tangent inside the implicit step. With
  ``sensors_after_force`` (default) a sample's sensors and tyre force go out once its damper
  force is in (before the next step at the latest), so their readers do not take the CPU the
  actuator needs for the force.
* Lock-step (``lockstep: true``): after publishing sample ``k`` the plant waits for the damper
  force of sample ``k``, then steps; time is simulated and published on ``/clock``. This is the
  simulator's step order exactly, reproducible and faster than real time.
"""

import threading
import time

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Float64
import yaml

from mr_suspension.core import road as rd
from mr_suspension.core.stepper import PlantStepper
from mr_suspension.nodes import cdr, common, contract as c

NODE = 'plant'


def parse_road(text):
    """Road mapping from ``"bump"``, ``"iso8608:road_class=C,speed=20"`` or a YAML mapping.

    The short form exists because ``-p road:={...}`` is read as a YAML mapping by rcl and
    rejected; ``-p road:=bump:height=0.08`` needs no quoting.
    """
    text = str(text).strip()
    if text.startswith('{'):
        spec = yaml.safe_load(text)
        if not isinstance(spec, dict):
            raise ValueError(f'plant: road must be a mapping, got {text!r}')
        return spec
    kind, _, rest = text.partition(':')
    spec = {'type': kind.strip()}
    for item in filter(None, (s.strip() for s in rest.split(','))):
        key, eq, value = item.partition('=')
        if not eq:
            raise ValueError(f'plant: road option {item!r} is not key=value')
        spec[key.strip()] = yaml.safe_load(value)
    return spec


class PlantNode(Node):
    """Quarter-car plant with road, sensors and ground truth."""

    def __init__(self, context=None, parameter_overrides=None, **kwargs):
        super().__init__(NODE, context=context, parameter_overrides=parameter_overrides,
                         **kwargs)
        d = common.node_defaults(NODE)
        self.config = common.declare_corner(self, d)
        spec = common.declare(self, d, 'road', 'Road: "bump", "iso8608:road_class=C,speed=20" '
                              'or a YAML mapping "{type: step, height: 0.05}" (types: step, '
                              'bump, harmonic, sweep, iso8608)')
        duration = common.declare(self, d, 'duration', 'Run duration [s]', 0.01, 1.0e5)
        self.lockstep = common.declare(self, d, 'lockstep', 'Lock-step simulated time (true) '
                                       'or real time (false)')
        self.publish_clock = common.declare(self, d, 'publish_clock', 'Publish /clock with '
                                            'the simulated time (lock-step only)')
        self.expect_subscribers = common.declare(
            self, d, 'expect_subscribers', 'Start once imu/body has this many subscribers '
            '(controller, plus recorders if any; every other link is checked likewise)', 0, 100)
        self.start_delay = common.declare(self, d, 'start_delay', 'Wait after discovery before '
                                          'the first step [s]', 0.0, 60.0)
        self.exit_at_end = common.declare(self, d, 'exit_at_end', 'End the process when the '
                                          'road is used up')
        self.max_catchup = common.declare(self, d, 'max_catchup', 'Real time: most steps per '
                                          'timer tick when behind the wall clock', 1, 100)
        self.max_force_age = common.declare(
            self, d, 'max_force_age', 'Real time: oldest damper force (in samples) a step may '
            'use; 1 keeps the one-sample coupling, more keeps the rate on a slow machine', 1, 10)
        self.coupling_delay = common.declare(
            self, d, 'coupling_delay', 'Lock-step: step k -> k+1 uses the damper force of '
            'sample k - coupling_delay moved along its tangent (0 = wait for force k: the '
            'offline simulator exactly; 1 or more lets plant and actuator run concurrently)',
            0, 10)
        self.resend_after = common.declare(
            self, d, 'resend_after', 'Lock-step: re-send the samples the loop waits on after '
            'this long without a step (recovers a lost sample) [s]', 0.001, 10.0)
        self.force_wait = common.declare(self, d, 'force_wait', 'Real time: longest wait for '
                                         'the damper force of a due step before stepping with '
                                         'the previous force [s]', 0.0, 0.1)
        self.sensors_after_force = common.declare(
            self, d, 'sensors_after_force', 'Real time: publish the sensors and tyre '
            'force once its damper force is in (at the latest with the next step), so the '
            'plant-actuator coupling has the CPU first')
        self.gravity = self.config.car.g
        # Read-only, from the vehicle set: the controller checks its own gravity against it.
        self.declare_parameter('gravity', float(self.gravity), ParameterDescriptor(
            description='Gravity in the IMU specific force [m/s^2] (from the vehicle set; '
            'read-only, for the start-up agreement check)', read_only=True))
        self.stats = common.Stats(common.declare(self, d, 'stats_file', 'Write run statistics '
                                                 'as JSON here on exit ("" = off)'))
        self.road = rd.from_spec(parse_road(spec), duration=duration, dt=self.config.dt)
        self.plant = PlantStepper(self.config, self.road).warm_up()
        self.dt_ns = common.step_ns(self.config)
        self.finished = threading.Event()

        ls = self.lockstep
        self.pub_imu_s = self.create_publisher(Imu, c.IMU_BODY, common.qos(c.IMU_BODY, ls))
        self.pub_imu_u = self.create_publisher(Imu, c.IMU_WHEEL, common.qos(c.IMU_WHEEL, ls))
        self.pub_stroke = self.create_publisher(JointState, c.STROKE, common.qos(c.STROKE, ls))
        self.pub_truth = self.create_publisher(JointState, c.TRUTH_STATE,
                                               common.qos(c.TRUTH_STATE, self.lockstep))
        self.pub_tyre = self.create_publisher(Float64, c.TRUTH_TYRE_FORCE,
                                              common.qos(c.TRUTH_TYRE_FORCE, self.lockstep))
        # The loop's stamped links, in publishing order (the damper motion first).
        self.loop_pubs = (self.pub_truth, self.pub_imu_s, self.pub_imu_u, self.pub_stroke)
        self.pub_clock = None
        if self.lockstep and self.publish_clock:
            self.pub_clock = self.create_publisher(Clock, c.CLOCK, common.qos(c.CLOCK, ls))
        self.sub_force = self.create_subscription(
            JointState, c.DAMPER_FORCE, self._on_force,
            common.qos(c.DAMPER_FORCE, ls, loop_reader=True), raw=True)
        self._init_messages()
        # Newest damper force: (sample index, force, tangent, stroke rate it was evaluated at).
        self.force = None
        self.forces = {}
        self.sent = {}
        self.deferred = ()  # real time: (pub, raw) of the sample's sensors not yet published
        self.n_duplicates = 0
        self.n_resends = 0
        self.resend_mark = (-1, time.monotonic())
        self.started = False
        self.stamp_k = {}
        self.last_stamp = 0
        self.wall0 = 0.0
        self.pub_wall = [0.0] * (self.road.n_steps + 1)
        self.latency = []
        self.periods = []
        self.last_tick = None
        self.late_forces = 0
        self.first_force = None
        self.step_cost = []
        self.n_forces = 0
        self.stats.data.update(mode='lockstep' if self.lockstep else 'realtime',
                               rate=1.0 / self.config.dt, steps_planned=self.road.n_steps)
        self.ready_since = None
        self.start_timer = self.create_timer(0.02, self._try_start)
        self.progress = (-1, time.monotonic())
        self.watchdog = self.create_timer(1.0, self._check_progress)
        self.step_timer = None
        if self.lockstep:
            self.create_timer(min(0.5 * self.resend_after, 0.02), self._resend)
        options = self.config.car.options_on  # corner-level model options of the vehicle set
        self.get_logger().info(
            f'plant: {self.road.name}, {self.road.n_steps} steps of {self.config.dt * 1e3:g} ms, '
            f'{"lock-step" if self.lockstep else "real time"}'
            + (f', corner options: {", ".join(options)}' if options else ''))

    def _init_messages(self):
        """Build serialized templates of the published messages (:class:`cdr.Template`)."""
        imu_s, imu_u = Imu(), Imu()
        imu_s.header.frame_id = c.FRAME_BODY_IMU
        imu_u.header.frame_id = c.FRAME_WHEEL_IMU
        for m in (imu_s, imu_u):
            m.orientation_covariance[0] = -1.0
            m.angular_velocity_covariance[0] = -1.0
        stroke = JointState()
        stroke.header.frame_id = c.FRAME_SUSPENSION
        stroke.name = [c.JOINT_STROKE]
        stroke.position = [0.0]
        truth = JointState()
        truth.header.frame_id = c.FRAME_WORLD
        truth.name = list(c.JOINTS_TRUTH)
        truth.position = [0.0] * len(c.JOINTS_TRUTH)
        truth.velocity = [0.0] * len(c.JOINTS_TRUTH)
        n = len(c.JOINTS_TRUTH)
        self.tpl_imu_s = cdr.Template(imu_s, ('linear_acceleration.z',))
        self.tpl_imu_u = cdr.Template(imu_u, ('linear_acceleration.z',))
        self.tpl_stroke = cdr.Template(stroke, ('position[0]',))
        self.tpl_truth = cdr.Template(truth, [f'position[{i}]' for i in range(n)]
                                      + [f'velocity[{i}]' for i in range(n)])
        self.tpl_tyre = cdr.Template(Float64(), ('data',), stamped=False)
        self.tpl_clock = cdr.Template(Clock(), ())

    # -- start-up --------------------------------------------------------------------------

    def _ready(self):
        """Check every contract link: own publishers matched, the others discovered."""
        if self.sub_force.get_publisher_count() < 1:
            return False
        recorders = max(self.expect_subscribers - 1, 0)
        own = {c.IMU_BODY: self.pub_imu_s, c.IMU_WHEEL: self.pub_imu_u, c.STROKE: self.pub_stroke,
               c.TRUTH_STATE: self.pub_truth, c.TRUTH_TYRE_FORCE: self.pub_tyre,
               c.CLOCK: self.pub_clock}
        for name, topic in c.TOPICS.items():
            need = len([s for s in topic.subscribers if s != 'recorder']) + recorders
            if name in own:
                if own[name] is not None and own[name].get_subscription_count() < need:
                    return False
            elif self.count_publishers(name) < 1 or self.count_subscribers(name) < need:
                return False
        return True

    def _try_start(self):
        if self.started:
            return
        if not self._ready():
            self.ready_since = None
            return
        now = time.monotonic()
        if self.ready_since is None:
            self.ready_since = now
        if now - self.ready_since < self.start_delay:
            return
        self.start_timer.cancel()
        self.started = True
        self.wall0 = time.monotonic()
        self.stats.mark()
        if not self.lockstep:
            self.step_timer = self.create_timer(self.config.dt, self._on_tick)
        self.get_logger().info('plant: node set connected, starting')
        self._publish_sample()

    def _check_progress(self):
        now = time.monotonic()
        if not self.started or self.plant.done:
            if not self.started and now - self.progress[1] > 10.0:
                self.get_logger().warning(
                    'plant: still waiting for the node set (controller, actuator'
                    + (', recorder' if self.expect_subscribers > 1 else '') + ')',
                    throttle_duration_sec=10.0)
            return
        if self.plant.k != self.progress[0]:
            self.progress = (self.plant.k, now)
        elif now - self.progress[1] > 5.0:
            self.get_logger().error(f'plant: no damper force for sample {self.plant.k} for '
                                    f'{now - self.progress[1]:.0f} s; is the actuator running?',
                                    throttle_duration_sec=10.0)

    # -- publishing ------------------------------------------------------------------------

    def _publish_sample(self):
        p = self.plant
        if self.lockstep:
            ns = p.k * self.dt_ns
        else:
            # Real time: stamped with the wall time of publication, as a driver stamps a
            # measurement; the damper force echoes the stamp and is matched back to k.
            ns = max(self.get_clock().now().nanoseconds, self.last_stamp + 1)
            self.last_stamp = ns
            self.stamp_k[ns] = p.k
            if len(self.stamp_k) > 4096:
                for key in list(self.stamp_k)[:2048]:
                    del self.stamp_k[key]
        x = p.stroke
        v = p.stroke_rate
        z_r, zr_dot = p.road_now()
        q = p.q
        self.pub_wall[p.k] = time.monotonic()
        # The damper motion first (the actuator answers it at once; in lock-step it is the
        # critical path), then the sensors, the tyre force and the clock.
        truth = self.tpl_truth.pack(ns, float(q[0]), float(q[1]), z_r, x, float(q[2]),
                                    float(q[3]), zr_dot, v)
        self.pub_truth.publish(truth)
        raws = (truth, self.tpl_imu_s.pack(ns, p.a_s + self.gravity),
                self.tpl_imu_u.pack(ns, p.a_u + self.gravity), self.tpl_stroke.pack(ns, x))
        rest = tuple(zip(self.loop_pubs[1:], raws[1:])) \
            + ((self.pub_tyre, self.tpl_tyre.pack(ns, p.f_t)),)
        if self.lockstep:
            self.sent[p.k] = raws
            self.sent.pop(p.k - self.coupling_delay - 2, None)
        self.deferred = rest
        if not self.lockstep and self.sensors_after_force and not p.done:
            # Real time: while the actuator answers, the sensors' readers (controller,
            # recorders) would wake and take the CPU it needs; they get them once the force is
            # in (before the next step at the latest), 0.1-0.5 ms later.
            return
        self._flush_deferred()
        if self.pub_clock is not None:
            self.pub_clock.publish(self.tpl_clock.pack(ns))

    def _flush_deferred(self):
        """Real time: publish the sensors held back by ``sensors_after_force``."""
        rest, self.deferred = self.deferred, ()
        for pub, raw in rest:
            pub.publish(raw)

    # -- stepping --------------------------------------------------------------------------

    def _on_force(self, raw):
        now = time.monotonic()
        stamp, _, velocity, effort = cdr.joint_state(raw)
        if self.lockstep:
            k = int(round(stamp / self.dt_ns))
        else:
            k = self.stamp_k.get(stamp, -1)
        if len(effort) < 2 or len(velocity) < 1 or not common.finite(
                effort[0], effort[1], velocity[0]):
            self.get_logger().error('plant: invalid damper/force message ignored',
                                    throttle_duration_sec=1.0)
            return
        if not self.started or not 0 <= k <= self.plant.k:
            return
        if self.lockstep:
            if k < self._wanted() or k in self.forces:
                self.n_duplicates += 1  # answer to a re-sent sample, already in
                return
            self._count_force(k, now)
            self.forces[k] = (k, effort[0], effort[1], velocity[0])
            self._pump()
            return
        self._count_force(k, now)
        if k == self.plant.k:
            self._flush_deferred()
        if self.force is not None and k < self.force[0]:
            return
        self.force = (k, effort[0], effort[1], velocity[0])
        if k == self.plant.k and not self.plant.done:
            self._catch_up(now)

    def _count_force(self, k, now):
        self.n_forces += 1
        self.latency.append(now - self.pub_wall[k])
        if self.first_force is None:
            self.first_force = now

    def _resend(self):
        """Lock-step: re-send the samples the loop waits on when it made no progress.

        The loop's stamped links are best effort (:func:`common.qos`); a sample lost on one of
        them would stall the loop. After ``resend_after`` without a step the plant publishes
        again, byte for byte, samples ``j - 1 .. k`` (``j``: the sample whose force it waits
        for; ``j - 1``: the sensors of the command that force needs). Actuator, controller and
        recorder recognise the repeated stamps, so a recovered run equals an undisturbed one.
        """
        now = time.monotonic()
        p = self.plant
        if not self.started or p.done or p.k != self.resend_mark[0]:
            self.resend_mark = (p.k, now)
            return
        if now - self.resend_mark[1] < self.resend_after:
            return
        wanted = self._wanted()
        first = max(wanted - 1, 0)
        for k in range(first, p.k + 1):
            for pub, raw in zip(self.loop_pubs, self.sent.get(k, ())):
                pub.publish(raw)
        self.n_resends += 1
        self.resend_mark = (p.k, now)
        self.get_logger().warning(
            f'plant: no damper force for sample {wanted} after '
            f'{self.resend_after * 1e3:.0f} ms; re-sent samples {first}..{p.k}',
            throttle_duration_sec=5.0)

    def _wanted(self):
        """Lock-step: the sample whose force the next step uses, ``max(k - delay, 0)``."""
        return max(self.plant.k - self.coupling_delay, 0)

    def _pump(self):
        """Lock-step: take every step whose force (of sample :meth:`_wanted`) is in."""
        p = self.plant
        while not p.done:
            force = self.forces.get(self._wanted())
            if force is None:
                return
            self.force = force
            self._advance()
            # Forces arrive in order and older ones are refused, so the one just used (if no
            # longer wanted) is the only stale entry.
            if force[0] < self._wanted():
                del self.forces[force[0]]

    def _advance(self):
        t_in = time.monotonic()
        if self.deferred:
            self._flush_deferred()
        p = self.plant
        if self.force is None:
            f_d, c_d = 0.0, 0.0
        else:
            k, f_m, c_m, v_m = self.force
            if k != (self._wanted() if self.lockstep else p.k):
                self.late_forces += 1
            f_d, c_d = p.coupled(f_m, c_m, v_m), c_m
        p.step(f_d, c_d)
        self._publish_sample()
        self.step_cost.append(time.monotonic() - t_in)
        if p.done:
            self._finish()

    def _on_tick(self):
        now = time.monotonic()
        if self.last_tick is not None:
            self.periods.append(now - self.last_tick)
        self.last_tick = now
        if not self.plant.done:
            self._catch_up(now)

    def _catch_up(self, now):
        """Take the steps that are due by the wall clock (real time).

        Step ``k -> k + 1`` is due at ``t0 + (k + 1) dt``. It is taken as soon as it is due and
        the damper force of sample ``k`` is in; without that force the plant waits at most
        ``force_wait`` past the due time, then steps with the newest force moved along its
        tangent (a late force), if that is at most ``max_force_age`` samples old (default 1:
        the one-sample coupling, whose error is bounded); with an older one it waits, so a
        loop slower than that falls behind the wall clock (the achieved rate) instead of
        losing accuracy.
        """
        dt = self.config.dt
        n = 0
        while not self.plant.done and n < self.max_catchup:
            due = self.wall0 + (self.plant.k + 1) * dt
            if now < due:
                return
            newest = -1 if self.force is None else self.force[0]
            if newest < self.plant.k and (newest < self.plant.k - self.max_force_age
                                          or now < due + self.force_wait):
                return
            self._advance()
            n += 1

    def _finish(self):
        if self.step_timer is not None:
            self.step_timer.cancel()
        wall = time.monotonic() - self.wall0
        lat = common.percentiles(self.latency)
        jit = common.percentiles([abs(x - self.config.dt) for x in self.periods])
        cost = common.percentiles(self.step_cost)
        self.stats.data.update(
            steps=self.plant.k, run_wall_s=wall, steps_per_s=self.plant.k / wall,
            startup_s=(self.first_force or self.wall0) - self.wall0,
            steps_per_s_sustained=(self.plant.k - 1) / max(
                time.monotonic() - (self.first_force or self.wall0), 1e-9),
            published=self.plant.k + 1, forces_received=self.n_forces,
            late_forces=self.late_forces, resends=self.n_resends,
            duplicate_forces=self.n_duplicates, latency_p50_s=lat[0], latency_p99_s=lat[1],
            latency_max_s=max(self.latency, default=float('nan')),
            latency_max_index=max(range(len(self.latency)), key=self.latency.__getitem__,
                                  default=-1),
            latency_sum_s=sum(self.latency),
            jitter_p50_s=jit[0], jitter_p99_s=jit[1], ticks=len(self.periods) + 1,
            step_cost_p50_s=cost[0], step_cost_p99_s=cost[1])
        self.get_logger().info(
            f'plant: done, {self.plant.k} steps in {wall:.2f} s ({self.plant.k / wall:.0f} '
            f"steps/s), {self.late_forces} steps used the previous sample's force")
        if self.exit_at_end:
            self.finished.set()

    def drain(self, executor):
        """Let in-flight force messages arrive before exit (for complete statistics)."""
        common.spin_until(executor, lambda: False, 0.2)

    def close(self):
        """Write the statistics file (forces counted after the drain)."""
        self.stats.data['forces_received'] = self.n_forces
        self.stats.write()


def main(args=None):
    """Console script ``plant``."""
    return common.run(PlantNode, args)


if __name__ == '__main__':
    main()
