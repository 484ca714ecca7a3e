"""Actuator node: current driver (Wonder Box) and MR damper.

Subscribes to ``current_command`` and to the damper motion (joint ``suspension`` of
``truth/state``: a real damper is moved by the corner). Clocked by the motion samples (the plant's
fixed rate): per sample it advances the driver and fluid by one step with the newest valid
command, evaluates the damper law at that stroke and rate and publishes ``damper/force`` (force
and tangent ``dF/dv``, stamped with the motion sample) and the measured ``coil_current``
(:class:`~mr_suspension.sim.stepper.ActuatorStepper`).

Real time: each motion sample is answered at once with the newest valid command, so the force
is normally back at the plant before its next step; the command is then usually the one computed
from the previous sensor sample (one sample, 1 ms, of command latency, against about 25 ms of
driver and fluid response). Lock-step pairs the ``k``-th command with the ``k``-th motion
sample, which is the simulator's order exactly; with a driver dead time of one sample or more
(the Wonder Box has 3 ms) force ``k`` does not depend on command ``k``, so the force is published
as soon as motion ``k`` arrives and command ``k`` is applied afterwards: the same numbers, with the
controller off the plant-actuator critical path. With ``coupling_delay`` d > 0 (the plant applies
force ``k`` to step ``k + d``) the damper is evaluated with the field current of sample ``k + d``,
which the dead-time buffer already holds (exact for d < dead time in samples).

Fail-safe (real time; :mod:`mr_suspension.nodes.health`, fault matrix in ``docs/nodes.md``):
commands are checked: NaN/inf are rejected (the previous command is held) and values outside
``[current_min, current_max]`` are clamped; neither refreshes the command time, so only valid
in-range commands keep the actuator out of its fallback. With no such command for
``command_timeout`` (controller dead, silent, NaN/inf or always out of range) it applies
``safe_current``. With no motion sample for ``motion_timeout`` (plant dead) it cannot publish
forces, but keeps stepping the driver at ``safe_current`` on its watchdog (steady clock, every
``watchdog_period``) and publishes the coil current. It leaves a fallback after
``recovery_time`` of healthy inputs; one log line on entering and one on leaving, and a
``diagnostic_msgs/DiagnosticArray`` on ``/diagnostics``. At start-up it checks ``rate``,
``lockstep``, ``coupling_delay`` (lock-step) and the corner's parameter sets against the plant's
and the controller's parameters (:class:`~mr_suspension.nodes.health.PeerCheck`); a mismatch is
an ERROR and ``safe_current`` (also in lock-step) until that peer restarts.
"""

from collections import deque
import math
import threading
import time

from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from mr_suspension.nodes import cdr, common, contract as c, health
from mr_suspension.nodes.health import ERROR, WARN
from mr_suspension.sim.stepper import ActuatorStepper

NODE = 'actuator'
SUSPENSION = c.JOINTS_TRUTH.index('suspension')


