"""Code shared by the nodes: environment, parameters, QoS, the corner config, stats, ``run``.

Parameter defaults live in ``config/nodes/<node>.yaml`` (ROS 2 parameter files, key
``/**/<node>``); each node declares its parameters with a description and a range here and takes
the default from that file, so ``--ros-args --params-file`` and ``-p`` override them as usual.
"""

from dataclasses import dataclass
import json
import math
import os
from pathlib import Path
import resource
import signal
import sys
import threading
import time

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
import rclpy
from rclpy.experimental import EventsExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
import yaml

from mr_suspension.nodes import contract
from mr_suspension.sim import config as cfg
from mr_suspension.sim.corner import build_corner


def ensure_environment():
    """Prepare this process's environment for rclpy; call it before the first ``rclpy.init``.

    Points ``AMENT_PREFIX_PATH`` at this interpreter's prefix if it does not cover it, and
    ``FASTDDS_DEFAULT_PROFILES_FILE`` at the package's ``config/fastdds.xml`` unless a Fast DDS
    profile file is already set (the middleware reads it once, at its first participant).
    """
    prefix = sys.prefix
    parts = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    if prefix not in parts:
        os.environ['AMENT_PREFIX_PATH'] = os.pathsep.join([prefix] + parts)
    if not (os.environ.get('FASTDDS_DEFAULT_PROFILES_FILE')
            or os.environ.get('FASTRTPS_DEFAULT_PROFILES_FILE')):
        profile = fastdds_profile()
        if profile.is_file():
            os.environ['FASTDDS_DEFAULT_PROFILES_FILE'] = str(profile)


def fastdds_profile():
    """Return the path of the package's Fast DDS profile (``config/fastdds.xml``)."""
    return cfg.config_dir() / 'fastdds.xml'


def qos(topic, lockstep=False, loop_reader=False):
    """Return the QoS profile of a contract topic: reliable, keep-last ``depth``.

    Volatile in real time (matches any reliable publisher, e.g. a sensor driver); transient
    local in lock-step, so that a message sent before discovery has matched a publisher with a
    subscriber is still delivered (a lost message would stall the lock-step loop).

    ``loop_reader``: a lock-step subscription on a stamped link of the plant-actuator-controller
    loop (sensors, ``truth/state``, ``damper/force``) is best effort instead. A reliable reader
    costs the writer a timer notification and acknowledgement traffic per sample, about 15 % of
    the loop's CPU; the loop instead recovers a lost sample itself: the plant re-sends the
    samples it waits on after ``resend_after`` and every node answers a repeated stamp
    idempotently (:mod:`mr_suspension.nodes.plant`). Writers stay reliable, so recorders keep
    reliable delivery.
    """
    t = contract.ALL_TOPICS[topic]
    rel = ReliabilityPolicy.RELIABLE if t.reliability == 'reliable' \
        else ReliabilityPolicy.BEST_EFFORT
    dur = DurabilityPolicy.TRANSIENT_LOCAL if lockstep else DurabilityPolicy.VOLATILE
    if lockstep and loop_reader:
        rel, dur = ReliabilityPolicy.BEST_EFFORT, DurabilityPolicy.VOLATILE
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=t.depth, reliability=rel,
                      durability=dur)


class MatchGate:
    """Lock-step start gate: open once every given publisher has its expected subscribers.

    Publishing before a subscriber is matched would still be delivered (transient local) but
    only after a middleware heartbeat, a stall of up to seconds; so the lock-step nodes hold
    their first outputs until their own publishers are matched. ``retry`` is called every
    10 ms while the gate is closed.
    """

    def __init__(self, node, pubs_and_counts, retry):
        self.pairs = list(pubs_and_counts)
        self.retry = retry
        self.open = False
        self.timer = node.create_timer(0.01, self._tick)

    def check(self):
        """Return True once open (and stop polling)."""
        if not self.open and all(p.get_subscription_count() >= n for p, n in self.pairs):
            self.open = True
            self.timer.cancel()
        return self.open

    def _tick(self):
        if self.check():
            self.retry()


