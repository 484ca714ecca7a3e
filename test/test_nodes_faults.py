"""Fault matrix of the fail-safe actuator and controller, in-process, on a virtual clock.

Each fault starts from a healthy loop (the peer or the law commanding 0 A) and must end at the
safe current (1 A) within the time ``docs/nodes.md`` states, with exactly one log line on
entering and one on leaving the fallback (read back from ``/rosout``), a ``/diagnostics`` status
of level WARN or ERROR while in fallback and OK after recovery. The truth is what a peer node
receives on the topics: the measured coil current, the current command, the log and the
diagnostics, not the nodes' internal state.

The nodes run their fault logic on ``node.clock`` (monotonic seconds); here it is a virtual
clock the test advances by one millisecond per sample, after each sample has been handled. The
stated times are thus checked exactly, whatever the load of the machine (a real-time scheduling
stall would otherwise be a real fault for the nodes); ``benchmarks/bench_faults.py`` measures
the same faults in real time. The nodes' own watchdog timers keep running on the steady clock
and see the virtual time; the test also calls the watchdog every ``watchdog_period`` of virtual
time.
"""

import math
import os
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import pytest
from rcl_interfaces.msg import Log
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Float64

from mr_suspension.nodes import common, contract as c
from mr_suspension.nodes.actuator import ActuatorNode
from mr_suspension.nodes.controller import ControllerNode
from mr_suspension.nodes.launch import _env, resolve_domain
from mr_suspension.nodes.plant import PlantNode
from mr_suspension.nodes.testing import add, params, ros_context

SAFE = 1.0
DT = 0.001  # one sample of the 1 kHz stream [s]
WATCHDOG = 0.005  # watchdog_period (both nodes)
RECOVERY = 0.1  # recovery_time (both nodes)
# Stated times [s] (docs/nodes.md, fault matrix) with the default parameters.
COMMAND_TIMEOUT = 0.025 + DT  # command_timeout + one motion sample
PLANT_DEAD = 0.025 + WATCHDOG  # motion_timeout + watchdog_period
SENSOR_STALE = 0.020 + WATCHDOG  # sensor_timeout + watchdog_period
FROZEN = 0.030 + WATCHDOG + 2 * DT  # frozen_timeout + watchdog_period + the next sample
AT_ONCE = DT  # on the first faulty sample
COIL_90 = 0.100  # coil current at 90 % of the safe current (Wonder Box lags included)
DEAD_TIME = 0.003  # Wonder Box dead time: the coil current answers a command this much later


class VirtualClock:
    """Monotonic seconds that advance only when the test says so."""

    def __init__(self):
        self.t = time.monotonic()

    def __call__(self):
        return self.t


