"""Fail-safe state, diagnostics and the start-up parameter agreement of actuator and controller.

:class:`Health` holds a node's active faults and its fallback state: it logs one line on
entering the fallback and one on leaving it (never per message), leaves only after the inputs
have been healthy for ``recovery_time`` (no flapping; at start-up at once), adds one line if a
worse fault (ERROR) joins a fallback that is already on, and publishes
``diagnostic_msgs/DiagnosticArray`` on ``/diagnostics`` on every change and every ``period``.

:class:`PeerCheck` is the start-up agreement: when a peer node (``plant``, ``controller``,
``actuator`` in the same namespace) appears, it reads the peer's key parameters through the
peer's standard ``get_parameters`` service and compares them with its own. A disagreement on a
parameter that must agree is a fault (ERROR, safe current) until that peer goes away; on a
parameter that only should agree it is one warning.
"""

import math
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.srv import GetParameters
from rclpy.clock import Clock, ClockType
from rclpy.parameter import parameter_value_to_python

from mr_suspension.nodes import common, contract as c

OK = DiagnosticStatus.OK
WARN = DiagnosticStatus.WARN
ERROR = DiagnosticStatus.ERROR


def steady_clock():
    """Return a steady (monotonic) clock for watchdog timers (immune to clock jumps)."""
    return Clock(clock_type=ClockType.STEADY_TIME)


class Health:
    """Active faults, fallback state with one log line per transition, ``/diagnostics``."""

    def __init__(self, node, action, recovery_time, period, lockstep, values=None, corner=None):
        """``corner``: the corner this status is about, for a node that serves several."""
        self.node = node
        self.action = action  # e.g. 'safe current 1 A to the driver'
        self.recovery_time = recovery_time
        self.period = period
        self.values = values or (lambda: ())
        # The node's clock (monotonic seconds), looked up per call: a test may swap it.
        self.clock = lambda: getattr(node, 'clock', time.monotonic)()
        self.log = node.get_logger()
        self.label = node.get_name() if corner is None else f'{node.get_name()} ({corner})'
        self.faults = {}  # key -> (level, reason)
        self.fallback = False
        self.started = False  # True once the node has left its start-up fallback
        self.clear_since = None
        self.entered = 0.0
        self.episodes = 0
        self.last_pub = -math.inf
        self.pub = getattr(node, 'diagnostics_pub', None) or node.create_publisher(
            DiagnosticArray, c.DIAGNOSTICS, common.qos(c.DIAGNOSTICS, lockstep))
        node.diagnostics_pub = self.pub
        self.name = f'{node.get_fully_qualified_name()}: fail-safe'
        self.hardware_id = node.get_namespace().strip('/') or 'corner'
        if corner is not None:
            self.name += f' {corner}'
            ns = node.get_namespace().strip('/')
            self.hardware_id = f'{ns}/{corner}' if ns else corner

    def has(self, key):
        """Return True while fault ``key`` is active."""
        return key in self.faults

    def set(self, key, level, reason, now=None):  # noqa: A003 - the natural name
        """Activate (or update) fault ``key``; enter the fallback if not in it (one log line)."""
        now = self.clock() if now is None else now
        known = self.faults.get(key)
        worst = self.level()
        self.faults[key] = (level, reason)
        self.clear_since = None
        if self.fallback and level > worst:
            # A worse fault joins a fallback already on (e.g. a peer mismatch while waiting
            # for sensors): one more line, or it would never be told.
            self.log.error(f'{self.label}: {reason} (in fallback: {self.action})')
            self.publish(now)
        elif not self.fallback:
            self.fallback = True
            self.entered = now
            self.episodes += 1
            text = f'{self.label}: {reason}; fallback: {self.action}'
            if level == ERROR:
                self.log.error(text)
            else:
                self.log.warning(text)
            self.publish(now)
        elif known is None or known[0] != level:
            self.publish(now)

    def clear(self, key, now=None):
        """Deactivate fault ``key``; the fallback ends ``recovery_time`` after the last one."""
        if key not in self.faults:
            return
        now = self.clock() if now is None else now
        del self.faults[key]
        if not self.faults:
            self.clear_since = now
        self.tick(now, publish=True)

    def tick(self, now=None, publish=False):
        """Leave the fallback when due; publish the status when due (every ``period``)."""
        now = self.clock() if now is None else now
        if self.fallback and not self.faults:
            hold = self.recovery_time if self.started else 0.0
            if now - self.clear_since >= hold:
                self.fallback = False
                self.started = True
                self.log.info(f'{self.label}: inputs healthy again; left the fallback after '
                              f'{now - self.entered:.3f} s')
                publish = True
        elif not self.fallback:
            self.started = True
        if publish or now - self.last_pub >= self.period:
            self.publish(now)

    def level(self):
        """Diagnostic level: OK, or the worst active fault (WARN while recovering)."""
        if not self.fallback:
            return OK
        return max((lvl for lvl, _ in self.faults.values()), default=WARN)

    def message(self, now):
        """One-line status text."""
        if not self.fallback:
            return 'ok'
        if not self.faults:
            return f'recovering: inputs healthy for {now - self.clear_since:.3f} s'
        return '; '.join(reason for _, reason in self.faults.values())

    def publish(self, now=None):
        """Publish the status on ``/diagnostics``."""
        now = self.clock() if now is None else now
        self.last_pub = now
        status = DiagnosticStatus(level=self.level(), name=self.name,
                                  message=self.message(now), hardware_id=self.hardware_id)
        pairs = [('fallback', str(self.fallback).lower()), ('action', self.action),
                 ('faults', ','.join(sorted(self.faults)) or 'none'),
                 ('episodes', str(self.episodes)),
                 ('in_fallback_s', f'{now - self.entered:.3f}' if self.fallback else '0')]
        pairs += [(k, str(v)) for k, v in self.values()]
        status.values = [KeyValue(key=k, value=v) for k, v in pairs]
        msg = DiagnosticArray()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.status = [status]
        self.pub.publish(msg)