def lower_priority(niceness):
    """Raise the nice value of every thread of this process to at least ``niceness``.

    Linux keeps a nice value per thread and the middleware's threads already run when a node is
    built, so each one in ``/proc/self/task`` is set (threads started later inherit it). Raising
    it needs no privileges. Returns the nice value of the calling thread afterwards.
    """
    if niceness <= os.getpriority(os.PRIO_PROCESS, 0):
        return os.getpriority(os.PRIO_PROCESS, 0)
    tids = [int(t) for t in os.listdir('/proc/self/task')] \
        if os.path.isdir('/proc/self/task') else [0]
    for tid in tids:
        try:
            os.setpriority(os.PRIO_PROCESS, tid, niceness)
        except OSError:
            pass  # a thread that ended meanwhile
    return os.getpriority(os.PRIO_PROCESS, 0)


def drain(executor, node, idle=0.1, limit=3.0):
    """Spin until ``node.last_input`` (monotonic time) is ``idle`` seconds old (max ``limit``)."""
    end = time.monotonic() + limit
    spin_until(executor, lambda: time.monotonic() - node.last_input > idle
               or time.monotonic() > end, limit + 1.0, step=0.02)


def publish(node, pub, raw):
    """Publish ``raw``; on a middleware refusal log (throttled), count and return False.

    A reliable writer whose readers lag a full queue behind (a starved recorder on an
    overloaded machine) can refuse a sample after blocking; the fail-safe nodes must keep
    running then (the peers' timeouts see the gap), so the refusal is counted in
    ``node.n_publish_failed``, not raised.
    """
    try:
        pub.publish(raw)
        return True
    except _rclpy.RCLError as exc:
        node.n_publish_failed = getattr(node, 'n_publish_failed', 0) + 1
        node.get_logger().error(f'{node.get_name()}: {pub.topic_name} not published ({exc}); '
                                f'{node.n_publish_failed} so far', throttle_duration_sec=5.0)
        return False


def node_defaults_path(node):
    """Path of ``config/nodes/<node>.yaml``."""
    return cfg.config_dir() / 'nodes' / f'{node}.yaml'


def node_defaults(node):
    """Return the default parameters of ``node`` from ``config/nodes/<node>.yaml``."""
    with open(node_defaults_path(node), encoding='utf-8') as fh:
        data = yaml.safe_load(fh) or {}
    for key, value in data.items():
        if key.rstrip('/').split('/')[-1] == node:
            return dict(value.get('ros__parameters', {}))
    raise KeyError(f'{node_defaults_path(node)}: no entry for node {node!r}')


def declare(node, defaults, name, description, lo=None, hi=None):
    """Declare parameter ``name`` with its default from ``defaults`` and return its value.

    ``lo``/``hi`` give a FloatingPointRange (float default) or IntegerRange (int default).
    """
    value = defaults[name]
    desc = ParameterDescriptor(description=description)
    if lo is not None:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise TypeError(f'{name}: a range needs a numeric default')
        if isinstance(value, int):
            desc.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
        else:
            desc.floating_point_range = [FloatingPointRange(from_value=float(lo),
                                                            to_value=float(hi), step=0.0)]
    return node.declare_parameter(name, value, desc).value


@dataclass(frozen=True)
class FailSafe:
    """Fail-safe and bookkeeping parameters of a controller node (corner or modal)."""

    gravity: float
    sensor_timeout: float
    fallback_current: float
    frozen_timeout: float
    frozen_requires_motion: bool
    recovery_time: float
    diagnostic_period: float
    watchdog_period: float
    coil_feedback: str
    recorders: int
    stats_file: str


