"""Modal controller node: the full car's modal sky-hook in place of four corner controllers.

Runs in the car's namespace. Subscribes to the body IMU (``body/imu``: vertical specific force
at the centre of gravity, pitch and roll rates) and to every corner's sensors
(``<corner>/imu/body``, ``imu/wheel``, ``stroke`` and, when the corners' inverse damper model
reads it, ``coil_current``); never to ground truth. Runs
:class:`~mr_suspension.sim.full_car_stepper.ModalControllerStepper` (heave, pitch and roll
sky-hook, distributed to the four dampers, each turned into a current by its corner's estimation,
inverse model and clip) once per sample and publishes every corner's ``current_command``.

A sample is run once the body IMU and every corner's three sensors with the same stamp are in.
Fail-safe, as the corner controller's (:mod:`mr_suspension.nodes.controller`), per corner: each
corner has its own fallback state, log lines and ``/diagnostics`` status
(``/modal_controller: fail-safe front_left``, hardware id the corner's namespace). A fault of
a corner's sensors (stale, never arrived, frozen, NaN/inf, clock jump, stamps off the node clock)
puts that corner on ``fallback_current``; the others keep the modal law (in real time a corner
whose sensors are stale is no longer waited for; its last valid values stand in for the law).
A fault of the body IMU, the modal law's input, puts all four corners on ``fallback_current``,
as does a parameter mismatch with the full-car plant; one with a corner's actuator that corner.
The watchdog runs every ``watchdog_period`` on the steady clock and keeps publishing the
fallback current of corners whose samples stopped. Lock-step: samples in stamp order, waiting
for the coil currents of the step before if read; no timing faults.
"""

from collections import deque
from dataclasses import fields
import functools
import math
import threading
import time

from rclpy.node import Node
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Float64

from mr_suspension.control.modal import MODAL_LAWS, ModalParams
from mr_suspension.nodes import cdr, common, contract as c, health
from mr_suspension.nodes.controller import MOTION
from mr_suspension.nodes.health import WARN
from mr_suspension.nodes.sensor_watch import SensorWatch
from mr_suspension.sim.full_car_stepper import ModalControllerStepper

NODE = 'modal_controller'
BODY = 'body'  # pending-sample key of the body IMU
SENSORS = (c.IMU_BODY, c.IMU_WHEEL, c.STROKE)
BODY_MOTION = 0.01  # [m/s^2] body IMU change that counts as motion (1 mg)
GAINS = tuple(f for f in fields(ModalParams) if f.metadata.get('range'))


class _Router:
    """Parameter-check faults to the corners: the plant's to all, an actuator's to its own."""

    def __init__(self, healths, corners):
        self.healths = healths
        self.corners = corners

    def _targets(self, key):
        peer = key.partition(':')[2]
        for corner, h in zip(self.corners, self.healths):
            if peer.startswith(corner + '/'):
                return (h,)
        return self.healths

    def set(self, key, level, reason, now=None):  # noqa: A003 - Health's interface
        for h in self._targets(key):
            h.set(key, level, reason, now)

    def clear(self, key, now=None):
        for h in self._targets(key):
            h.clear(key, now)


