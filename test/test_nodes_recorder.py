"""Recorder bags read back with independent readers; replay publishes them with their timing."""

import time

from mcap.reader import make_reader
import pytest
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from sensor_msgs.msg import Imu

from mr_suspension.nodes import common, contract as c
from mr_suspension.nodes.actuator import ActuatorNode
from mr_suspension.nodes.controller import ControllerNode
from mr_suspension.nodes.launch import bag_summary, read_bag
from mr_suspension.nodes.plant import PlantNode
from mr_suspension.nodes.recorder import RecorderNode
from mr_suspension.nodes.replay import ReplayNode, target_name
from mr_suspension.nodes.testing import add, params, ros_context

NS = '/front_left'


def record_run(path, storage, duration=0.3):
    lock = {'lockstep': True}
    with ros_context() as (ctx, ex, nodes):
        rec = add(ex, nodes, RecorderNode(context=ctx, namespace=NS, parameter_overrides=params(
            output=str(path), storage=storage, lockstep=True)))
        plant = add(ex, nodes, PlantNode(context=ctx, namespace=NS, parameter_overrides=params(
            lockstep=True, duration=duration, start_delay=0.05, exit_at_end=False,
            expect_subscribers=2)))
        add(ex, nodes, ControllerNode(context=ctx, namespace=NS, parameter_overrides=params(
            **lock)))
        add(ex, nodes, ActuatorNode(context=ctx, namespace=NS, parameter_overrides=params(
            **lock)))
        assert common.spin_until(ex, lambda: plant.plant.done, 30.0)
        rec.drain(ex)
        rec.close()
        return dict(rec.counts), plant.plant.k + 1


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_recorder_bag_complete_and_readable(tmp_path, storage):
    bag = tmp_path / 'bag'
    counts, samples = record_run(bag, storage)
    assert (bag / 'metadata.yaml').is_file()
    expected = {(NS + '/' + t if t != c.CLOCK else t): samples for t in c.TOPICS}
    assert counts == expected
    with Reader(bag) as reader:
        assert reader.message_count == sum(expected.values())
        assert {x.topic: x.msgtype for x in reader.connections} == {
            (NS + '/' + t if t != c.CLOCK else t): c.TOPICS[t].type for t in c.TOPICS}
    if storage == 'mcap':
        files = list(bag.glob('*.mcap'))
        assert len(files) == 1
        with open(files[0], 'rb') as fh:
            reader = make_reader(fh)
            got = {}
            for _, channel, _ in reader.iter_messages():
                got[channel.topic] = got.get(channel.topic, 0) + 1
            schemas = {s.name for s in reader.get_summary().schemas.values()}
        assert got == expected
        assert 'sensor_msgs/msg/Imu' in schemas
    summary = bag_summary(bag, NS)
    assert summary['samples'] == samples
    assert summary['body_acc_rms'] > 0.0
    data = read_bag(bag)
    times, imu = data[NS + '/' + c.IMU_BODY]
    # Lock-step bags carry simulated time: log time = the sample's stamp.
    same = sum(t == common.stamp_to_ns(m.header.stamp) for t, m in zip(times, imu))
    assert same >= 0.99 * len(imu)
    assert imu[0].header.frame_id == c.FRAME_BODY_IMU
    assert imu[0].linear_acceleration.z == pytest.approx(9.81)
    # The unstamped loop topics: the n-th message at sample n's time, as reproducible.
    for topic in (c.CURRENT_COMMAND, c.COIL_CURRENT, c.TRUTH_TYRE_FORCE):
        times, _ = data[NS + '/' + topic]
        assert times == [k * 1_000_000 for k in range(samples)], topic


def test_replay_publishes_bag_with_timing(tmp_path):
    bag = tmp_path / 'bag'
    record_run(bag, 'mcap', duration=0.2)
    original = [m.linear_acceleration.z for m in read_bag(bag)[NS + '/' + c.IMU_BODY][1]]
    got = []
    with ros_context() as (ctx, ex, nodes):
        rep = add(ex, nodes, ReplayNode(context=ctx, namespace='/rear_right',
                                        parameter_overrides=params(
                                            bag=str(bag), speed=1.0, start_delay=0.3,
                                            topics='imu/body,stroke', exit_at_end=False)))
        sink = add(ex, nodes, common_sink(ctx, '/rear_right'))
        sink.create_subscription(Imu, c.IMU_BODY, lambda m: got.append(
            m.linear_acceleration.z), common.qos(c.IMU_BODY))
        assert common.spin_until(ex, lambda: rep.done, 10.0)
        common.spin_until(ex, lambda: len(got) >= len(original), 2.0)
        wall = rep.stats.data
        assert sorted(p.topic_name for p in rep.publishers if 'rear_right' in p.topic_name) == \
            ['/rear_right/imu/body', '/rear_right/stroke']
    assert got == original
    assert wall is not None


def common_sink(ctx, ns):
    from rclpy.node import Node
    return Node('sink', context=ctx, namespace=ns)


def test_target_names():
    assert target_name('/front_left/imu/body') == 'imu/body'
    assert target_name('/front_left/truth/tyre_force') == 'truth/tyre_force'
    assert target_name('/clock') == '/clock'
    assert target_name('/other/topic') == '/other/topic'


