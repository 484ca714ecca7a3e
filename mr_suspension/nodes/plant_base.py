"""The plant loop shared by the quarter-car and the full-car plant nodes.

:class:`PlantBase` holds what both plants do the same way for any number of corners: the shared
parameters (road, duration, modes and their tuning), the start-up handshake over the contract
links, the real-time stepping on a wall timer and the lock-step stepping on the damper forces,
the re-sending of lost samples, and the run statistics. A subclass gives the model (parameters,
road, stepper), the published messages of a sample and how the corners' forces step the model;
:mod:`mr_suspension.nodes.plant` has one corner (topics in the node's namespace),
:mod:`mr_suspension.nodes.full_car_plant` four (topics under ``front_left/`` etc.).

Sample ``k`` carries the state at ``t_k = k dt`` and the accelerations and tyre forces of the
step that ended there.

* Real time (``lockstep: false``): a wall timer at ``rate``; each tick advances one step with the
  newest damper force of every corner, moved to the corner's present stroke rate along its
  tangent. If a corner's force of the present sample has not arrived yet the force of the
  sample before is used: one sample of coupling latency, stable because the stiff part acts
  through the tangent inside the implicit step. With ``sensors_after_force`` (default) a
  sample's sensors and tyre forces go out once all its damper forces are in (before the next
  step at the latest), so their readers do not take the CPU the actuators need.
* Lock-step (``lockstep: true``): after publishing sample ``k`` the plant waits for the damper
  forces of sample ``k - coupling_delay`` of every corner, then steps; time is simulated and
  published on ``/clock``. With ``coupling_delay: 0`` this is the simulator's step order
  exactly, reproducible and faster than real time.
"""

import functools
import threading
import time

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
import yaml

from mr_suspension.nodes import cdr, common, contract as c

ROAD_HELP = ('Road: "bump", "iso8608:road_class=C,speed=20" or a YAML mapping "{type: step, '
             'height: 0.05}" (types: step, bump, harmonic, sweep, iso8608)')


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


