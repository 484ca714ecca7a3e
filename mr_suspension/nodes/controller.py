"""Controller node: from the car's sensors to the coil-current command, at a fixed rate.

Subscribes only to what a car's sensors give: ``imu/body``, ``imu/wheel`` (specific force,
gravity removed here), ``stroke`` and the driver's measured ``coil_current``; never to ground
truth. Fills the measurement vector of :mod:`mr_suspension.control.laws` and runs the configured
law (:class:`~mr_suspension.sim.stepper.ControllerStepper`; the control core estimates body
velocity and stroke rate from these sensors), publishes ``current_command``. The measured coil
current fills the field-current slot (NaN until the first one: the core then uses its last
command). Only the laws that invert the damper model read that slot
(:func:`~mr_suspension.control.laws.uses_field`); with ``coil_feedback: auto`` the node
subscribes to ``coil_current`` only for them (one message a sample less on the loop otherwise).

* ``trigger: sample`` (default): the law runs once per sensor sample, as soon as the three
  sensor messages with the same stamp are in (the sensors' fixed rate; no added latency).
  ``trigger: timer``: a wall timer at ``rate`` runs the law on the newest value of every sensor
  (for sensor drivers whose stamps are not synchronised).
* Real time (both triggers): a watchdog every ``watchdog_period`` (steady clock; with
  ``trigger: timer`` the ``rate`` timer) commands ``fallback_current`` while any fault is active
  (:mod:`mr_suspension.nodes.health`, fault matrix in ``docs/nodes.md``): a sensor older than
  ``sensor_timeout`` or never arrived, no complete sample within it, a NaN/inf value, a sensor
  frozen (value unchanged for ``frozen_timeout`` while another one changes, or at all with
  ``frozen_requires_motion: false``), stamps off the node clock by more than ``sensor_timeout``
  (dropped) or jumping against their arrival times (clock jumps), or peers whose ``rate``,
  ``lockstep`` or gravity disagree. The law keeps running on valid samples during a fallback
  (its estimators stay continuous); the fallback ends after ``recovery_time`` of healthy
  inputs. One log line on entering and one on leaving; status on ``/diagnostics``.
* Lock-step: sample trigger that also waits for the coil current of the step before (when it
  subscribes to it), so the run is deterministic; no timing watchdog (the plant waits for the
  loop), NaN values and peer mismatches still give the fallback.
"""

from collections import deque
import math
import threading
import time

from rclpy.node import Node
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Float64

from mr_suspension.nodes import cdr, common, contract as c, health
from mr_suspension.nodes.health import WARN
from mr_suspension.nodes.sensor_watch import SensorWatch
from mr_suspension.sim.stepper import ControllerStepper

NODE = 'controller'
# Frozen-sensor check with frozen_requires_motion: a sensor counts as moving when its value
# changed by more than this within frozen_timeout (1 mg, 10 um). A simulated corner at rest
# changes by round-off only (1e-15 m/s^2, 1e-19 m), which is no motion.
MOTION = {c.IMU_BODY: 0.01, c.IMU_WHEEL: 0.01, c.STROKE: 1e-5}