class ModalControllerNode(Node):
    """Modal sky-hook on the body IMU and the corners' sensors, fail-safe per corner."""

    def __init__(self, context=None, parameter_overrides=None, **kwargs):
        super().__init__(NODE, context=context, parameter_overrides=parameter_overrides,
                         **kwargs)
        d = common.node_defaults(NODE)
        gains = {'law': common.declare(self, d, 'law', 'Modal law: '
                                       + ', '.join(MODAL_LAWS))}
        for f in GAINS:
            lo, hi, unit, hint, _ = f.metadata['range']
            gains[f.name] = common.declare(self, d, f.name, f'Modal sky-hook: {hint} [{unit}]',
                                           lo, hi)
        self.config = common.declare_full_car(self, d, modal=ModalParams(**gains))
        self.lockstep = common.declare(self, d, 'lockstep', 'Lock-step: run once per sample '
                                       'after the coil currents of the step before')
        self.fs = fs = common.declare_fail_safe(
            self, d, NODE, timeout_scope=' (of a corner: that corner; the body IMU: all corners)',
            coil_text="Subscribe to each corner's coil_current")
        self.stats = common.Stats(fs.stats_file)
        self.stepper = ModalControllerStepper(self.config).warm_up()
        self.use_coil = fs.coil_feedback == 'on' or \
            (fs.coil_feedback == 'auto' and self.stepper.uses_field)
        self.corners = c.CORNERS
        n = len(self.corners)
        self.finished = threading.Event()
        self.clock = time.monotonic  # of the fault logic (a test may run it on virtual time)
        self.pub_cmd = [self.create_publisher(Float64, f'{corner}/{c.CURRENT_COMMAND}',
                                              common.qos(c.CURRENT_COMMAND, self.lockstep))
                        for corner in self.corners]
        over = QoSOverridingOptions.with_default_policies()
        self.create_subscription(Imu, c.BODY_IMU, self._on_body,
                                 common.qos(c.BODY_IMU, self.lockstep, loop_reader=True),
                                 qos_overriding_options=over, raw=True)
        readers = {c.IMU_BODY: (Imu, self._on_imu), c.IMU_WHEEL: (Imu, self._on_imu),
                   c.STROKE: (JointState, self._on_stroke)}
        for i, corner in enumerate(self.corners):
            for topic in SENSORS:
                cls, cb = readers[topic]
                self.create_subscription(cls, f'{corner}/{topic}',
                                         functools.partial(cb, i, topic),
                                         common.qos(topic, self.lockstep, loop_reader=True),
                                         qos_overriding_options=over, raw=True)
            if self.use_coil:
                self.create_subscription(Float64, f'{corner}/{c.COIL_CURRENT}',
                                         functools.partial(self._on_coil, i),
                                         common.qos(c.COIL_CURRENT, self.lockstep), raw=True)
        self.tpl_cmd = cdr.Template(Float64(), ('data',), stamped=False)
        self.watch = [SensorWatch(MOTION, fs.sensor_timeout, fs.frozen_timeout,
                                  fs.frozen_requires_motion) for _ in range(n)]
        self.body_watch = SensorWatch({c.BODY_IMU: BODY_MOTION}, self.fs.sensor_timeout,
                                      fs.frozen_timeout, fs.frozen_requires_motion)
        self.coil = [deque() for _ in range(n)]  # lock-step: coil current k - 1, per corner
        self.coil_latest = [math.nan] * n
        self.held = [(0.0, 0.0, 0.0)] * n  # newest finite sensor values per corner
        self.absent = set()  # real time: corners whose sensors are stale (not waited for)
        self.dt_ns = int(round(self.config.dt * 1e9))
        self.pending = {}
        self.k = 0
        self.n_cmd = [0] * n
        self.n_fallback = [0] * n
        self.n_publish_failed = 0  # refused by the middleware (common.publish)
        self.last_input = time.monotonic()
        self.last_law = [-math.inf] * n
        self.last_cmd = [-math.inf] * n
        self.gate = None
        action = f'fallback current {self.fs.fallback_current:g} A commanded'
        self.health = [health.Health(self, action, fs.recovery_time, fs.diagnostic_period,
                                     self.lockstep, functools.partial(self._diagnostic_values,
                                                                      i), corner=corner)
                       for i, corner in enumerate(self.corners)]
        names = ('rate', 'lockstep', 'vehicle', 'damper', 'driver', 'gravity')
        mine = {name: self.get_parameter(name).value for name in names}
        rules = {'full_car_plant': [('rate', True), ('lockstep', True), ('gravity', True),
                                    ('vehicle', False), ('damper', False), ('driver', False)]}
        for corner in self.corners:
            rules[f'{corner}/actuator'] = [('rate', True), ('lockstep', True),
                                           ('damper', False), ('driver', False)]
        self.peers = health.PeerCheck(self, _Router(self.health, self.corners), mine, rules)
        steady = health.steady_clock()
        if self.lockstep:
            self.gate = common.MatchGate(self, [(p, 1 + fs.recorders) for p in self.pub_cmd],
                                         self._run_samples)
            self.create_timer(fs.diagnostic_period, self._tick_health, clock=steady)
        else:
            for h in self.health:
                h.set('stale', WARN, 'no sensor data yet')
            self.create_timer(self.fs.watchdog_period, self._on_tick, clock=steady)

    @property
    def fallback(self):
        """Fallback state per corner (True: the fallback current is commanded)."""
        return [h.fallback for h in self.health]

    # -- inputs ----------------------------------------------------------------------------

    def _store(self, key, watch, name, stamp, value, check):
        """Take a sensor sample; ``check``: the scalar the real-time checks look at."""
        now = self.clock()
        if not self.stats.marked:
            self.stats.mark()
        self.last_input = time.monotonic()
        accepted, jump = watch.receive(
            name, stamp, check, now, None if self.lockstep else self.get_clock().now().nanoseconds)
        if not accepted:
            return
        if jump is not None:
            self._clock_jump(key, watch, name, stamp, jump, now)
        if self.lockstep and (stamp < self.k * self.dt_ns
                              or not common.check_grid(self, stamp, self.dt_ns)):
            return  # lock-step: a sample the plant re-sent after a stall, already controlled
        self.pending.setdefault(stamp, {})[key] = value
        self._run_samples()

    def _on_body(self, raw):
        stamp, w_roll, w_pitch, acc = cdr.imu_body(raw)
        a_z = acc - self.fs.gravity
        self._store(BODY, self.body_watch, c.BODY_IMU, stamp, (a_z, w_pitch, w_roll), a_z)

    def _on_imu(self, i, topic, raw):
        stamp, acc = cdr.imu_acc_z(raw)
        self._store((i, topic), self.watch[i], topic, stamp, acc - self.fs.gravity,
                    acc - self.fs.gravity)

    def _on_stroke(self, i, topic, raw):
        stamp, position, _, _ = cdr.joint_state(raw)
        x = float(position[0]) if position else math.nan
        self._store((i, topic), self.watch[i], topic, stamp, x, x)

    def _on_coil(self, i, raw):
        self.last_input = time.monotonic()
        value = cdr.float64(raw)
        self.coil_latest[i] = value
        if self.lockstep:
            self.coil[i].append(value)
            self._run_samples()

    # -- control ---------------------------------------------------------------------------

    def _complete(self, sample):
        if BODY not in sample:
            return False
        return all((i, t) in sample for i in range(len(self.corners)) if i not in self.absent
                   for t in SENSORS)

    def _run_samples(self):
        if self.gate is not None and not self.gate.check():
            return
        n = len(self.corners)
        while self.pending:
            # Lock-step: the samples in order of their stamps k dt (a gap, a sample lost on a
            # best-effort link and re-sent by the plant, is waited for).
            key = self.k * self.dt_ns if self.lockstep else min(self.pending)
            sample = self.pending.get(key, {})
            if not self._complete(sample):
                if self.lockstep or len(self.pending) < 8:
                    return
                if BODY not in sample:  # real time: never completes (message lost)
                    del self.pending[key]
                    continue
            if self.lockstep:
                if self.use_coil and self.k > 0 and not all(self.coil):
                    return
                coil = [q.popleft() for q in self.coil] if self.use_coil and self.k > 0 \
                    else [math.nan] * n
            else:
                coil = list(self.coil_latest)
            del self.pending[key]
            self._command(sample, coil)
            self.k += 1

    def _command(self, sample, coil):
        """Run the modal law on a sample; publish each corner's command or its fallback."""
        now = self.clock()
        body = sample.get(BODY)
        body_ok = body is not None and common.finite(*body)
        if body is not None:
            self._fault_all('body_value', None if body_ok else 'non-finite body IMU value',
                            now)
        corners = []
        fresh = []
        for i, h in enumerate(self.health):
            present = all((i, t) in sample for t in SENSORS)
            values = tuple(sample.get((i, t), math.nan) for t in SENSORS)
            good = present and common.finite(*values)
            if good:
                self.held[i] = values
                if 'value' in h.faults:
                    h.clear('value', now)
            elif present and 'value' not in h.faults:
                h.set('value', WARN, 'non-finite sensor value', now)
            fresh.append(good)
            corners.append(self.held[i] + (coil[i],))
        cmds = [self.fs.fallback_current] * len(corners)
        if body_ok:
            cmds = self.stepper.step(body, corners)
            for i, good in enumerate(fresh):
                if good:
                    self.last_law[i] = now
        for i, h in enumerate(self.health):
            ok = body_ok and fresh[i] and not h.fallback
            self._publish(i, cmds[i] if ok else self.fs.fallback_current, now)

    def _publish(self, i, i_cmd, now):
        if self.health[i].fallback:
            self.n_fallback[i] += 1
        common.publish(self, self.pub_cmd[i], self.tpl_cmd.pack(0, float(i_cmd)))
        self.last_cmd[i] = now
        self.n_cmd[i] += 1

    # -- fail-safe (real time) ---------------------------------------------------------------

    def _fault_all(self, key, reason, now):
        """Set (reason given) or clear a fault of every corner."""
        for h in self.health:
            if reason is not None:
                if h.faults.get(key, (None, None))[1] != reason:
                    h.set(key, WARN, reason, now)
            elif key in h.faults:
                h.clear(key, now)

    def _clock_jump(self, key, watch, name, stamp, delta_ns, now):
        if delta_ns < 0:  # the old time base's incomplete samples will never complete
            for k in [k for k in self.pending if k > stamp]:
                del self.pending[k]
        reason = watch.jump_reason(name, delta_ns)
        if key == BODY:
            if 'body_clock' not in self.health[0].faults:
                self._fault_all('body_clock', reason, now)
            return
        h = self.health[key[0]]
        if 'clock' not in h.faults:
            h.set('clock', WARN, reason, now)

    def _stale(self, i, now):
        reason = self.watch[i].stale(now)
        if reason is None and now - self.last_law[i] > self.fs.sensor_timeout:
            reason = "no complete sensor sample (same stamp on body/imu and the corner's " \
                f'imu/body, imu/wheel and stroke) for {self.fs.sensor_timeout:g} s'
        return reason

    def _check(self, now):
        body_stale = self.body_watch.stale(now)
        self._fault_all('body_stale', None if body_stale is None else 'body IMU: ' + body_stale,
                        now)
        moving = any(w.moving(now) for w in self.watch)
        body_frozen = self.body_watch.frozen(now, moving)
        self._fault_all('body_frozen', None if body_frozen is None
                        else 'body IMU: ' + body_frozen, now)
        if 'body_clock' in self.health[0].faults and self.body_watch.jump_over(now):
            self._fault_all('body_clock', None, now)
        self.absent = set()
        for i, h in enumerate(self.health):
            if self.watch[i].stale(now) is not None:
                self.absent.add(i)
            for key, reason in (('stale', self._stale(i, now)),
                                ('frozen', self.watch[i].frozen(now))):
                if reason is not None:
                    h.set(key, WARN, reason, now)
                elif key in h.faults:
                    h.clear(key, now)
            if 'clock' in h.faults and self.watch[i].jump_over(now):
                h.clear('clock', now)

    def _diagnostic_values(self, i):
        now = self.clock()
        ages = self.watch[i].ages_ms(now)
        ages.update(self.body_watch.ages_ms(now))
        return (('fallback_current_A', f'{self.fs.fallback_current:g}'),
                ('commands_in_fallback', self.n_fallback[i]),
                ('samples_dropped', self.watch[i].n_dropped + self.body_watch.n_dropped)) \
            + tuple((f'age_ms {t}', a) for t, a in ages.items())

    def _tick_health(self):
        for h in self.health:
            h.tick()

    def _on_tick(self):
        now = self.clock()
        self._check(now)
        for i, h in enumerate(self.health):
            h.tick(now)
            if h.fallback and now - self.last_cmd[i] >= 0.5 * self.fs.watchdog_period:
                self._publish(i, self.fs.fallback_current, now)  # no samples come: keep commanding

    def drain(self, executor):
        """On shutdown, handle the messages still queued (clean statistics)."""
        common.drain(executor, self)

    def close(self):
        """Write the statistics file."""
        self.stats.data.update(
            commands=dict(zip(self.corners, self.n_cmd)),
            fallback_steps=dict(zip(self.corners, self.n_fallback)),
            fallback_episodes={cn: h.episodes for cn, h in zip(self.corners, self.health)},
            samples=self.k, publish_failed=self.n_publish_failed,
            received={cn: dict(w.n_sensor) for cn, w in zip(self.corners, self.watch)}
            | {c.BODY_IMU: self.body_watch.n_sensor[c.BODY_IMU]})
        self.stats.write()


def main(args=None):
    """Console script ``modal_controller``."""
    return common.run(ModalControllerNode, args)


if __name__ == '__main__':
    main()