def declare_fail_safe(node, defaults, who, timeout_scope='', watchdog_scope='Real time',
                      coil_text='Subscribe to the measured coil_current'):
    """Declare a controller's fail-safe parameters (descriptions, ranges); return them.

    ``who`` names the node in errors; the other arguments word the descriptions that differ
    between the corner controller and the modal one.
    """
    def get(name, description, lo=None, hi=None):
        return declare(node, defaults, name, description, lo, hi)

    out = FailSafe(
        gravity=get('gravity', 'Gravity removed from the accelerometers [m/s^2]', 0.0, 20.0),
        sensor_timeout=get('sensor_timeout', 'Sensors older than this trigger the fallback'
                           f'{timeout_scope} [s]', 0.0005, 10.0),
        fallback_current=get('fallback_current', 'Safe fixed current commanded in every '
                             'fallback [A]', 0.0, 10.0),
        frozen_timeout=get('frozen_timeout', 'Real time: a sensor whose value has not changed '
                           'for this long is frozen [s]', 0.001, 10.0),
        frozen_requires_motion=get('frozen_requires_motion', 'Frozen only while another sensor '
                                   'changes (exact simulated values at rest never change); '
                                   'false for real, noisy sensors'),
        recovery_time=get('recovery_time', 'Inputs healthy this long before leaving a '
                          'fallback [s]', 0.0, 10.0),
        diagnostic_period=get('diagnostic_period', 'Period of the /diagnostics status (also '
                              'sent on every change) [s]', 0.01, 60.0),
        watchdog_period=get('watchdog_period', f'{watchdog_scope}: stale-sensor check period '
                            '[s]; the fallback starts within sensor_timeout + watchdog_period',
                            0.0005, 1.0),
        coil_feedback=get('coil_feedback', f'{coil_text}: "auto" (if the law reads the field '
                          'current), "on" or "off" (the law uses its last command)'),
        recorders=get('recorders', 'Lock-step: recorders to wait for on current_command '
                      'before the first command', 0, 10),
        stats_file=get('stats_file', 'Write run statistics as JSON here on exit ("" = off)'))
    if out.coil_feedback not in ('auto', 'on', 'off'):
        raise ValueError(f'{who}: coil_feedback must be auto, on or off, got '
                         f'{out.coil_feedback!r}')
    return out


def declare_corner(node, defaults):
    """Declare the parameter-set names and rate shared by the nodes; return the CornerConfig."""
    names = {}
    for kind, key in (('vehicles', 'vehicle'), ('dampers', 'damper'), ('drivers', 'driver'),
                      ('controllers', 'controller')):
        names[key] = declare(node, defaults, key,
                             f'{kind[:-1]} parameter set: a name in config/{kind} or a YAML path')
    rate = declare(node, defaults, 'rate', 'Fixed step rate [Hz] (all nodes must agree)',
                   100.0, 10000.0)
    return corner_config(rate=rate, **names)


def corner_config(vehicle='city_car', damper='rd1005_bingham', driver='wonder_box',
                  controller='skyhook_onoff', rate=1000.0):
    """Build the corner the nodes and the offline reference use from parameter-set names.

    The same builder as the CLI and the evaluation
    (:func:`mr_suspension.sim.corner.build_corner`): the controller gets the plant knowledge
    of the corner (vehicle, damper model, driver range).
    """
    return build_corner(controller, vehicle, damper, driver, dt=1.0 / rate)


def declare_full_car(node, defaults, modal=None):
    """Declare the parameter-set names and rate of a full-car node; return the FullCarConfig.

    ``vehicle`` names a full-car set (body and axles); ``damper`` and ``driver`` one set for
    all four corners or one per axle or corner (:func:`corner_sets`); ``controller`` applies
    to all four corners (with ``modal``, a
    :class:`~mr_suspension.control.modal.ModalParams`, the corner law gives each corner's
    estimation, inverse model and current range).
    """
    names = {}
    for kind, key, what in (
            ('vehicles', 'vehicle', 'full-car parameter set (body, front and rear corners)'),
            ('dampers', 'damper', 'damper parameter set(s): one for all four corners, '
             '"front, rear" or four in corner order, each'),
            ('drivers', 'driver', 'driver parameter set(s): one for all four corners, '
             '"front, rear" or four in corner order, each'),
            ('controllers', 'controller', 'controller parameter set of each corner')):
        names[key] = declare(node, defaults, key, f'{what}: a name in config/{kind} or a YAML '
                             'path')
    rate = declare(node, defaults, 'rate', 'Fixed step rate [Hz] (all nodes must agree)',
                   100.0, 10000.0)
    return full_car_config(rate=rate, modal=modal, **names)


