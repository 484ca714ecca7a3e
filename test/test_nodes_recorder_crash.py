"""The recorder as a real process: SIGKILL loses at most the last second, SIGINT loses nothing.

A publisher process sends a counter (0, 1, 2, ... on three contract topics at 1 kHz, reliable,
starting once the recorder is matched) and logs the wall time of every publication, so what the
bag must hold is known without the recorder: every count published before the signal.
"""

import json
import os
import random
import signal
import subprocess
import sys
import time

from mcap.reader import make_reader
import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import get_typestore, Stores
from std_msgs.msg import Float64

from mr_suspension import bagtools
from mr_suspension.nodes import common, contract as c
from mr_suspension.nodes.launch import _env
from mr_suspension.nodes.replay import ReplayNode
from mr_suspension.nodes.testing import add, params, ros_context

NS = '/crash'
TOPICS = (c.TRUTH_TYRE_FORCE, c.CURRENT_COMMAND, c.COIL_CURRENT)
RATE = 1000.0
PUBLISHER = r"""
import json, sys, time
import rclpy
from rclpy.node import Node
from std_msgs.msg import Float64
from mr_suspension.nodes import common
topics, rate, duration, log = sys.argv[1].split(','), float(sys.argv[2]), float(sys.argv[3]), \
    sys.argv[4]
common.ensure_environment()
ctx = rclpy.Context()
rclpy.init(context=ctx)
node = Node('counter', context=ctx, namespace='/crash')
pubs = [node.create_publisher(Float64, t, common.qos(t)) for t in topics]
end = time.monotonic() + 60.0
while any(p.get_subscription_count() < 1 for p in pubs) and time.monotonic() < end:
    time.sleep(0.01)
time.sleep(0.2)  # the recorder's matching of the publishers, too
print('matched', flush=True)
times, msg, t0, k = [], Float64(), time.monotonic(), 0
while k < rate * duration:
    due = t0 + k / rate
    while time.monotonic() < due:
        time.sleep(max(0.0, min(due - time.monotonic(), 0.0005)))
    msg.data = float(k)
    for p in pubs:
        p.publish(msg)
    times.append(time.time())
    k += 1
with open(log, 'w') as fh:
    json.dump(times, fh)
node.destroy_node()
rclpy.try_shutdown(context=ctx)
"""