class Peer(Node):
    """Stands in for the rest of the node set; records what the node under test publishes."""

    def __init__(self, context, clock):
        super().__init__('peer', context=context)
        self.now = clock
        self.pubs = {t: self.create_publisher(cls, t, common.qos(t)) for t, cls in (
            (c.CURRENT_COMMAND, Float64), (c.TRUTH_STATE, JointState), (c.IMU_BODY, Imu),
            (c.IMU_WHEEL, Imu), (c.STROKE, JointState))}
        self.clock_pub = self.create_publisher(Clock, c.CLOCK, 10)
        self.coil, self.cmd, self.diag, self.logs = [], [], [], []
        self.create_subscription(Float64, c.COIL_CURRENT,
                                 lambda m: self.coil.append((self.now(), m.data)),
                                 common.qos(c.COIL_CURRENT))
        self.create_subscription(Float64, c.CURRENT_COMMAND,
                                 lambda m: self.cmd.append((self.now(), m.data)),
                                 common.qos(c.CURRENT_COMMAND))
        self.create_subscription(DiagnosticArray, c.DIAGNOSTICS, self._on_diag,
                                 common.qos(c.DIAGNOSTICS))
        self.create_subscription(Log, '/rosout', lambda m: self.logs.append((self.now(), m)),
                                 QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))

    def _on_diag(self, msg):
        for st in msg.status:
            values = {kv.key: kv.value for kv in st.values}
            self.diag.append((self.now(), st.name, st.level, values['fallback']))

    def motion(self, ns):
        m = JointState()
        common.set_stamp(m.header, ns)
        m.name = list(c.JOINTS_TRUTH)
        m.position = [0.0, 0.0, 0.0, 0.001]
        m.velocity = [0.0, 0.0, 0.0, 0.0]
        self.pubs[c.TRUTH_STATE].publish(m)

    def sensors(self, ns, acc_s, acc_u, x):
        for topic, acc in ((c.IMU_BODY, acc_s), (c.IMU_WHEEL, acc_u)):
            m = Imu()
            common.set_stamp(m.header, ns)
            m.linear_acceleration.z = acc
            self.pubs[topic].publish(m)
        m = JointState()
        common.set_stamp(m.header, ns)
        m.name = [c.JOINT_STROKE]
        m.position = [x]
        self.pubs[c.STROKE].publish(m)

    def clock(self, ns):
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(int(ns), 1_000_000_000)
        self.clock_pub.publish(msg)

    def lines(self, node, t0):
        """Log lines of ``node`` received since ``t0``."""
        return [m for t, m in self.logs if t >= t0 and m.name.split('.')[-1] == node]

    def diags(self, node, t0=-math.inf):
        return [d for d in self.diag if d[0] >= t0 and d[1].endswith(f'/{node}: fail-safe')]


def _first(samples, t0, test):
    """Time after ``t0`` of the first recorded sample whose value passes ``test``."""
    return next((t - t0 for t, v in samples if t >= t0 and test(v)), math.inf)


def _settle(ex, done, what, timeout=10.0):
    """Spin until ``done()`` (every message of this sample handled), one event at a time."""
    end = time.monotonic() + timeout
    while not done():
        assert time.monotonic() < end, what
        ex.spin_once(timeout_sec=0.01)


class Loop:
    """Advance the virtual clock sample by sample; each sample is handled before the next."""

    def __init__(self, ex, clock, node, watchdog):
        self.ex, self.clock, self.node, self.watchdog = ex, clock, node, watchdog
        self.k = 0

    def run(self, seconds, step):
        """``step(k)`` publishes sample ``k`` and returns the condition that it was handled."""
        for _ in range(int(round(seconds / DT))):
            self.clock.t += DT
            _settle(self.ex, step(self.k), f'sample {self.k}')
            if self.k % int(round(WATCHDOG / DT)) == 0:
                self.watchdog()
            self.k += 1

    def flush(self):
        """Let the logs and diagnostics still on their way arrive (no time passes)."""
        common.spin_until(self.ex, lambda: False, 0.1)


def _check_episode(peer, node, t0):
    """One log line on entering, one on leaving; WARN/ERROR in fallback, then OK."""
    lines = peer.lines(node, t0)
    assert len(lines) == 2, [m.msg for m in lines]
    assert lines[0].level in (Log.WARN, Log.ERROR) and 'fallback' in lines[0].msg
    assert lines[1].level == Log.INFO and 'left the fallback' in lines[1].msg
    seq = peer.diags(node, t0)
    assert len(seq) >= 2 and all(level in (DiagnosticStatus.WARN, DiagnosticStatus.ERROR)
                                 and fb == 'true' for _, _, level, fb in seq[:-1]), seq
    assert seq[-1][2] == DiagnosticStatus.OK and seq[-1][3] == 'false'


ACTUATOR_FAULTS = {
    # fault: (command published during the fault, or None; motion published; stated time)
    'controller_silent': (None, True, COMMAND_TIMEOUT),
    'controller_dead': (None, True, COMMAND_TIMEOUT),
    'command_nan': (math.nan, True, COMMAND_TIMEOUT),
    'command_inf': (math.inf, True, COMMAND_TIMEOUT),
    'command_always_out_of_range': (-3.0, True, COMMAND_TIMEOUT),
    'plant_dead': (0.0, False, PLANT_DEAD),
}


