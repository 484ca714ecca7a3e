"""Replay node: publishes a recorded bag back onto the topics with its timing.

This is how measured runs re-enter the node set: a bag recorded on a car (or by the recorder)
is played into a namespace, e.g. the controller's sensor topics only (``topics: imu/body,
imu/wheel, stroke``). A recorded topic ``/<ns>/<name>`` whose ``<name>`` is a contract topic is
published on the relative ``<name>`` (so it lands in the replay node's namespace); other topics
keep their recorded name. Messages go out serialized as stored, at their recorded log times
scaled by ``speed``. ``/clock`` is published only with ``publish_clock``. A bag that cannot
be read (a recorder killed before closing it) is a one-line error naming
``mr-suspension bag repair``.
"""

import threading
import time

from rclpy.node import Node
from rosbags.rosbag2 import Reader, ReaderError

from mr_suspension.nodes import common, contract as c
from mr_suspension.nodes.recorder import message_class

NODE = 'replay'


def target_name(recorded):
    """Topic to publish a recorded topic on: the relative contract name when it matches."""
    if recorded == c.CLOCK:
        return c.CLOCK
    for name in sorted(c.TOPICS, key=len, reverse=True):
        if not name.startswith('/') and (recorded == '/' + name or
                                         recorded.endswith('/' + name)):
            return name
    return recorded


class ReplayNode(Node):
    """Publish a rosbag2 bag with its original timing."""

    def __init__(self, context=None, parameter_overrides=None, **kwargs):
        super().__init__(NODE, context=context, parameter_overrides=parameter_overrides,
                         **kwargs)
        d = common.node_defaults(NODE)
        bag = common.declare(self, d, 'bag', 'Bag directory to play (required)')
        self.speed = common.declare(self, d, 'speed', 'Playback speed factor', 0.01, 1000.0)
        topics = common.declare(self, d, 'topics', 'Comma-separated topics to play, as recorded '
                                'or as contract names ("" = all)')
        self.publish_clock = common.declare(self, d, 'publish_clock', 'Also publish /clock')
        self.start_delay = common.declare(self, d, 'start_delay', 'Wait before the first '
                                          'message [s]', 0.0, 60.0)
        self.exit_at_end = common.declare(self, d, 'exit_at_end', 'End the process after the '
                                          'last message')
        self.stats = common.Stats(common.declare(self, d, 'stats_file', 'Write run statistics '
                                                 'as JSON here on exit ("" = off)'))
        if not bag:
            raise ValueError('replay: parameter bag is required')
        self.reader = Reader(bag)
        try:
            self.reader.open()
        except ReaderError as exc:
            raise ValueError(f'replay: cannot read {bag}: {exc} (a bag whose recorder was '
                             f'killed is made readable by: mr-suspension bag repair {bag})') \
                from None
        wanted = {t.strip() for t in topics.split(',') if t.strip()}
        conns = []
        self.pubs = {}
        for conn in self.reader.connections:
            name = target_name(conn.topic)
            if wanted and conn.topic not in wanted and name not in wanted:
                continue
            if name == c.CLOCK and not self.publish_clock:
                continue
            qos = common.qos(name) if name in c.TOPICS else 1000
            self.pubs[conn.id] = self.create_publisher(message_class(conn.msgtype), name, qos)
            conns.append(conn)
        if not conns or self.reader.message_count == 0:
            self.reader.close()
            raise ValueError(f'replay: {bag} holds no messages on the selected topics')
        self.messages = self.reader.messages(connections=conns)
        self.pending = next(self.messages, None)
        self.bag_t0 = self.pending[1]
        self.finished = threading.Event()
        self.wall0 = None
        self.created = time.monotonic()
        self.count = 0
        self.timer = self.create_timer(0.001, self._on_tick)
        self.get_logger().info(f'replay: {bag}, {len(conns)} topics, x{self.speed:g}')

    def _on_tick(self):
        now = time.monotonic()
        if self.wall0 is None:
            if now - self.created < self.start_delay:
                return
            self.wall0 = now
        bag_now = self.bag_t0 + (now - self.wall0) * self.speed * 1e9
        while self.pending is not None and self.pending[1] <= bag_now:
            conn, _, raw = self.pending
            self.pubs[conn.id].publish(bytes(raw))
            self.count += 1
            self.pending = next(self.messages, None)
        if self.pending is None:
            self.timer.cancel()
            self.get_logger().info(f'replay: done, {self.count} messages')
            if self.exit_at_end:
                self.finished.set()

    @property
    def done(self):
        """True once every message was published."""
        return self.pending is None

    def close(self):
        """Close the bag and write the statistics file."""
        self.reader.close()
        self.stats.data.update(published=self.count)
        self.stats.write()


def main(args=None):
    """Console script ``replay``."""
    return common.run(ReplayNode, args)


if __name__ == '__main__':
    main()
