"""Recorder node: writes the contract topics to a rosbag2 bag (MCAP by default, or sqlite3).

Writes with :class:`mr_suspension.bagtools.BagWriter` (the ``mcap`` package or sqlite3; no
rosbag2 install needed); the bag is a standard rosbag2 directory (``metadata.yaml`` plus the
storage file) that ``ros2 bag``, ``rosbags`` and ``mcap`` read. It survives a crash: every
``flush_period`` (of wall or log time) the MCAP chunk in progress is closed and the file flushed
and fsynced (sqlite3: a commit), and ``metadata.yaml`` is rewritten atomically every
``metadata_period``, so a killed recorder loses at most the last ``flush_period`` of data;
``mr-suspension bag repair`` makes such a bag readable again.
Messages are taken serialized (raw CDR) and written as they are, time-stamped at reception like
``ros2 bag record``: with the middleware's reception time (system clock) in real time; with
simulated time in lock-step (``lockstep: true``, as ``ros2 bag record --use-sim-time``): the
header stamp of stamped messages and ``/clock``; a stamped message whose stamp is not newer than
the last one on its topic (a sample re-sent after a lock-step stall) is recorded once. The
lock-step loop's unstamped topics (``current_command``, ``coil_current``,
``truth/tyre_force``) carry one message per sample, in order, so the ``n``-th one is logged at
sample ``n``'s time ``n dt``, the same in every run (``dt``: the least positive stamp, once the
stamps are seen to start at 0 and to be its multiples); until then, or if they are not, at the
newest simulated time seen.

The recorder needs no low latency. Run as a process of its own in real time it lowers its CPU
priority (``niceness``, default 10), so on a small machine the control loop's wake-ups go first
(not in lock-step, where the loop runs as fast as the CPU allows and would starve it). It does
not wake for every message either: its subscriptions sit on an internal node (``<name>_taps``,
not spun by any executor) whose middleware queues (depth 1000, one second at 1 kHz; 10x that
in lock-step, which runs faster than real time) fill between polls; every ``poll_period``
the node takes all queued messages and writes them in order of reception. At 1 kHz on seven
topics that is about 200 wake-ups a second instead of 7000, which leaves the CPU to the
control loop. On SIGINT/SIGTERM it stops recording: it takes
every queued message received up to ``drain_grace`` (0.2 s) after the stop, none received later,
for at most ``drain_max`` (0.5 s), then closes the bag (summary and metadata written), so no
message received before the signal is lost and publishers that keep going cannot hold it open.
"""

from datetime import datetime
import importlib
import math
import os
from pathlib import Path
import threading
import time

from rclpy.node import Node

from mr_suspension.bagtools import BagWriter, SUFFIX
from mr_suspension.nodes import cdr, common, contract as c

NODE = 'recorder'
# Lock-step stamps are k dt; a step below 1 us means wall-clock stamps (a plant in real time).
MIN_STEP_NS = 1000
LOCKSTEP_QUEUE_FACTOR = 10  # queue depth in lock-step, times the contract's
STORAGES = tuple(SUFFIX)


def message_class(msgtype):
    """Python class of a ROS message type such as ``sensor_msgs/msg/Imu``."""
    pkg, _, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{pkg}.msg'), name)