def full_car_config(vehicle='lisa_full_car', damper='rd1005_bingham', driver='wonder_box',
                    controller='skyhook_onoff', rate=1000.0, modal=None):
    """Build the full car the nodes and the offline reference use from parameter-set names.

    Corner ``i`` of it (:meth:`~mr_suspension.sim.full_car_sim.FullCarConfig.corner`) equals
    :func:`corner_config` with ``vehicle='<vehicle>:<corner>'``, which the corner nodes use.
    """
    from mr_suspension.sim import corner as cn
    from mr_suspension.sim.full_car_sim import FullCarConfig
    data = cfg.load_yaml('vehicles', vehicle)
    if isinstance(data, dict) and 'front' not in data and 'rear' not in data:
        raise ValueError(f'vehicle {vehicle!r} is a quarter car (no front and rear corners); '
                         'the full car needs a full-car set, e.g. lisa_full_car')
    car = cfg.load_full_car(vehicle)
    loaded = {}

    def four(load, value, what):
        out = []
        for name in corner_sets(value, what):
            if (what, name) not in loaded:
                loaded[what, name] = load(name)
            out.append(loaded[what, name])
        return tuple(out)

    return FullCarConfig(car=car, damper=four(cn.load_damper, damper, 'damper'),
                         driver=four(cn.load_driver, driver, 'driver'),
                         controller=cn.load_controller(controller), modal=modal, dt=1.0 / rate)


def corner_sets(value, what='damper'):
    """Four parameter-set names, in corner order, from a full-car node's ``damper``/``driver``.

    One name serves all four corners; ``"front, rear"`` one per axle; four names, comma
    separated, one per corner (:data:`~mr_suspension.nodes.contract.CORNERS`).
    """
    names = [n.strip() for n in str(value).split(',')]
    if all(names) and len(names) in (1, 2, 4):
        return tuple(names * 4 if len(names) == 1 else
                     (names[0], names[0], names[1], names[1]) if len(names) == 2 else names)
    raise ValueError(f'{what} {value!r}: give one set for all corners, "front, rear", or four '
                     f'in corner order ({", ".join(contract.CORNERS)})')


def corner_vehicle(vehicle, corner):
    """Vehicle parameter of a full car's corner node: ``'<full car set>:<corner>'``."""
    return f'{vehicle}:{corner}'