@pytest.mark.parametrize('fault', sorted(ACTUATOR_FAULTS))
def test_actuator_fault_ends_at_safe_current(fault):
    command, motion, stated = ACTUATOR_FAULTS[fault]
    clock = VirtualClock()
    with ros_context() as (ctx, ex, nodes):
        act = add(ex, nodes, ActuatorNode(context=ctx, parameter_overrides=params(
            lockstep=False, safe_current=SAFE)))
        act.clock = clock
        peer = add(ex, nodes, Peer(ctx, clock))
        _settle(ex, lambda: peer.pubs[c.CURRENT_COMMAND].get_subscription_count() > 0
                and act.pub_coil.get_subscription_count() > 0, 'discovery')
        loop = Loop(ex, clock, act, act._on_watchdog)

        def sample(cmd, move):
            def step(k):
                n_cmd, n_motion, n_coil = act.n_commands, act.n_motion, len(peer.coil)
                if cmd is not None:
                    peer.pubs[c.CURRENT_COMMAND].publish(Float64(data=cmd))
                if move:
                    peer.motion(1_000_000 * k)
                return lambda: (act.n_commands == n_cmd + (cmd is not None)
                                and act.n_motion == n_motion + move
                                and len(peer.coil) >= n_coil + move)
            return step

        loop.run(0.15, sample(0.0, True))
        assert peer.coil[-1][1] < 0.01  # the peer's 0 A, not the safe current
        assert peer.diags('actuator')[-1][2] == DiagnosticStatus.OK
        if fault == 'controller_dead':
            peer.destroy_publisher(peer.pubs.pop(c.CURRENT_COMMAND))
            _settle(ex, lambda: act.count_publishers(c.CURRENT_COMMAND) == 0, 'publisher gone')
        t0 = clock()
        loop.run(0.2, sample(command, motion))
        assert abs(peer.coil[-1][1] - SAFE) < 0.01 and act.applied == SAFE
        t1 = clock()
        if fault == 'controller_dead':
            peer.pubs[c.CURRENT_COMMAND] = peer.create_publisher(
                Float64, c.CURRENT_COMMAND, common.qos(c.CURRENT_COMMAND))
            _settle(ex, lambda: act.count_publishers(c.CURRENT_COMMAND) == 1, 'publisher back')
        loop.run(0.2, sample(0.0, True))
        assert peer.coil[-1][1] < 0.05  # back under the peer's command
        loop.flush()
    # The safe current was commanded within the stated time: the coil current answers after
    # the driver's dead time (its first sample above 1 % bounds the command from above) ...
    t_rise = _first(peer.coil, t0, lambda v: v >= 0.01)
    assert t_rise <= stated + DEAD_TIME + 2 * DT, (fault, t_rise)
    # ... and follows with the driver's lag (plant dead: stepped on the watchdog, in bursts).
    t_90 = _first(peer.coil, t0, lambda v: v >= 0.9 * SAFE)
    assert t_90 <= COIL_90 and t_90 - t_rise <= 0.025, (fault, t_rise, t_90)
    _check_episode(peer, 'actuator', t0)
    lines = peer.lines('actuator', t0)
    assert ('plant dead' in lines[0].msg) == (fault == 'plant_dead')
    assert ('dead?' in lines[0].msg) == (fault in ('plant_dead', 'controller_dead'))
    # It leaves after recovery_time of healthy input (checked on the watchdog).
    t_ok = _first([(t, lvl) for t, _, lvl, _ in peer.diags('actuator')], t1,
                  lambda lvl: lvl == DiagnosticStatus.OK)
    assert RECOVERY <= t_ok <= RECOVERY + WATCHDOG + 2 * DT, t_ok