class RecorderNode(Node):
    """Record the contract topics of this namespace into a rosbag2 bag."""

    def __init__(self, context=None, parameter_overrides=None, **kwargs):
        super().__init__(NODE, context=context, parameter_overrides=parameter_overrides,
                         **kwargs)
        d = common.node_defaults(NODE)
        output = common.declare(self, d, 'output', 'Bag directory to create ("" = '
                                'rosbag2_<date-time> in the working directory)')
        storage = common.declare(self, d, 'storage', 'Storage plugin: mcap or sqlite3')
        topics = common.declare(self, d, 'topics', 'Comma-separated contract topics to record '
                                '("" = all)')
        namespaces = common.declare(
            self, d, 'namespaces', 'Comma-separated corner namespaces relative to the '
            'recorder namespace (full car: front_left,front_right,rear_left,rear_right): record '
            'the corner topics under each, plus the car topics (body/imu) and /clock once ("" = '
            'one corner: the recorder namespace)')
        self.lockstep = common.declare(self, d, 'lockstep', 'Subscribe transient-local, as the '
                                       'lock-step nodes publish (no message lost to discovery)')
        self.drain_grace = common.declare(self, d, 'drain_grace', 'On shutdown, still record '
                                          'messages received up to this long after it [s]',
                                          0.0, 10.0)
        self.drain_max = common.declare(self, d, 'drain_max', 'On shutdown, close the bag '
                                        'after at most this long [s]', 0.0, 10.0)
        flush_period = common.declare(self, d, 'flush_period', 'Make the bag durable this '
                                      'often, in wall or log time [s] (at most this much data '
                                      'is lost if the process is killed)', 0.01, 10.0)
        metadata_period = common.declare(self, d, 'metadata_period', 'Rewrite metadata.yaml '
                                         'this often [s]', 0.1, 3600.0)
        fsync = common.declare(self, d, 'fsync', 'fsync the bag at every flush (survives a '
                               'power loss too, not only a killed process)')
        poll_period = common.declare(self, d, 'poll_period', 'Take the queued messages this '
                                     'often [s] (queues hold 1 s at 1 kHz)', 0.0005, 0.5)
        niceness = common.declare(self, d, 'niceness', 'Run at this nice value in real time '
                                  '(0 = as started; higher yields the CPU to the control '
                                  'loop; lock-step always runs as started)', 0, 19)
        self.stats = common.Stats(common.declare(self, d, 'stats_file', 'Write run statistics '
                                                 'as JSON here on exit ("" = off)'))
        if storage not in STORAGES:
            raise ValueError(f'recorder: storage must be one of {list(STORAGES)}, '
                             f'got {storage!r}')
        corners = [n.strip().strip('/') for n in namespaces.split(',') if n.strip().strip('/')]
        known = dict(c.TOPICS, **c.CAR_TOPICS)
        names = [t.strip() for t in topics.split(',') if t.strip()] \
            or list(c.TOPICS) + (list(c.CAR_TOPICS) if corners else [])
        unknown = sorted(set(names) - set(known))
        if unknown:
            raise ValueError(f'recorder: unknown topics {unknown}; contract: {sorted(known)}')
        if len(set(corners)) != len(corners):
            raise ValueError(f'recorder: namespaces repeat a name: {namespaces!r}')
        # (relative name to subscribe, contract name)
        streams = [(f'{ns}/{name}', name) for name in names for ns in corners
                   if name in c.TOPICS and name not in c.ABSOLUTE]
        streams += [(name, name) for name in names
                    if not corners or name in c.ABSOLUTE or name not in c.TOPICS]
        if not output:
            output = datetime.now().strftime('rosbag2_%Y_%m_%d-%H_%M_%S')
        self.path = Path(output)
        if self.path.exists():
            raise FileExistsError(f'recorder: {self.path} exists; choose a new output')
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.finished = threading.Event()
        self.lock = threading.Lock()
        self.writer = BagWriter(self.path, storage, flush_period, metadata_period, fsync)
        self.closed = False
        store = cdr.typestore()
        self.counts = {}
        self.repeated = 0
        self.sim_ns = None
        # Lock-step stamps are k dt from k = 0: sample 0 seen, gcd and least positive stamp.
        self.grid = [False, 0, 0]
        self.cutoff = None  # set on shutdown: messages received later are not recorded
        self.stopped = set()  # sources taken up to the cutoff
        self.after_stop = 0
        # Subscriptions on a node no executor spins: messages wait in the middleware's queues
        # until _poll takes them (no wake-up per message).
        self.taps = Node(f'{self.get_name()}_taps', context=context,
                         namespace=self.get_namespace(), start_parameter_services=False,
                         enable_rosout=False)
        self.sources = []
        for rel, name in streams:
            t = known[name]
            full = self.resolve_topic_name(rel)
            msgdef, _ = store.generate_msgdef(t.type, ros_version=2)
            conn = self.writer.add_connection(full, t.type, msgdef, store.hash_rihs01(t.type))
            self.counts[full] = 0
            qos = common.qos(name, self.lockstep)
            if self.lockstep:
                # The lock-step loop runs at up to 4x real time: the contract's 1 s of queue is
                # 0.25 s there, and a recorder held up longer lost the rest (a 2.6 s gap).
                qos.depth = LOCKSTEP_QUEUE_FACTOR * qos.depth
            sub = self.taps.create_subscription(message_class(t.type), rel, _never, qos,
                                                raw=True)
            # Lock-step: Clock and stamped messages carry the simulated time at one offset.
            timed = self.lockstep and (full == c.CLOCK or t.type in (c.IMU, c.JOINT_STATE))
            self.sources.append((sub, conn, full, timed, [-1]))
        self.poll_timer = self.create_timer(poll_period, self._poll)
        # Applied by common.run (a process of its own) only. Not in lock-step: that loop runs
        # as fast as the CPU allows and has no wake-up latency to protect, so a niced recorder
        # starved there and its 1 s queues overflowed (26 % of a 12 s run lost, gaps of 1.7 s).
        self.niceness = 0 if self.lockstep else niceness
        self.get_logger().info(f'recorder: writing {len(streams)} topics to {self.path} '
                               f'({storage})')

    def _poll(self):
        """Take every queued message and write them in order of reception.

        A topic's messages keep the order they are taken in (the publication order): a sample
        the middleware repaired arrives later than the ones after it but is delivered before
        them, so its key is the latest reception time of the topic so far.
        """
        batch = []
        past = self.cutoff is not None and time.time_ns() > self.cutoff
        for i, source in enumerate(self.sources):
            if i in self.stopped:
                continue
            sub = source[0]
            key = 0
            for _ in range(c.DEPTH):  # at most a full queue, so a poll always ends
                got = sub.handle.take_message(sub.msg_type, True)
                if got is None:
                    if past:  # anything still to come was received after the cutoff
                        self.stopped.add(i)
                    break
                received = got[1]['received_timestamp']
                if self.cutoff is not None and received > self.cutoff:
                    self.after_stop += 1
                    self.stopped.add(i)
                    break
                key = max(key, received)
                batch.append((key, len(batch), got[0], source))
        batch.sort()
        with self.lock:
            if self.closed:
                return 0
            for received, _, raw, (_, conn, full, timed, last) in batch:
                self._write(received, raw, conn, full, timed, last)
            if batch and not self.stats.marked:
                self.stats.mark()
            self.writer.maybe_flush()  # chunk closed, file flushed: a crash loses no more
        return len(batch)

    def _write(self, received, raw, conn, full, timed, last):
        stamp = cdr.stamp(raw) if timed else None
        if stamp is not None:
            if stamp <= last[0]:
                self.repeated += 1  # re-sent after a lock-step stall: recorded once
                return
            last[0] = stamp
            if self.sim_ns is None or stamp > self.sim_ns:
                self.sim_ns = stamp
            if self.lockstep:
                self._on_grid(stamp)
        elif self.lockstep and (step := self._step(self.counts[full])) is not None:
            stamp = self.counts[full] * step  # the n-th message: sample n's time
        elif self.lockstep and self.sim_ns is not None:
            stamp = self.sim_ns
        else:
            stamp = received
        self.writer.write(conn, stamp, raw)
        self.counts[full] += 1

    def _on_grid(self, stamp):
        grid = self.grid
        if stamp == 0:
            grid[0] = True
        else:
            grid[1] = math.gcd(grid[1], stamp)
            grid[2] = stamp if not grid[2] else min(grid[2], stamp)

    def _step(self, n):
        """Return the lock-step step [ns] for message ``n`` if the stamps fix it, else None.

        The stamps must start at 0 and their least positive one (sample 1) must divide all the
        others; wall-clock stamps (a plant in real time) never do.
        """
        zero, gcd, least = self.grid
        if zero and n == 0:
            return 0
        if zero and gcd >= MIN_STEP_NS and gcd == least:
            return gcd
        return None

    def drain(self, executor):
        """Stop recording: take what was received up to ``drain_grace`` from now, then return.

        Returns once every topic is taken up to that cutoff (a later message, or an empty queue
        after it), at most ``drain_max`` seconds from now.
        """
        self.cutoff = time.time_ns() + int(self.drain_grace * 1e9)  # reception times: system
        end = time.monotonic() + self.drain_max
        common.spin_until(executor, lambda: len(self.stopped) == len(self.sources)
                          or time.monotonic() > end, self.drain_max + 0.1, step=0.01)

    def close(self):
        """Take what is still queued, close the bag (summary, metadata) and the statistics file.

        One last round of the queues (bounded: publishers that keep going cannot hold the bag
        open), then the file is finished.
        """
        if not self.closed:
            self._poll()
        with self.lock:
            if self.closed:
                return
            self.closed = True
            self.writer.close()
        self.get_logger().info(f'recorder: closed {self.path} with '
                               f'{sum(self.counts.values())} messages')
        self.stats.data.update(path=str(self.path), counts=self.counts,
                               repeated_dropped=self.repeated, flushes=self.writer.flushes,
                               after_stop=self.after_stop,
                               flush_max_s=self.writer.flush_max_s,
                               niceness=os.getpriority(os.PRIO_PROCESS, 0))
        self.stats.write()

    def destroy_node(self):
        """Close the bag before the node goes away."""
        self.close()
        self.taps.destroy_node()
        return super().destroy_node()


def _never(_msg):
    """Ignore a message (the taps' callback; no executor spins them, so it is never called)."""


def main(args=None):
    """Console script ``recorder``."""
    return common.run(RecorderNode, args)


if __name__ == '__main__':
    main()