class ControllerNode(Node):
    """Semi-active control law on sensor data with a stale-sensor fallback."""

    def __init__(self, context=None, parameter_overrides=None, **kwargs):
        super().__init__(NODE, context=context, parameter_overrides=parameter_overrides,
                         **kwargs)
        d = common.node_defaults(NODE)
        self.config = common.declare_corner(self, d)
        self.lockstep = common.declare(self, d, 'lockstep', 'Lock-step: run once per sensor '
                                       'sample after the coil current of the step before')
        self.fs = fs = common.declare_fail_safe(self, d, NODE,
                                                watchdog_scope='Real time, trigger sample')
        self.trigger = common.declare(self, d, 'trigger', 'Run the law per complete sensor '
                                      'sample ("sample") or on a wall timer ("timer")')
        if self.trigger not in ('sample', 'timer'):
            raise ValueError(f'controller: trigger must be sample or timer, got {self.trigger!r}')
        self.stats = common.Stats(fs.stats_file)
        self.stepper = ControllerStepper(self.config).warm_up()
        self.use_coil = fs.coil_feedback == 'on' or \
            (fs.coil_feedback == 'auto' and self.stepper.uses_field)
        self.finished = threading.Event()
        self.clock = time.monotonic  # of the fault logic (a test may run it on virtual time)
        self.pub_cmd = self.create_publisher(Float64, c.CURRENT_COMMAND,
                                             common.qos(c.CURRENT_COMMAND, self.lockstep))
        # Sensor QoS can be overridden by parameters (qos_overrides./<ns>/imu/body.subscription.
        # reliability etc.) to match a driver's publisher.
        over = QoSOverridingOptions.with_default_policies()
        for topic, cls, cb in ((c.IMU_BODY, Imu, self._on_imu_s),
                               (c.IMU_WHEEL, Imu, self._on_imu_u),
                               (c.STROKE, JointState, self._on_stroke)):
            self.create_subscription(cls, topic, cb,
                                     common.qos(topic, self.lockstep, loop_reader=True),
                                     qos_overriding_options=over, raw=True)
        if self.use_coil:
            self.create_subscription(Float64, c.COIL_CURRENT, self._on_coil,
                                     common.qos(c.COIL_CURRENT, self.lockstep), raw=True)
        self.tpl_cmd = cdr.Template(Float64(), ('data',), stamped=False)
        # Newest value, arrival time and the real-time checks per sensor.
        self.watch = SensorWatch(MOTION, self.fs.sensor_timeout, self.fs.frozen_timeout,
                                 self.fs.frozen_requires_motion)
        self.latest = self.watch.latest
        self.arrival = self.watch.arrival
        self.n_sensor = self.watch.n_sensor
        self.coil = deque()  # lock-step: coil current k - 1 for the command of sample k
        self.dt_ns = common.step_ns(self.config)
        self.coil_latest = math.nan
        self.pending = {}
        self.k = 0
        self.n_fallback = 0
        self.n_cmd = 0
        self.last_input = time.monotonic()
        self.last_law = -math.inf
        self.last_cmd = -math.inf
        self.n_cmd_run = 0
        self.n_publish_failed = 0  # refused by the middleware (common.publish)
        self.timer = None
        self.gate = None
        self.health = health.Health(self, f'fallback current {self.fs.fallback_current:g} A '
                                    'commanded', fs.recovery_time, fs.diagnostic_period,
                                    self.lockstep, self._diagnostic_values)
        names = ('rate', 'lockstep', 'vehicle', 'damper', 'driver', 'gravity')
        mine = {n: self.get_parameter(n).value for n in names}
        model = [('vehicle', False), ('damper', False), ('driver', False)]
        self.peers = health.PeerCheck(self, self.health, mine, {
            'plant': [('rate', True), ('lockstep', True), ('gravity', True)] + model,
            'actuator': [('rate', True), ('lockstep', True)] + model})
        steady = health.steady_clock()
        if self.lockstep:
            self.gate = common.MatchGate(self, [(self.pub_cmd, 1 + fs.recorders)],
                                         self._run_samples)
            self.create_timer(fs.diagnostic_period, lambda: self.health.tick(), clock=steady)
        else:
            self.health.set('stale', WARN, 'no sensor data yet')
            period = self.config.dt if self.trigger == 'timer' else self.fs.watchdog_period
            self.timer = self.create_timer(period, self._on_tick, clock=steady)

    @property
    def fallback(self):
        """True while the fallback current is commanded."""
        return self.health.fallback

    @property
    def n_dropped(self):
        """Samples dropped for a stamp off the node clock by more than ``sensor_timeout``."""
        return self.watch.n_dropped

    # -- inputs ----------------------------------------------------------------------------

    def _store(self, topic, stamp, value):
        now = self.clock()
        if not self.stats.marked:
            self.stats.mark()
        self.last_input = time.monotonic()
        accepted, jump = self.watch.receive(
            topic, stamp, value, now,
            None if self.lockstep else self.get_clock().now().nanoseconds)
        if not accepted:
            return
        if jump is not None:
            self._clock_jump(topic, stamp, jump, now)
        if self.lockstep and (stamp < self.k * self.dt_ns
                              or not common.check_grid(self, stamp, self.dt_ns)):
            return  # lock-step: a sample the plant re-sent after a stall, already controlled
        if self.lockstep or self.trigger == 'sample':
            self.pending.setdefault(stamp, {})[topic] = value
            self._run_samples()

    # Messages arrive serialized (raw=True) and are read with the fast CDR readers.

    # Real time: a sample older than sensor_timeout by its stamp (acquisition time; e.g. this
    # process was starved and works through a queue) is dropped, not controlled on; the
    # watchdog then applies the fallback until fresh samples come.

    def _on_imu_s(self, raw):
        stamp, acc = cdr.imu_acc_z(raw)
        self._store(c.IMU_BODY, stamp, acc - self.fs.gravity)

    def _on_imu_u(self, raw):
        stamp, acc = cdr.imu_acc_z(raw)
        self._store(c.IMU_WHEEL, stamp, acc - self.fs.gravity)

    def _on_stroke(self, raw):
        stamp, position, _, _ = cdr.joint_state(raw)
        self._store(c.STROKE, stamp, float(position[0]) if position else math.nan)

    def _on_coil(self, raw):
        self.last_input = time.monotonic()
        value = cdr.float64(raw)
        self.coil_latest = value
        if self.lockstep:
            self.coil.append(value)
            self._run_samples()

    # -- control ---------------------------------------------------------------------------

    def _command(self, acc_s, acc_u, x, field):
        """Run the law on a sample; publish its command, or the fallback current."""
        now = self.clock()
        if not common.finite(acc_s, acc_u, x):
            if 'value' not in self.health.faults:
                self.health.set('value', WARN, 'non-finite sensor value', now)
            i_cmd = self.fs.fallback_current
        else:
            if 'value' in self.health.faults:
                self.health.clear('value', now)
            self.last_law = now
            i_cmd = self.stepper.step(acc_s, acc_u, x, field)
            if self.health.fallback:
                i_cmd = self.fs.fallback_current
        self._publish(i_cmd, now)

    def _publish(self, i_cmd, now):
        if self.health.fallback:
            self.n_fallback += 1
        common.publish(self, self.pub_cmd, self.tpl_cmd.pack(0, float(i_cmd)))
        self.last_cmd = now
        self.n_cmd += 1
        if self.stats.marked:
            self.n_cmd_run += 1

    # -- fail-safe (real time) ---------------------------------------------------------------

    def _clock_jump(self, topic, stamp, delta_ns, now):
        if delta_ns < 0:  # the old time base's incomplete samples will never complete
            for key in [k for k in self.pending if k > stamp]:
                del self.pending[key]
        if 'clock' not in self.health.faults:
            self.health.set('clock', WARN, self.watch.jump_reason(topic, delta_ns), now)

    def _stale(self, now):
        reason = self.watch.stale(now)
        if reason is None and self.trigger == 'sample' \
                and now - self.last_law > self.fs.sensor_timeout:
            return 'no complete sensor sample (same stamp on imu/body, imu/wheel and stroke) ' \
                f'for {self.fs.sensor_timeout:g} s; use trigger: timer for unsynchronised sensors'
        return reason

    def _check(self, now):
        for key, reason in (('stale', self._stale(now)), ('frozen', self.watch.frozen(now))):
            if reason is not None:
                self.health.set(key, WARN, reason, now)
            elif key in self.health.faults:
                self.health.clear(key, now)
        if 'clock' in self.health.faults and self.watch.jump_over(now):
            self.health.clear('clock', now)

    def _diagnostic_values(self):
        ages = self.watch.ages_ms(self.clock())
        return (('fallback_current_A', f'{self.fs.fallback_current:g}'),
                ('commands_in_fallback', self.n_fallback),
                ('samples_dropped', self.n_dropped)) + tuple(
            (f'age_ms {t}', ages[t]) for t in self.latest)

    def _on_tick(self):
        now = self.clock()
        self._check(now)
        self.health.tick(now)
        if self.trigger == 'timer' and not self.health.has('stale'):
            self._command(self.latest[c.IMU_BODY], self.latest[c.IMU_WHEEL],
                          self.latest[c.STROKE], self.coil_latest)
        elif self.health.fallback and now - self.last_cmd >= 0.5 * self.fs.watchdog_period:
            self._publish(self.fs.fallback_current, now)  # no samples come: keep commanding

    def _run_samples(self):
        if self.gate is not None and not self.gate.check():
            return
        while self.pending:
            # Lock-step: the samples in order of their stamps k dt (a gap, a sample lost on the
            # best-effort link and re-sent by the plant, is waited for).
            key = self.k * self.dt_ns if self.lockstep else min(self.pending)
            sample = self.pending.get(key, ())
            if len(sample) < 3:
                if self.lockstep or len(self.pending) < 8:
                    return
                del self.pending[key]  # real time: a sample never completed (message lost)
                continue
            if self.lockstep:
                if self.use_coil and self.k > 0 and not self.coil:
                    return
                field = self.coil.popleft() if self.use_coil and self.k > 0 else math.nan
            else:
                field = self.coil_latest
            del self.pending[key]
            self._command(sample[c.IMU_BODY], sample[c.IMU_WHEEL], sample[c.STROKE], field)
            self.k += 1

    def drain(self, executor):
        """On shutdown, handle the messages still queued (clean statistics)."""
        common.drain(executor, self)

    def close(self):
        """Write the statistics file."""
        self.stats.data.update(commands=self.n_cmd, commands_after_start=self.n_cmd_run,
                               fallback_steps=self.n_fallback,
                               stale_samples_dropped=self.n_dropped,
                               fallback_episodes=self.health.episodes,
                               received=dict(self.n_sensor),
                               publish_failed=self.n_publish_failed)
        self.stats.write()


def main(args=None):
    """Console script ``controller``."""
    return common.run(ControllerNode, args)


if __name__ == '__main__':
    main()