def _agree(ours, theirs):
    if isinstance(ours, (int, float)) and isinstance(theirs, (int, float)) \
            and not isinstance(ours, bool) and not isinstance(theirs, bool):
        return math.isclose(float(ours), float(theirs), rel_tol=1e-9, abs_tol=1e-12)
    return ours == theirs


class PeerCheck:
    """Start-up agreement of key parameters with the peer nodes (their parameter services).

    ``rules`` maps a peer node name to ``[(parameter, must_agree), ...]``; ``mine`` holds this
    node's values. Peers are looked for in this node's namespace every ``period`` (steady
    clock); each is checked once when it appears (again if it goes away and comes back). A
    parameter a peer does not declare is not compared (for instance sensor drivers in place of
    the plant: no ``plant`` node at all, nothing to compare).
    """

    def __init__(self, node, health, mine, rules, period=0.25):
        self.node = node
        self.health = health
        self.mine = mine
        self.rules = rules
        ns = node.get_namespace().rstrip('/')
        self.clients = {peer: node.create_client(GetParameters, f'{ns}/{peer}/get_parameters')
                        for peer in rules}
        self.state = dict.fromkeys(rules)  # None, 'pending', 'ok' or 'bad'
        self.checked = {}  # peer -> list of compared (name, ours, theirs)
        self.timer = node.create_timer(period, self._tick, clock=steady_clock())

    def _tick(self):
        for peer, client in self.clients.items():
            st = self.state[peer]
            if not client.service_is_ready():
                if st in ('ok', 'bad'):  # the peer went away: forget its verdict
                    self.state[peer] = None
                    self.health.clear('params:' + peer)
                continue
            if st is None:
                self.state[peer] = 'pending'
                req = GetParameters.Request(names=[n for n, _ in self.rules[peer]])
                client.call_async(req).add_done_callback(
                    lambda fut, p=peer: self._done(p, fut))

    def _done(self, peer, fut):
        try:
            values = [parameter_value_to_python(v) for v in fut.result().values]
        except Exception as exc:  # noqa: B902 - a failed call is retried, never fatal
            self.node.get_logger().debug(f'parameter check of {peer} failed: {exc}')
            self.state[peer] = None
            return
        hard, soft, compared = [], [], []
        for (name, must), theirs in zip(self.rules[peer], values):
            if theirs is None:
                continue
            ours = self.mine[name]
            compared.append((name, ours, theirs))
            if not _agree(ours, theirs):
                (hard if must else soft).append(f'{name} {ours!r} here, {theirs!r} on {peer}')
        self.checked[peer] = compared
        if soft:
            self.node.get_logger().warning(f'{self.node.get_name()}: model parameters differ '
                                           f'from {peer}: ' + '; '.join(soft))
        if hard:
            self.state[peer] = 'bad'
            self.health.set('params:' + peer, ERROR,
                            f'parameters disagree with {peer}: ' + '; '.join(hard))
        else:
            self.state[peer] = 'ok'