class ActuatorNode(Node):
    """Wonder Box current driver plus MR damper force law."""

    def __init__(self, context=None, parameter_overrides=None, **kwargs):
        super().__init__(NODE, context=context, parameter_overrides=parameter_overrides,
                         **kwargs)
        d = common.node_defaults(NODE)
        self.config = common.declare_corner(self, d)
        self.lockstep = common.declare(self, d, 'lockstep', 'Pair the k-th command with the '
                                       'k-th motion sample (lock-step)')
        self.current_min = common.declare(self, d, 'current_min', 'Lowest accepted command '
                                          '[A]; lower ones are clamped', 0.0, 10.0)
        self.current_max = common.declare(self, d, 'current_max', 'Highest accepted command '
                                          '[A]; higher ones are clamped', 0.0, 10.0)
        self.safe_current = common.declare(self, d, 'safe_current', 'Current applied before the '
                                           'first command and in every fallback [A]', 0.0, 10.0)
        self.command_timeout = common.declare(
            self, d, 'command_timeout', 'Real time: no valid in-range command for this long '
            'gives safe_current [s]', 0.0005, 10.0)
        self.motion_timeout = common.declare(
            self, d, 'motion_timeout', 'Real time: no motion sample for this long (plant dead): '
            'no forces, the driver is stepped at safe_current [s]', 0.0005, 10.0)
        self.watchdog_period = common.declare(self, d, 'watchdog_period', 'Real time: fault '
                                              'check period (steady clock) [s]', 0.0005, 1.0)
        recovery_time = common.declare(self, d, 'recovery_time', 'Inputs healthy this long '
                                       'before leaving a fallback [s]', 0.0, 10.0)
        diagnostic_period = common.declare(self, d, 'diagnostic_period', 'Period of the '
                                           '/diagnostics status (also sent on every change) '
                                           '[s]', 0.01, 60.0)
        self.coupling_delay = common.declare(
            self, d, 'coupling_delay', 'Lock-step: the plant applies each force this many '
            'samples late (set it as the plant does); the damper is evaluated with the field '
            'current of that later sample, exact within the driver dead time', 0, 10)
        recorders = common.declare(self, d, 'recorders', 'Lock-step: recorders to wait for on '
                                   'damper/force and coil_current before the first output', 0, 10)
        self.stats = common.Stats(common.declare(self, d, 'stats_file', 'Write run statistics '
                                                 'as JSON here on exit ("" = off)'))
        if self.current_min > self.current_max:
            raise ValueError('actuator: current_min must be <= current_max')
        self.stepper = ActuatorStepper(self.config).warm_up()
        self.finished = threading.Event()
        self.clock = time.monotonic  # of the fault logic (a test may run it on virtual time)
        self.pub_force = self.create_publisher(JointState, c.DAMPER_FORCE,
                                               common.qos(c.DAMPER_FORCE, self.lockstep))
        self.pub_coil = self.create_publisher(Float64, c.COIL_CURRENT,
                                              common.qos(c.COIL_CURRENT, self.lockstep))
        # Serialized messages (raw=True), read with the fast CDR readers.
        self.create_subscription(Float64, c.CURRENT_COMMAND, self._on_command,
                                 common.qos(c.CURRENT_COMMAND, self.lockstep), raw=True)
        self.create_subscription(
            JointState, c.TRUTH_STATE, self._on_motion,
            common.qos(c.TRUTH_STATE, self.lockstep, loop_reader=True), raw=True)
        self.gate = None
        if self.lockstep:
            self.gate = common.MatchGate(self, [(self.pub_force, 1 + recorders),
                                                (self.pub_coil, recorders)],
                                         self._run_lockstep)
        force = JointState()
        force.header.frame_id = c.FRAME_SUSPENSION
        force.name = list(c.JOINTS_DAMPER)
        force.position = [0.0, 0.0]
        force.velocity = [0.0, 0.0]
        force.effort = [0.0, 0.0]
        self.tpl_force = cdr.Template(force, ('position[0]', 'velocity[0]', 'effort[0]',
                                              'effort[1]'))
        self.tpl_coil = cdr.Template(Float64(), ('data',), stamped=False)
        self.command = self.safe_current  # newest accepted command (clamped)
        self.command_time = -math.inf  # monotonic time of the newest valid in-range command
        self.have_command = False
        self.commands = deque()
        self.motions = {}  # lock-step: stamp -> motion sample not answered yet
        self.dt_ns = common.step_ns(self.config)
        self.answers = {}
        self.n_repeated = 0
        self.forces_done = 0
        self.commands_done = 0
        self.n_rejected = 0
        self.n_clamped = 0
        self.bad_at_valid = (0, 0)  # (rejected, clamped) at the newest valid command
        self.n_commands = 0
        self.last_input = time.monotonic()
        self.n_commands_run = 0
        self.n_forces = 0
        self.n_motion = 0
        self.motion_time = None  # monotonic time of the newest motion sample
        self.driver_time = None  # monotonic time the driver was last stepped
        self.last_x = 0.0
        self.applied = self.safe_current  # current last given to the driver
        self.n_alone = 0  # driver steps without motion (plant dead)
        self.n_publish_failed = 0
        self.health = health.Health(self, f'safe current {self.safe_current:g} A to the driver',
                                    recovery_time, diagnostic_period, self.lockstep,
                                    self._diagnostic_values)
        names = ('rate', 'lockstep', 'vehicle', 'damper', 'driver', 'coupling_delay')
        mine = {n: self.get_parameter(n).value for n in names}
        corner = [('rate', True), ('lockstep', True), ('vehicle', True), ('damper', True),
                  ('driver', True)]
        self.peers = health.PeerCheck(self, self.health, mine, {
            'plant': corner + ([('coupling_delay', True)] if self.lockstep else []),
            'controller': [('rate', True), ('lockstep', True), ('vehicle', False),
                           ('damper', False), ('driver', False)]})
        if self.lockstep:
            self.create_timer(diagnostic_period, lambda: self.health.tick(),
                              clock=health.steady_clock())
        else:
            self.health.set('command', WARN, 'no valid command yet')
            self.health.set('motion', WARN, 'no motion sample yet')
            self.create_timer(self.watchdog_period, self._on_watchdog,
                              clock=health.steady_clock())

    def validate(self, value, now):
        """Return the current to apply for a received command (clamped; NaN/inf hold).

        Only a finite in-range command refreshes the command time (``now``, monotonic).
        """
        if not math.isfinite(value):
            self.n_rejected += 1
            return self.command
        if value < self.current_min or value > self.current_max:
            self.n_clamped += 1
            self.command = min(max(value, self.current_min), self.current_max)
            return self.command
        self.command = value
        self.command_time = now
        self.bad_at_valid = (self.n_rejected, self.n_clamped)
        if 'command' in self.health.faults:
            self.health.clear('command', now)
        return value

    def _on_command(self, msg):
        now = self.clock()
        self.last_input = time.monotonic()
        self.n_commands += 1
        if self.stats.marked:
            self.n_commands_run += 1
        i = self.validate(cdr.float64(msg), now)
        self.have_command = True
        if self.lockstep:
            self.commands.append(i)
            self._run_lockstep()

    # -- fail-safe (real time) ---------------------------------------------------------------

    def _command_fault(self, now):
        age = now - self.command_time
        since = f'for {1e3 * age:.0f} ms' if math.isfinite(age) else 'yet'
        rejected = self.n_rejected - self.bad_at_valid[0]
        clamped = self.n_clamped - self.bad_at_valid[1]
        level = WARN
        if self.count_publishers(c.CURRENT_COMMAND) == 0:
            reason, level = f'no controller publishes {c.CURRENT_COMMAND} (dead?)', ERROR
        elif rejected or clamped:
            reason = (f'no valid command {since}: {rejected} rejected (NaN/inf), {clamped} '
                      f'outside [{self.current_min:g}, {self.current_max:g}] A')
        else:
            reason = f'no command {since} (controller silent)'
        self.health.set('command', level, reason, now)

    def _on_watchdog(self):
        now = self.clock()
        faults = self.health.faults
        if now - self.command_time > self.command_timeout and 'command' not in faults:
            self._command_fault(now)
        if self.motion_time is not None and now - self.motion_time > self.motion_timeout:
            if 'motion' not in faults:
                self.health.set('motion', ERROR, f'no motion sample ({c.TRUTH_STATE}) for '
                                f'{1e3 * (now - self.motion_time):.0f} ms (plant dead?): no '
                                'damper force published', now)
            self._step_alone(now)
        self.health.tick(now)

    def _step_alone(self, now):
        """Plant dead: step the driver at the safe current up to ``now``, publish the coil."""
        dt = self.config.dt
        n = int((now - self.driver_time) / dt)
        if n > 1000:  # starved for over a second at 1 kHz: do not replay all of it
            self.driver_time = now - n * dt
            n = 1000
        for _ in range(n):
            coil = self.stepper.step(self.safe_current, self.last_x, 0.0)[0]
            common.publish(self, self.pub_coil, self.tpl_coil.pack(0, coil))
        self.driver_time += n * dt
        self.n_alone += n
        self.applied = self.safe_current

    def _diagnostic_values(self):
        now = self.clock()
        motion = 'never' if self.motion_time is None else f'{1e3 * (now - self.motion_time):.1f}'
        return (('safe_current_A', f'{self.safe_current:g}'), ('applied_A', f'{self.applied:g}'),
                ('command_age_ms', f'{1e3 * (now - self.command_time):.1f}'),
                ('motion_age_ms', motion), ('rejected_commands', self.n_rejected),
                ('clamped_commands', self.n_clamped), ('forces_published', self.n_forces),
                ('driver_steps_without_motion', self.n_alone))

    def _on_motion(self, msg):
        stamp, position, velocity, _ = cdr.joint_state(msg)
        if len(position) <= SUSPENSION or len(velocity) <= SUSPENSION:
            self.get_logger().error('actuator: truth/state without the suspension joint',
                                    throttle_duration_sec=1.0)
            return
        self.last_input = time.monotonic()
        if not self.stats.marked:
            self.stats.mark()
        motion = (stamp, position[SUSPENSION], velocity[SUSPENSION])
        if self.lockstep:
            if not common.check_grid(self, stamp, self.dt_ns):
                return
            if stamp < self.forces_done * self.dt_ns or stamp in self.motions:
                # A sample the plant re-sent after a stall: answer again if answered.
                self.n_repeated += 1
                if stamp in self.answers:
                    common.publish(self, self.pub_force, self.answers[stamp])
                return
            self.n_motion += 1
            self.motions[stamp] = motion
            self._run_lockstep()
            return
        # Real time: answer at once with the newest command, so the force is back at the plant
        # before its next step (the command is then normally one sample old).
        now = self.clock()
        self.n_motion += 1
        self.motion_time = now
        faults = self.health.faults
        if 'motion' in faults:
            self.health.clear('motion', now)
        if now - self.command_time > self.command_timeout and 'command' not in faults:
            self._command_fault(now)
        self._apply(self.safe_current if self.health.fallback else self.command, motion)
        self.driver_time = now
        self.last_x = motion[1]

    def _run_lockstep(self):
        if not self.gate.check():
            return
        # Samples in order of their stamps k dt: a gap (a sample lost on the best-effort link
        # and re-sent by the plant) is waited for.
        if not self.stepper.command_ahead:
            while self.commands and self.forces_done * self.dt_ns in self.motions:
                i = self.commands.popleft()
                self._apply(self.safe_current if self.health.fallback else i,
                            self.motions.pop(self.forces_done * self.dt_ns))
                self.forces_done += 1
            return
        # The driver's dead time makes force k independent of command k: answer the plant as
        # soon as motion k is in (command k-1 applied), then take command k. The controller
        # is off the critical path; the numbers are those of step() (same order of updates).
        progress = True
        while progress:
            progress = False
            due = self.forces_done * self.dt_ns
            if self.forces_done == self.commands_done and due in self.motions:
                stamp, x, v = self._checked(self.motions.pop(due))
                self._publish(stamp, x, v, *self.stepper.force(x, v, self.coupling_delay))
                self.forces_done += 1
                progress = True
            if self.commands_done < self.forces_done and self.commands:
                i = self.commands.popleft()
                self.stepper.command(self.safe_current if self.health.fallback else i)
                self.commands_done += 1
                progress = True

    def _checked(self, motion):
        stamp, x, v = motion
        if not common.finite(x, v):
            self.get_logger().error('actuator: non-finite stroke motion; damper force held '
                                    'at zero', throttle_duration_sec=1.0)
            x, v = 0.0, 0.0
        return stamp, x, v

    def _apply(self, i_cmd, motion):
        self.applied = i_cmd
        stamp, x, v = self._checked(motion)
        self._publish(stamp, x, v, *self.stepper.step(i_cmd, x, v))

    def _publish(self, stamp, x, v, coil, _field, force, tangent):
        raw = self.tpl_force.pack(stamp, x, v, force, tangent)
        common.publish(self, self.pub_force, raw)
        if self.lockstep:
            self.answers[stamp] = raw
            if len(self.answers) > 32:
                del self.answers[next(iter(self.answers))]
        self.n_forces += 1
        common.publish(self, self.pub_coil, self.tpl_coil.pack(0, coil))

    def drain(self, executor):
        """On shutdown, handle the messages still queued (clean statistics)."""
        common.drain(executor, self)

    def close(self):
        """Write the statistics file."""
        self.stats.data.update(commands=self.n_commands, commands_after_start=self.n_commands_run,
                               forces_published=self.n_forces, motion_samples=self.n_motion,
                               repeated_motion=self.n_repeated,
                               rejected=self.n_rejected, clamped=self.n_clamped,
                               fallback_episodes=self.health.episodes,
                               driver_steps_without_motion=self.n_alone,
                               publish_failed=self.n_publish_failed)
        self.stats.write()


def main(args=None):
    """Console script ``actuator``."""
    return common.run(ActuatorNode, args)


if __name__ == '__main__':
    main()