class PlantBase(Node):
    """A plant of one or more corners driven by their damper forces (module doc).

    ``corners``: the topic prefix of each corner (``''``: the node's namespace). A subclass
    implements :meth:`_declare_model` (sets ``config``, ``dt`` and ``gravity``),
    :meth:`_make_road`, :meth:`_make_stepper`, :meth:`_create_outputs` (publishers and
    ``own``, the relative topic names it publishes), :meth:`_sample`, :meth:`_coupled` and
    :meth:`_step`.
    """

    def __init__(self, name, corners, context=None, parameter_overrides=None, **kwargs):
        super().__init__(name, context=context, parameter_overrides=parameter_overrides,
                         **kwargs)
        self.corners = tuple(corners)
        d = common.node_defaults(name)
        self._declare_model(d)
        spec = common.declare(self, d, 'road', ROAD_HELP)
        duration = common.declare(self, d, 'duration', 'Run duration [s]', 0.01, 1.0e5)
        self.lockstep = common.declare(self, d, 'lockstep', 'Lock-step simulated time (true) '
                                       'or real time (false)')
        self.publish_clock = common.declare(self, d, 'publish_clock', 'Publish /clock with '
                                            'the simulated time (lock-step only)')
        self.expect_subscribers = common.declare(
            self, d, 'expect_subscribers', 'Start once imu/body (of every corner) has this '
            'many subscribers (controller, plus recorders if any; every other link is checked '
            'likewise)', 0, 100)
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
        # Read-only, from the vehicle set: the controller checks its own gravity against it.
        self.declare_parameter('gravity', float(self.gravity), ParameterDescriptor(
            description='Gravity in the IMU specific force [m/s^2] (from the vehicle set; '
            'read-only, for the start-up agreement check)', read_only=True))
        self.stats = common.Stats(common.declare(self, d, 'stats_file', 'Write run statistics '
                                                 'as JSON here on exit ("" = off)'))
        self.road = self._make_road(parse_road(spec), duration)
        self.plant = self._make_stepper().warm_up()
        self.dt_ns = int(round(self.dt * 1e9))
        self.finished = threading.Event()
        ls = self.lockstep
        self.own = {}  # relative topic name -> own publisher (None: not published)
        self._create_outputs()
        self.pub_clock = None
        if self.lockstep and self.publish_clock:
            self.pub_clock = self.create_publisher(Clock, c.CLOCK, common.qos(c.CLOCK, ls))
        self.own[c.CLOCK] = self.pub_clock
        self.tpl_clock = cdr.Template(Clock(), ())
        self.subs_force = [self.create_subscription(
            JointState, prefix + c.DAMPER_FORCE, self._force_callback(i),
            common.qos(c.DAMPER_FORCE, ls, loop_reader=True), raw=True)
            for i, prefix in enumerate(self.corners)]
        n = len(self.corners)
        # Newest damper force per corner: (sample index, force, tangent, stroke rate at eval).
        self.force = [None] * n
        self.forces = [{} for _ in range(n)]  # lock-step: sample index -> force, per corner
        self.arrived = {}  # sample index -> forces in (all corners: the loop latency)
        self.sent = {}  # lock-step: sample index -> (publisher, raw) the loop reads
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
        self.lags = []  # real time: how late each step was taken after it was due [s]
        self.n_forces = 0
        self.stats.data.update(mode='lockstep' if self.lockstep else 'realtime',
                               rate=1.0 / self.dt, steps_planned=self.road.n_steps,
                               corners=n)
        self.ready_since = None
        self.start_timer = self.create_timer(0.02, self._try_start)
        self.progress = (-1, time.monotonic())
        self.watchdog = self.create_timer(1.0, self._check_progress)
        self.step_timer = None
        if self.lockstep:
            self.create_timer(min(0.5 * self.resend_after, 0.02), self._resend)
        self.get_logger().info(
            f'{self.get_name()}: {self.road.name}, {self.road.n_steps} steps of '
            f'{self.dt * 1e3:g} ms, {"lock-step" if self.lockstep else "real time"}'
            + self._describe())

    # -- the model (subclass) ----------------------------------------------------------------

    def _declare_model(self, defaults):
        """Declare the model's parameters; set ``config``, ``dt`` and ``gravity``."""
        raise NotImplementedError

    def _make_road(self, spec, duration):
        """Return the road of a spec mapping."""
        raise NotImplementedError

    def _make_stepper(self):
        """Return the model's stepper (with ``k``, ``done``, ``warm_up()``)."""
        raise NotImplementedError

    def _create_outputs(self):
        """Create the publishers and templates; fill ``own``."""
        raise NotImplementedError

    def _sample(self, ns):
        """Messages of the present sample stamped ``ns``: (motion, sensors, other).

        Each a list of ``(publisher, raw)``: the damper motion goes out first, then (real time,
        ``sensors_after_force``: once the sample's forces are in) the sensors and the other
        messages; the lock-step re-send repeats motion and sensors.
        """
        raise NotImplementedError

    def _coupled(self, i, f_m, c_m, v_m):
        """Force to apply at corner ``i`` from a force evaluated at stroke rate ``v_m``."""
        raise NotImplementedError

    def _step(self, forces, tangents):
        """Advance the model one step with the corners' forces and tangents."""
        raise NotImplementedError

    def _describe(self):
        """Extra text of the start-up log line."""
        return ''

    def _ready_extra(self):
        """Further start conditions of the subclass."""
        return True

    # -- start-up --------------------------------------------------------------------------

    def _ready(self):
        """Check every contract link of every corner: own publishers matched, others discovered.

        A link needs its contract subscribers other than the recorder (one of each
        alternative) plus ``expect_subscribers - 1`` recorders.
        """
        if any(sub.get_publisher_count() < 1 for sub in self.subs_force):
            return False
        recorders = max(self.expect_subscribers - 1, 0)
        for name, topic in c.TOPICS.items():
            need = len([s for s in topic.subscribers if s != 'recorder']) + recorders
            for prefix in ('',) if name in c.ABSOLUTE else self.corners:
                full = prefix + name
                if full in self.own:
                    pub = self.own[full]
                    if pub is not None and pub.get_subscription_count() < need:
                        return False
                elif self.count_publishers(full) < 1 or self.count_subscribers(full) < need:
                    return False
        return self._ready_extra()

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
            self.step_timer = self.create_timer(self.dt, self._on_tick)
        self.get_logger().info(f'{self.get_name()}: node set connected, starting')
        self._publish_sample()

    def _check_progress(self):
        now = time.monotonic()
        name = self.get_name()
        if not self.started or self.plant.done:
            if not self.started and now - self.progress[1] > 10.0:
                self.get_logger().warning(
                    f'{name}: still waiting for the node set (controller, actuator'
                    + (', recorder' if self.expect_subscribers > 1 else '') + ')',
                    throttle_duration_sec=10.0)
            return
        if self.plant.k != self.progress[0]:
            self.progress = (self.plant.k, now)
        elif now - self.progress[1] > 5.0:
            missing = [p.rstrip('/') or '.' for p, f in zip(self.corners, self.force)
                       if f is None or f[0] < self._wanted()]
            where = f' ({", ".join(missing)})' if len(self.corners) > 1 and missing else ''
            self.get_logger().error(f'{name}: no damper force{where} for sample '
                                    f'{self.plant.k} for {now - self.progress[1]:.0f} s; is '
                                    'the actuator running?', throttle_duration_sec=10.0)

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
        self.pub_wall[p.k] = time.monotonic()
        # The damper motion first (the actuator answers it at once; in lock-step it is the
        # critical path), then the sensors, the tyre force and the clock.
        motion, sensors, other = self._sample(ns)
        for pub, raw in motion:
            pub.publish(raw)
        if self.lockstep:
            self.sent[p.k] = tuple(motion) + tuple(sensors)
            self.sent.pop(p.k - self.coupling_delay - 2, None)
        self.deferred = tuple(sensors) + tuple(other)
        if not self.lockstep and self.sensors_after_force and not p.done:
            # Real time: while the actuators answer, the sensors' readers (controllers,
            # recorders) would wake and take the CPU they need; they get them once the forces
            # are in (before the next step at the latest), 0.1-0.5 ms later.
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

    def _force_callback(self, i):
        """Subscription callback of corner ``i``'s damper force."""
        if len(self.corners) == 1:
            return self._on_force
        return functools.partial(self._on_corner_force, i)

    def _on_force(self, raw):
        """Damper force of the (only) corner."""
        self._on_corner_force(0, raw)

    def _on_corner_force(self, i, raw):
        now = time.monotonic()
        stamp, _, velocity, effort = cdr.joint_state(raw)
        if self.lockstep:
            k = int(round(stamp / self.dt_ns))
        else:
            k = self.stamp_k.get(stamp, -1)
        if len(effort) < 2 or len(velocity) < 1 or not common.finite(
                effort[0], effort[1], velocity[0]):
            self.get_logger().error(f'{self.get_name()}: invalid damper/force message '
                                    'ignored', throttle_duration_sec=1.0)
            return
        if not self.started or not 0 <= k <= self.plant.k:
            return
        if self.lockstep:
            if k < self._wanted() or k in self.forces[i]:
                self.n_duplicates += 1  # answer to a re-sent sample, already in
                return
            self._count_force(k, now)
            self.forces[i][k] = (k, effort[0], effort[1], velocity[0])
            self._pump()
            return
        self._count_force(k, now)
        if self.force[i] is not None and k < self.force[i][0]:
            return
        self.force[i] = (k, effort[0], effort[1], velocity[0])
        if k == self.plant.k and self._newest() == k:
            self._flush_deferred()
            if not self.plant.done:
                self._catch_up(now)

    def _newest(self):
        """Newest sample whose damper forces are in for every corner (-1: none yet)."""
        return min(-1 if f is None else f[0] for f in self.force)

    def _count_force(self, k, now):
        self.n_forces += 1
        if self.first_force is None:
            self.first_force = now
        n = self.arrived.get(k, 0) + 1
        if n < len(self.corners):
            self.arrived[k] = n
            if len(self.arrived) > 64:
                del self.arrived[next(iter(self.arrived))]
            return
        self.arrived.pop(k, None)
        self.latency.append(now - self.pub_wall[k])

    def _resend(self):
        """Lock-step: re-send the samples the loop waits on when it made no progress.

        The loop's stamped links are best effort (:func:`common.qos`); a sample lost on one of
        them would stall the loop. After ``resend_after`` without a step the plant publishes
        again, byte for byte, samples ``j - 1 .. k`` (``j``: the sample whose force it waits
        for; ``j - 1``: the sensors of the command that force needs). Actuators, controllers
        and recorders recognise the repeated stamps, so a recovered run equals an undisturbed
        one.
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
            for pub, raw in self.sent.get(k, ()):
                pub.publish(raw)
        self.n_resends += 1
        self.resend_mark = (p.k, now)
        self.get_logger().warning(
            f'{self.get_name()}: no damper force for sample {wanted} after '
            f'{self.resend_after * 1e3:.0f} ms; re-sent samples {first}..{p.k}',
            throttle_duration_sec=5.0)

    def _wanted(self):
        """Lock-step: the sample whose force the next step uses, ``max(k - delay, 0)``."""
        return max(self.plant.k - self.coupling_delay, 0)

    def _pump(self):
        """Lock-step: take every step whose forces (of sample :meth:`_wanted`) are all in."""
        p = self.plant
        while not p.done:
            wanted = self._wanted()
            got = [forces.get(wanted) for forces in self.forces]
            if any(f is None for f in got):
                return
            self.force = got
            self._advance()
            # Forces arrive in order and older ones are refused, so the ones just used (if no
            # longer wanted) are the only stale entries.
            if wanted < self._wanted():
                for forces in self.forces:
                    del forces[wanted]

    def _advance(self):
        t_in = time.monotonic()
        if self.deferred:
            self._flush_deferred()
        p = self.plant
        if not self.lockstep:
            self.lags.append(t_in - self.wall0 - (p.k + 1) * self.dt)
        due = self._wanted() if self.lockstep else p.k
        late = False
        forces, tangents = [], []
        for i, force in enumerate(self.force):
            if force is None:
                forces.append(0.0)
                tangents.append(0.0)
                continue
            k, f_m, c_m, v_m = force
            late = late or k != due
            forces.append(self._coupled(i, f_m, c_m, v_m))
            tangents.append(c_m)
        if late:
            self.late_forces += 1
        self._step(forces, tangents)
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
        the damper forces of sample ``k`` are in; without them the plant waits at most
        ``force_wait`` past the due time, then steps with each corner's newest force moved
        along its tangent (a late force), if the oldest of them is at most ``max_force_age``
        samples old (default 1: the one-sample coupling, whose error is bounded); with an older
        one it waits, so a loop slower than that falls behind the wall clock (the achieved
        rate) instead of losing accuracy.
        """
        dt = self.dt
        n = 0
        while not self.plant.done and n < self.max_catchup:
            due = self.wall0 + (self.plant.k + 1) * dt
            if now < due:
                return
            newest = self._newest()
            if newest < self.plant.k and (newest < self.plant.k - self.max_force_age
                                          or now < due + self.force_wait):
                return
            self._advance()
            n += 1

    def _finish(self):
        if self.step_timer is not None:
            self.step_timer.cancel()
        wall = self._summarize()
        self.get_logger().info(
            f'{self.get_name()}: done, {self.plant.k} steps in {wall:.2f} s '
            f'({self.plant.k / wall:.0f} steps/s), {self.late_forces} steps used the previous '
            "sample's force")
        if self.exit_at_end:
            self.finished.set()

    def _summarize(self):
        """Put the run's figures into the statistics; return the run's wall time [s]."""
        wall = max(time.monotonic() - self.wall0, 1e-9)
        lat = common.percentiles(self.latency)
        jit = common.percentiles([abs(x - self.dt) for x in self.periods])
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
            # real time: steps taken more than one period after they were due
            deadline_misses=sum(1 for x in self.lags if x > self.dt),
            lag_p99_s=common.percentiles(self.lags)[1],
            lag_max_s=max(self.lags, default=float('nan')),
            step_cost_p50_s=cost[0], step_cost_p99_s=cost[1], completed=self.plant.done)
        return wall

    def drain(self, executor):
        """Let in-flight force messages arrive before exit (for complete statistics)."""
        common.spin_until(executor, lambda: False, 0.2)

    def close(self):
        """Write the statistics file (forces counted after the drain; so far if stopped)."""
        if self.started and 'steps' not in self.stats.data:
            self._summarize()
        self.stats.data['forces_received'] = self.n_forces
        self.stats.write()