def stamp_to_ns(stamp):
    """``builtin_interfaces/Time`` to integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def set_stamp(header, ns):
    """Write integer nanoseconds into a header stamp."""
    header.stamp.sec = int(ns // 1_000_000_000)
    header.stamp.nanosec = int(ns % 1_000_000_000)


def step_ns(config):
    """Step of a corner config in integer nanoseconds (lock-step stamps are ``k`` times it)."""
    return int(round(config.dt * 1e9))


def check_grid(node, stamp, dt_ns):
    """Lock-step: log an error if ``stamp`` is not a multiple of the step (rates disagree)."""
    if stamp % dt_ns:
        node.get_logger().error(
            f'{node.get_name()}: stamp {stamp} ns is not on the {dt_ns} ns step grid; do all '
            'nodes use the same rate?', throttle_duration_sec=5.0)
        return False
    return True


def finite(*values):
    """Return True when every value is a finite float."""
    return all(math.isfinite(v) for v in values)


def percentiles(values, ps=(50, 99)):
    """Percentiles of a list (NaN when empty)."""
    import numpy as np
    if len(values) == 0:
        return [float('nan')] * len(ps)
    return [float(v) for v in np.percentile(np.asarray(values, dtype=float), ps)]


def cpu_time():
    """Return the CPU time [s] (user + system) of this process so far, all threads."""
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


class Stats:
    """Per-node run statistics written as JSON on shutdown (parameter ``stats_file``)."""

    def __init__(self, path):
        self.path = path
        self.data = {}
        self.wall0 = time.monotonic()
        self.cpu0 = cpu_time()
        self.marked = False

    def mark(self):
        """Start the CPU and wall clocks of the run here (after imports and set-up)."""
        self.wall0 = time.monotonic()
        self.cpu0 = cpu_time()
        self.data['start_unix'] = time.time()
        self.marked = True

    def write(self):
        """Write the statistics plus CPU and wall time since :meth:`mark` (no-op w/o path)."""
        if not self.path:
            return
        self.data['cpu_s'] = cpu_time() - self.cpu0
        self.data['wall_s'] = time.monotonic() - self.wall0
        self.data['cpu_fraction'] = self.data['cpu_s'] / max(self.data['wall_s'], 1e-9)
        Path(self.path).parent.mkdir(parents=True, exist_ok=True)
        with open(self.path, 'w', encoding='utf-8') as fh:
            json.dump(self.data, fh, indent=1)


def spin_until(executor, condition, timeout_sec, step=0.05):
    """Spin ``executor`` until ``condition()`` holds or ``timeout_sec`` passes; return it.

    Spins in slices of ``step`` seconds with ``spin_until_future_complete`` on a future that
    never completes (``spin_once`` handles one event per call, far too slow at 1 kHz); the
    timeout is always finite (the events executor can hang otherwise).
    """
    never = executor.create_future()
    end = time.monotonic() + timeout_sec
    while not condition():
        left = end - time.monotonic()
        if left <= 0.0:
            return condition()
        executor.spin_until_future_complete(never, timeout_sec=min(step, left))
    return True


def run_composed(builders, args=None):
    """Run several nodes in one process and one events executor (a composed node set).

    ``builders``: callables ``context -> node``; the first node's ``finished`` event (and
    SIGINT/SIGTERM) ends the process; then every node drains (``drain``), closes (``close``)
    and is destroyed. The process runs at the lowest ``niceness`` any of its nodes asks for
    (a node without one asks for 0): one niced node lowers a process of its own, DDS included.
    """
    ensure_environment()
    stop = threading.Event()
    context = rclpy.Context()
    rclpy.init(args=args if args is not None else sys.argv, context=context,
               signal_handler_options=SignalHandlerOptions.NO)

    def _on_signal(signum, frame):
        stop.set()

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _on_signal)
    nodes = []
    try:
        for build in builders:
            nodes.append(build(context))
        niceness = min(getattr(node, 'niceness', 0) or 0 for node in nodes)
        if niceness:
            lower_priority(niceness)
        executor = EventsExecutor(context=context)
        for node in nodes:
            executor.add_node(node)
        finished = getattr(nodes[0], 'finished', threading.Event())
        spin_until(executor, lambda: stop.is_set() or finished.is_set() or not context.ok(),
                   math.inf, step=0.1)
        for node in nodes:
            if hasattr(node, 'drain'):
                node.drain(executor)
    finally:
        for node in nodes:
            if hasattr(node, 'close'):
                node.close()
            node.destroy_node()
        rclpy.try_shutdown(context=context)
    return 0


def run(node_cls, args=None):
    """Run one node until SIGINT/SIGTERM or until it asks to stop; clean shutdown either way.

    The node may define ``finished`` (a threading.Event it sets to end the process) and
    ``close()`` (called after spinning stops, before the context is shut down). This is
    :func:`run_composed` with one node.
    """
    return run_composed([lambda context: node_cls(context=context)], args)