def start(tmp_path, storage, duration):
    """Start recorder and publisher; return them once the publisher's counting started."""
    env = _env(random.Random(os.getpid() ^ time.time_ns()).randint(101, 230))
    bag = tmp_path / 'bag'
    rec = subprocess.Popen(
        [sys.executable, '-m', 'mr_suspension.nodes.recorder', '--ros-args', '-r',
         f'__ns:={NS}', '-p', f'output:={bag}', '-p', f'storage:={storage}', '-p',
         'topics:=' + ','.join(TOPICS)], env=env, stdout=open(tmp_path / 'rec.log', 'w'),
        stderr=subprocess.STDOUT)
    pub = subprocess.Popen([sys.executable, '-c', PUBLISHER, ','.join(TOPICS), str(RATE),
                            str(duration), str(tmp_path / 'times.json')], env=env,
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    line = pub.stdout.readline()  # blocks until matched (the publisher gives up after 60 s)
    assert line.strip() == 'matched', line + pub.stdout.read()
    return bag, rec, pub


def published_before(tmp_path, pub, when):
    """Return the counts published before wall time ``when``, and all (waits for the end)."""
    pub.wait(30.0)
    times = json.loads((tmp_path / 'times.json').read_text())
    return sum(t < when for t in times), len(times)


def recorded(bag):
    """``{topic: [counter values]}`` in log-time order, read with rosbags."""
    store = get_typestore(Stores.LATEST)
    out = {}
    with Reader(bag) as reader:
        for conn, _, raw in reader.messages():
            out.setdefault(conn.topic, []).append(store.deserialize_cdr(raw, conn.msgtype).data)
    return out


def stop(*procs):
    for p in procs:
        if p.poll() is None:
            p.kill()
            p.wait(10.0)


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_sigkill_loses_at_most_one_second(tmp_path, storage):
    bag, rec, pub = start(tmp_path, storage, duration=3.0)
    try:
        time.sleep(2.0)
        killed = time.time()
        rec.send_signal(signal.SIGKILL)
        rec.wait(10.0)
        n_before, n_total = published_before(tmp_path, pub, killed)
    finally:
        stop(rec, pub)
    assert n_total == 3000 and n_before > 1500
    if storage == 'mcap':
        with pytest.raises(Exception):
            Reader(bag).open()  # killed: no summary, unreadable until repaired
    res = bagtools.repair(bag, log=lambda _: None)
    got = recorded(bag)
    assert sorted(got) == sorted(f'{NS}/{t}' for t in TOPICS)
    for topic, values in got.items():
        n = len(values)
        assert values == [float(k) for k in range(n)], topic  # in order, contiguous, from 0
        lost_s = (n_before - n) / RATE
        print(f'{storage} {topic}: {n} of {n_before} published before the kill, lost '
              f'{lost_s:.3f} s')
        assert lost_s <= 1.0, (topic, n, n_before)
    assert res['messages'] == sum(len(v) for v in got.values())
    if storage == 'mcap':
        replayed(bag, got[f'{NS}/{c.CURRENT_COMMAND}'])


def replayed(bag, expected):
    """Check that the replay node publishes the repaired bag: every value, in order."""
    got = []
    with ros_context() as (ctx, ex, nodes):
        rep = add(ex, nodes, ReplayNode(
            context=ctx, namespace='/again', parameter_overrides=params(
                bag=str(bag), speed=20.0, start_delay=0.3, topics=c.CURRENT_COMMAND,
                exit_at_end=False)))
        from rclpy.node import Node
        sink = add(ex, nodes, Node('sink', context=ctx, namespace='/again'))
        sink.create_subscription(Float64, c.CURRENT_COMMAND, lambda m: got.append(m.data),
                                 common.qos(c.CURRENT_COMMAND))
        assert common.spin_until(ex, lambda: rep.done, 20.0)
        common.spin_until(ex, lambda: len(got) >= len(expected), 2.0)
    assert got == expected


def test_sigint_closes_within_one_second_and_loses_nothing(tmp_path):
    bag, rec, pub = start(tmp_path, 'mcap', duration=3.5)
    try:
        time.sleep(2.0)
        signalled = time.time()
        t0 = time.monotonic()
        rec.send_signal(signal.SIGINT)
        closed = None
        file = bag / 'bag.mcap'
        while rec.poll() is None and time.monotonic() - t0 < 10.0:
            if closed is None and bagtools.mcap_summary(file) is not None:
                closed = time.monotonic() - t0  # the summary is written: the file is finished
            time.sleep(0.01)
        exited = time.monotonic() - t0
        if closed is None and bagtools.mcap_summary(file) is not None:
            closed = exited
        n_before, _ = published_before(tmp_path, pub, signalled)
    finally:
        stop(rec, pub)
    print(f'SIGINT: bag closed after {closed:.3f} s, process exited after {exited:.3f} s')
    assert rec.returncode == 0
    assert closed is not None and closed <= 1.0
    with open(file, 'rb') as fh:
        assert make_reader(fh).get_summary().statistics.message_count > 0
    got = recorded(bag)  # no repair
    meta = bagtools.read_metadata(bag / 'metadata.yaml')
    assert meta['message_count'] == sum(len(v) for v in got.values())
    for topic, values in got.items():
        assert values == [float(k) for k in range(len(values))], topic
        assert len(values) >= n_before, (topic, len(values), n_before)  # nothing lost


def test_replay_of_unrepaired_bag_names_repair(tmp_path):
    """A crash image (flushed, never closed) is a one-line error that points at bag repair."""
    from rosbags.typesys import get_typestore, Stores
    store = get_typestore(Stores.LATEST)
    src = tmp_path / 'src'
    writer = bagtools.BagWriter(src, 'mcap')
    msgdef, _ = store.generate_msgdef(c.FLOAT64, ros_version=2)
    cid = writer.add_connection(f'{NS}/{c.CURRENT_COMMAND}', c.FLOAT64, msgdef,
                                store.hash_rihs01(c.FLOAT64))
    for k in range(100):
        writer.write(cid, 10**9 + k * 10**6, store.serialize_cdr(
            store.types[c.FLOAT64](data=float(k)), c.FLOAT64))
    writer.flush()
    bag = tmp_path / 'crashed'
    bag.mkdir()
    (bag / 'crashed.mcap').write_bytes((src / 'src.mcap').read_bytes())
    (bag / 'metadata.yaml').write_text((src / 'metadata.yaml').read_text().replace(
        'src.mcap', 'crashed.mcap'))
    writer.close()
    with ros_context() as (ctx, ex, nodes):
        with pytest.raises(ValueError, match='mr-suspension bag repair') as err:
            ReplayNode(context=ctx, parameter_overrides=params(bag=str(bag)))
    assert '\n' not in str(err.value)
    bagtools.repair(bag, log=lambda _: None)
    replayed(bag, [float(k) for k in range(100)])