BASE = 50 * 10**9  # sim time of the first sample [ns]


def _feed(peer, k, stamp_offset=0, clock_offset=0, sensors=True, frozen=(), nan=()):
    """Sample ``k`` of a noisy sensor stream on sim time: ``(clock ns, sensors?)``."""
    ns = BASE + k * 1_000_000 + stamp_offset
    if sensors:
        wiggle = 0.01 * math.sin(0.7 * k)  # noisy sensors: the values always change
        acc_s = math.nan if c.IMU_BODY in nan else \
            9.81 + (0.0 if c.IMU_BODY in frozen else wiggle)
        acc_u = 9.81 + (0.0 if c.IMU_WHEEL in frozen else 2 * wiggle)
        x = 0.0 if c.STROKE in frozen else 1e-4 * wiggle
        peer.sensors(ns, acc_s, acc_u, x)
    return ns + clock_offset


BACK, AHEAD = {'stamp_offset': -10**9}, {'stamp_offset': 10**9}
CONTROLLER_FAULTS = {
    # fault: (stated time, stream during the fault, stream afterwards; None: healthy)
    'sensors_stale': (SENSOR_STALE, {'sensors': False}, None),
    'sensor_nan': (AT_ONCE, {'nan': (c.IMU_BODY,)}, None),
    'sensor_frozen': (FROZEN, {'frozen': (c.STROKE,)}, None),
    # Sim time (clock and stamps together) going back or jumping forward by 1 s, for good:
    # a fallback that ends by itself once the new time base has been consistent.
    'sim_time_backwards': (AT_ONCE, BACK, BACK),
    'sim_time_forward': (AT_ONCE, AHEAD, AHEAD),
    # The node's own clock steps 1 s ahead of the sensors' stamps (a wall-clock step) and back.
    'node_clock_step': (SENSOR_STALE, {'clock_offset': 10**9}, None),
}


def _controller_loop(ctx, ex, nodes, clock, **overrides):
    ctl = add(ex, nodes, ControllerNode(context=ctx, parameter_overrides=params(
        lockstep=False, controller='passive_0A', fallback_current=SAFE, use_sim_time=True,
        **overrides)))
    ctl.clock = clock
    peer = add(ex, nodes, Peer(ctx, clock))
    _settle(ex, lambda: peer.pubs[c.STROKE].get_subscription_count() > 0
            and peer.clock_pub.get_subscription_count() > 0
            and ctl.pub_cmd.get_subscription_count() > 0, 'discovery')

    def sample(**kwargs):
        def step(k):
            ns = BASE + k * 1_000_000 + kwargs.get('stamp_offset', 0) \
                + kwargs.get('clock_offset', 0)
            peer.clock(ns)  # sim time first, then the sensors stamped with it
            _settle(ex, lambda: ctl.get_clock().now().nanoseconds == ns, f'/clock {k}')
            n_in, n_cmd = sum(ctl.n_sensor.values()), ctl.n_cmd
            _feed(peer, k, **kwargs)
            n_new = 0 if kwargs.get('sensors') is False else 3
            return lambda: (sum(ctl.n_sensor.values()) == n_in + n_new
                            and len(peer.cmd) == ctl.n_cmd and ctl.n_cmd >= n_cmd)
        return step

    return ctl, peer, Loop(ex, clock, ctl, ctl._on_tick), sample