def test_empty_bag_gives_clear_error(tmp_path):
    bag = tmp_path / 'empty'
    writer = Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    writer.close()
    with pytest.raises(ValueError, match='no messages'):
        read_bag(bag)
    with ros_context() as (ctx, ex, nodes):
        with pytest.raises(ValueError, match='no messages'):
            ReplayNode(context=ctx, parameter_overrides=params(bag=str(bag)))


class _Handle:
    """Stands in for a subscription's middleware handle: hands out queued (raw, info) pairs."""

    def __init__(self, queue):
        self.queue = list(queue)

    def take_message(self, _msg_type, _raw):
        return self.queue.pop(0) if self.queue else None


class _Sub:
    def __init__(self, queue):
        self.handle = _Handle(queue)
        self.msg_type = Imu


def test_recorder_keeps_publication_order_of_repaired_samples(tmp_path):
    """A repaired sample (received after later ones, delivered before them) is not dropped."""
    from mr_suspension.nodes.cdr import Template
    tpl = Template(Imu(), ('linear_acceleration.z',))
    with ros_context() as (ctx, ex, nodes):
        rec = add(ex, nodes, RecorderNode(context=ctx, namespace=NS, parameter_overrides=params(
            output=str(tmp_path / 'bag'), lockstep=True, topics='imu/body')))
        _, conn, full, timed, last = rec.sources[0]
        # Samples 0..5 taken in order; sample 2 was repaired, so it was received last.
        received = [10, 11, 50, 12, 13, 14]
        queue = [(bytes(tpl.pack(k * 1_000_000, float(k))), {'received_timestamp': t})
                 for k, t in enumerate(received)]
        rec.sources = [(_Sub(queue), conn, full, timed, last)]
        assert rec._poll() == 6
        rec.close()
        assert rec.repeated == 0
    times, msgs = read_bag(tmp_path / 'bag')[NS + '/' + c.IMU_BODY]
    assert [m.linear_acceleration.z for m in msgs] == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
    assert times == [k * 1_000_000 for k in range(6)]


class _Endless:
    """A handle whose queue never runs dry (a publisher that keeps going while the bag closes)."""

    def __init__(self, raw):
        self.raw = raw
        self.k = 0

    def take_message(self, _msg_type, _raw):
        self.k += 1
        return self.raw, {'received_timestamp': self.k}


def test_recorder_close_is_bounded_while_messages_keep_coming(tmp_path):
    from mr_suspension.nodes.cdr import Template
    raw = bytes(Template(Imu(), ('linear_acceleration.z',)).pack(0, 1.0))
    with ros_context() as (ctx, ex, nodes):
        rec = add(ex, nodes, RecorderNode(context=ctx, namespace=NS, parameter_overrides=params(
            output=str(tmp_path / 'bag'), topics='imu/body')))
        sub = _Sub([])
        sub.handle = _Endless(raw)
        _, conn, full, timed, last = rec.sources[0]
        rec.sources = [(sub, conn, full, timed, last)]
        t0 = time.monotonic()
        rec.close()
        assert time.monotonic() - t0 < 10.0
        assert rec.closed and rec.counts[full] > 0
    assert (tmp_path / 'bag' / 'metadata.yaml').is_file()


def _record_imu_and_commands(path, stamps, imu_received, cmd_received):
    """Return the commands' (log times, messages) of a lock-step recorder fed in one poll.

    Imu samples carry ``stamps``; one Float64 command per entry of ``cmd_received`` (its
    reception time).
    """
    from std_msgs.msg import Float64

    from mr_suspension.nodes.cdr import Template
    imu = Template(Imu(), ('linear_acceleration.z',))
    f64 = Template(Float64(), ('data',), stamped=False)
    with ros_context() as (ctx, ex, nodes):
        rec = add(ex, nodes, RecorderNode(context=ctx, namespace=NS, parameter_overrides=params(
            output=str(path), lockstep=True, topics='imu/body,current_command')))
        imus = [(bytes(imu.pack(s, 9.81)), {'received_timestamp': t})
                for s, t in zip(stamps, imu_received)]
        cmds = [(bytes(f64.pack(0, float(k))), {'received_timestamp': t})
                for k, t in enumerate(cmd_received)]
        queues = (imus, cmds)
        rec.sources = [(_Sub(q),) + src[1:] for q, src in zip(queues, rec.sources)]
        assert rec._poll() == len(imus) + len(cmds)
        rec.close()
    return read_bag(path)[NS + '/' + c.CURRENT_COMMAND]


def test_recorder_logs_unstamped_lockstep_messages_at_their_sample(tmp_path):
    """In lock-step the n-th command is logged at n dt, however late it was received."""
    dt = 2_000_000
    # Sample k's command is received after the sensors of sample k + 1 (or k + 2).
    times, msgs = _record_imu_and_commands(
        tmp_path / 'bag', [k * dt for k in range(6)], [100 * k for k in range(6)],
        [100 * (k + 1) + 50 + (100 if k == 3 else 0) for k in range(5)])
    assert [m.data for m in msgs] == [0.0, 1.0, 2.0, 3.0, 4.0]
    assert times == [k * dt for k in range(5)]


def test_recorder_lockstep_with_wall_clock_stamps_keeps_newest_stamp(tmp_path):
    """Stamps off any step grid (a real-time plant): unstamped messages keep the newest stamp."""
    wall = [1_795_000_000_123_456_789 + 1_000_123 * k + 7 * k * k for k in range(4)]
    times, _ = _record_imu_and_commands(tmp_path / 'bag', wall, [100 * k for k in range(4)],
                                        [100 * k + 50 for k in range(4)])
    assert times == wall
