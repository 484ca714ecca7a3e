"""Real-time checks of a synchronised sensor set: stale, frozen, off the clock, clock jumps.

Shared by the corner controller (one set: ``imu/body``, ``imu/wheel``, ``stroke``) and the modal
controller (one set per corner and one for the body IMU). :class:`SensorWatch` keeps each
sensor's newest value, arrival time (the node's fault clock, monotonic seconds) and stamp, and
reports the faults of the fault matrix in ``docs/nodes.md``:

* stale: a sensor older than ``sensor_timeout`` or never arrived;
* frozen: a value unchanged for ``frozen_timeout`` (with ``frozen_requires_motion`` only while
  another sensor of the set moves by more than its ``motion`` threshold);
* dropped: a sample stamped more than ``sensor_timeout`` off the node clock is not used;
* clock jump: stamps going back, or advancing more than ``sensor_timeout`` beyond their arrival
  times.
"""

import math


class SensorWatch:
    """Freshness and plausibility of one set of sensors (module doc)."""

    def __init__(self, motion, sensor_timeout, frozen_timeout, frozen_requires_motion):
        names = tuple(motion)
        self.motion = dict(motion)  # sensor -> change that counts as motion
        self.sensor_timeout = sensor_timeout
        self.timeout_ns = int(sensor_timeout * 1e9)
        self.frozen_timeout = frozen_timeout
        self.frozen_requires_motion = frozen_requires_motion
        self.latest = dict.fromkeys(names)
        self.arrival = dict.fromkeys(names, -math.inf)
        self.n_sensor = dict.fromkeys(names, 0)
        self.last_stamp = dict.fromkeys(names)
        self.changed = dict.fromkeys(names, -math.inf)  # last change of the value
        self.moved = dict.fromkeys(names, -math.inf)  # last change by more than the motion
        self.moved_from = dict.fromkeys(names)
        self.n_dropped = 0
        self.drop_offset = 0  # [ns] stamp minus node clock of the newest dropped sample
        self.clock_event = -math.inf

    def receive(self, name, stamp, value, now, clock_ns=None):
        """Take a sample; return ``(accepted, jump)``.

        ``clock_ns``: the node clock [ns] (real time; None in lock-step: no timing checks).
        ``accepted`` is False for a sample dropped for its stamp; ``jump`` is the stamp's jump
        [ns] against the previous one when it is a clock jump, else None.
        """
        self.n_sensor[name] += 1
        jump = None
        if clock_ns is not None:
            offset = stamp - clock_ns
            if offset < -self.timeout_ns or offset > self.timeout_ns:
                self.n_dropped += 1  # too old (or from the future) by the node clock
                self.drop_offset = offset
                return False, None
            last = self.last_stamp[name]
            if last is not None and (stamp < last or (stamp - last) - 1e9 * (
                    now - self.arrival[name]) > self.timeout_ns):
                jump = stamp - last
                self.clock_event = now
            self.last_stamp[name] = stamp
            if value != self.latest[name]:
                self.changed[name] = now
            ref = self.moved_from[name]
            if math.isfinite(value) and (ref is None or abs(value - ref) > self.motion[name]):
                if ref is not None:  # (the first value is no motion)
                    self.moved[name] = now
                self.moved_from[name] = value
        self.latest[name] = value
        self.arrival[name] = now
        return True, jump

    def stale(self, now):
        """Reason text if a sensor is older than ``sensor_timeout`` (or never came), else None."""
        stale = [t for t in self.latest
                 if self.latest[t] is None or now - self.arrival[t] > self.sensor_timeout]
        if not stale:
            return None
        reason = f'sensor data stale for more than {self.sensor_timeout:g} s ' \
            f'({", ".join(stale)})'
        if self.n_dropped and all(self.latest[t] is not None for t in stale):
            reason += f'; {self.n_dropped} samples dropped so far, newest stamped ' \
                f'{self.drop_offset * 1e-9:+.3f} s off the node clock'
        return reason

    def moving(self, now):
        """Return True if a fresh sensor of the set moved within ``frozen_timeout``."""
        return any(now - self.moved[t] <= self.frozen_timeout for t in self.latest
                   if now - self.arrival[t] <= self.sensor_timeout)

    def frozen(self, now, moving=None):
        """Reason text if a fresh sensor's value has not changed for ``frozen_timeout``.

        With ``frozen_requires_motion`` only while another sensor of the set moves, or, if
        given, while ``moving`` (other sensors of the car) is True.
        """
        fresh = [t for t in self.latest if now - self.arrival[t] <= self.sensor_timeout]
        frozen = [t for t in fresh if now - self.changed[t] > self.frozen_timeout]
        if not frozen:
            return None
        if moving is None:
            moving = any(now - self.moved[t] <= self.frozen_timeout
                         for t in fresh if t not in frozen)
        if self.frozen_requires_motion and not moving:
            return None  # no other sensor moves: a corner at rest (exact simulated values)
        return f'sensor value frozen for more than {self.frozen_timeout:g} s ' \
            f'({", ".join(frozen)})'

    def jump_reason(self, name, delta_ns):
        """Reason text of a clock jump of ``delta_ns`` on ``name``."""
        way = 'back' if delta_ns < 0 else 'forward'
        return f'{name} stamps jumped {way} by {abs(delta_ns) * 1e-9:.3f} s against their ' \
            'arrival (clock jump)'

    def jump_over(self, now):
        """Return True once ``sensor_timeout`` has passed since the last clock jump."""
        return now - self.clock_event > self.sensor_timeout

    def ages_ms(self, now):
        """Age of each sensor's newest value [ms] as text ('never' if none came)."""
        return {t: 'never' if self.latest[t] is None else f'{1e3 * (now - self.arrival[t]):.1f}'
                for t in self.latest}