@pytest.mark.parametrize('fault', sorted(CONTROLLER_FAULTS))
def test_controller_fault_ends_at_fallback_current(fault):
    stated, during, after = CONTROLLER_FAULTS[fault]
    clock = VirtualClock()
    with ros_context() as (ctx, ex, nodes):
        ctl, peer, loop, sample = _controller_loop(ctx, ex, nodes, clock)
        loop.run(0.15, sample())
        assert not ctl.fallback and peer.cmd[-1][1] == 0.0
        assert peer.diags('controller')[-1][2] == DiagnosticStatus.OK
        t0 = clock()
        loop.run(0.2, sample(**during))
        if after is None:
            assert peer.cmd[-1][1] == SAFE
        t1 = clock()
        loop.run(0.2, sample(**(after or {})))
        assert not ctl.fallback and peer.cmd[-1][1] == 0.0
        loop.flush()
    t_safe = _first(peer.cmd, t0, lambda v: v == SAFE)
    assert t_safe <= stated + DT, (fault, t_safe)
    _check_episode(peer, 'controller', t0)
    t_law = _first([(t, v) for t, v in peer.cmd if t > t0 + t_safe], t0, lambda v: v == 0.0)
    if after is None:
        # recovery_time of healthy samples first (checked on the watchdog)
        assert RECOVERY <= t_law - (t1 - t0) <= RECOVERY + WATCHDOG + 2 * DT, t_law
    else:  # a jump: the clock fault clears sensor_timeout after it, then recovery_time
        assert 0.020 + RECOVERY <= t_law <= 0.020 + RECOVERY + 2 * WATCHDOG + 2 * DT, t_law


@pytest.mark.parametrize('requires_motion', [True, False])
def test_frozen_detector_and_exact_values_at_rest(requires_motion):
    """Constant exact values on all sensors (a simulated corner at rest): no fault by default.

    With frozen_requires_motion false (real, noisy sensors) they are one.
    """
    clock = VirtualClock()
    with ros_context() as (ctx, ex, nodes):
        ctl, peer, loop, sample = _controller_loop(
            ctx, ex, nodes, clock, frozen_requires_motion=requires_motion)
        loop.run(0.2, sample(frozen=(c.IMU_BODY, c.IMU_WHEEL, c.STROKE)))
        assert ctl.fallback == (not requires_motion)
        assert peer.cmd[-1][1] == (0.0 if requires_motion else SAFE)


@pytest.mark.parametrize('plant, controller, fault', [
    ({}, {}, False),
    ({'rate': 500.0}, {}, True),
    ({}, {'gravity': 9.0}, True),
])
def test_start_up_agreement_with_the_plant(plant, controller, fault):
    clock = VirtualClock()
    with ros_context() as (ctx, ex, nodes):
        add(ex, nodes, PlantNode(context=ctx, parameter_overrides=params(
            lockstep=False, exit_at_end=False, **plant)))
        ctl, peer, loop, sample = _controller_loop(ctx, ex, nodes, clock, **controller)
        loop.run(0.05, sample())
        _settle(ex, lambda: ctl.peers.state['plant'] in ('ok', 'bad'), 'parameter check')
        loop.run(0.05, sample())
        loop.flush()
    assert ctl.peers.state['plant'] == ('bad' if fault else 'ok')
    assert ('params:plant' in ctl.health.faults) == fault
    assert peer.cmd[-1][1] == (SAFE if fault else 0.0)  # fallback current or the law's 0 A
    errors = [m for m in peer.lines('controller', -math.inf) if m.level == Log.ERROR]
    assert len(errors) == int(fault)
    if fault:
        assert 'disagree with plant' in errors[0].msg
        assert peer.diags('controller')[-1][2] == DiagnosticStatus.ERROR


def test_node_set_domain_respects_the_user(monkeypatch):
    monkeypatch.setenv('ROS_DOMAIN_ID', '42')
    assert _env()['ROS_DOMAIN_ID'] == '42'
    assert _env(resolve_domain(None))['ROS_DOMAIN_ID'] == '42'
    assert 1 <= int(_env(resolve_domain('random'))['ROS_DOMAIN_ID']) <= 100
    assert _env(resolve_domain(7))['ROS_DOMAIN_ID'] == '7'
    monkeypatch.delenv('ROS_DOMAIN_ID')
    assert 'ROS_DOMAIN_ID' not in _env()
    with pytest.raises(ValueError, match='domain id'):
        resolve_domain(300)
    assert os.environ.get('ROS_DOMAIN_ID') is None
