"""Benchmark of the recorder's crash safety: data lost to SIGKILL and to SIGINT, time to close.

A publisher process sends a counter (0, 1, 2, ...) on eight contract topics at 1 kHz (the node
set's load: two ``Imu``, three ``JointState``, three ``Float64``; reliable, starting once the
recorder is matched) and logs the wall time of every publication. The recorder runs as its own
process with the defaults of ``config/nodes/recorder.yaml`` (MCAP, flush every 0.25 s, fsync).

* SIGKILL after ``--run`` seconds (plus a random phase within one flush period): the bag is
  repaired (``mr-suspension bag repair``) and read back with rosbags; lost = counts published
  before the kill that are not in the bag, in seconds of data (worst topic). Target <= 1 s.
* SIGINT after ``--run`` seconds: time until the MCAP summary is written (bag closed) and until
  the process exits; lost = counts published before the signal missing from the bag, read
  without repair. Targets: 0 lost, closed within 1 s.

Usage: ``python benchmarks/bench_recorder.py [--repeats 3] [--run 3] [--storage mcap]``.
"""

import argparse
import json
from pathlib import Path
import random
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time

from rosbags.rosbag2 import Reader
from rosbags.typesys import get_typestore, Stores

from mr_suspension import bagtools
from mr_suspension.nodes import contract as c
from mr_suspension.nodes.launch import _env

NS = '/bench'
RATE = 1000.0
TOPICS = (c.IMU_BODY, c.IMU_WHEEL, c.STROKE, c.DAMPER_FORCE, c.TRUTH_STATE, c.CURRENT_COMMAND,
          c.COIL_CURRENT, c.TRUTH_TYRE_FORCE)
PUBLISHER = r"""
import json, sys, time
import rclpy
from rclpy.node import Node
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Float64
from mr_suspension.nodes import common, contract as c
topics, rate, duration, log = sys.argv[1].split(','), float(sys.argv[2]), float(sys.argv[3]), \
    sys.argv[4]
common.ensure_environment()
ctx = rclpy.Context()
rclpy.init(context=ctx)
node = Node('counter', context=ctx, namespace=sys.argv[5])
kinds = {c.IMU: Imu, c.JOINT_STATE: JointState, c.FLOAT64: Float64}
pubs = [(node.create_publisher(kinds[c.TOPICS[t].type], t, common.qos(t)),
         kinds[c.TOPICS[t].type]()) for t in topics]
for _, msg in pubs:
    if isinstance(msg, JointState):
        msg.name = ['a', 'b', 'c', 'd']
end = time.monotonic() + 60.0
while any(p.get_subscription_count() < 1 for p, _ in pubs) and time.monotonic() < end:
    time.sleep(0.01)
time.sleep(0.2)
print('matched', flush=True)
times, t0, k = [], time.monotonic(), 0
while k < rate * duration:
    due = t0 + k / rate
    while time.monotonic() < due:
        time.sleep(max(0.0, min(due - time.monotonic(), 0.0005)))
    now = time.time_ns()
    for p, msg in pubs:
        if isinstance(msg, Float64):
            msg.data = float(k)
        else:
            common.set_stamp(msg.header, now)
            if isinstance(msg, Imu):
                msg.linear_acceleration.z = float(k)
            else:
                msg.position = [float(k), 0.0, 0.0, 0.0]
        p.publish(msg)
    times.append(time.time())
    k += 1
with open(log, 'w') as fh:
    json.dump(times, fh)
node.destroy_node()
rclpy.try_shutdown(context=ctx)
"""


def counter(msg):
    """Return the counter a publisher message carries."""
    if hasattr(msg, 'data'):
        return msg.data
    if hasattr(msg, 'linear_acceleration'):
        return msg.linear_acceleration.z
    return msg.position[0]


def one_run(work, storage, run, how):
    """One recorder run stopped by ``how`` (SIGKILL or SIGINT); return its figures."""
    work.mkdir(parents=True)
    env = _env(random.randint(101, 230))
    bag = work / 'bag'
    rec = subprocess.Popen(
        [sys.executable, '-m', 'mr_suspension.nodes.recorder', '--ros-args', '-r',
         f'__ns:={NS}', '-p', f'output:={bag}', '-p', f'storage:={storage}', '-p',
         'topics:=' + ','.join(TOPICS), '-p', f'stats_file:={work / "stats.json"}'],
        env=env, stdout=open(work / 'rec.log', 'w'), stderr=subprocess.STDOUT)
    pub = subprocess.Popen([sys.executable, '-c', PUBLISHER, ','.join(TOPICS), str(RATE),
                            str(run + 2.0), str(work / 'times.json'), NS], env=env,
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    out = {}
    try:
        line = pub.stdout.readline()
        if line.strip() != 'matched':
            raise RuntimeError(f'publisher: {line}{pub.stdout.read()}')
        time.sleep(run + random.uniform(0.0, 0.25))
        when = time.time()
        t0 = time.monotonic()
        rec.send_signal(how)
        if how == signal.SIGINT:
            closed = None
            while rec.poll() is None and time.monotonic() - t0 < 20.0:
                if closed is None and bagtools.mcap_summary(bag / 'bag.mcap') is not None:
                    closed = time.monotonic() - t0
                time.sleep(0.005)
            out['exit_s'] = time.monotonic() - t0
            out['close_s'] = closed if closed is not None else out['exit_s']
            out['returncode'] = rec.returncode
        rec.wait(20.0)
        pub.wait(30.0)
    finally:
        for p in (rec, pub):
            if p.poll() is None:
                p.kill()
                p.wait(10.0)
    times = json.loads((work / 'times.json').read_text())
    before = sum(t < when for t in times)
    if how == signal.SIGKILL:
        t0 = time.monotonic()
        bagtools.repair(bag, log=lambda _: None)
        out['repair_s'] = time.monotonic() - t0
    store = get_typestore(Stores.LATEST)
    got = {}
    with Reader(bag) as reader:
        for conn, _, raw in reader.messages():
            got.setdefault(conn.topic, []).append(counter(store.deserialize_cdr(raw,
                                                                                conn.msgtype)))
    contiguous = all(v == [float(k) for k in range(len(v))] for v in got.values())
    missing = max(max(before - len(got.get(f'{NS}/{t}', [])), 0) for t in TOPICS)
    out.update(published_before=before, missing=missing, lost_s=missing / RATE,
               contiguous=contiguous, recorded=sum(len(v) for v in got.values()))
    return out


def describe(values, fmt='.3f'):
    """Median [min, max] of a list."""
    return (f'{statistics.median(values):{fmt}} [{min(values):{fmt}}, {max(values):{fmt}}]'
            if values else 'n/a')


def main(argv=None):
    """Run the SIGKILL and SIGINT rounds and print the figures."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--repeats', type=int, default=3, help='runs of each kind')
    ap.add_argument('--run', type=float, default=3.0, help='publishing before the signal [s]')
    ap.add_argument('--storage', default='mcap', choices=sorted(bagtools.SUFFIX))
    ap.add_argument('--out', default='', help='keep bags and logs here (default: temporary)')
    args = ap.parse_args(argv)
    root = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix='bench_recorder_'))
    kills, ints = [], []
    try:
        for k in range(args.repeats):
            kills.append(one_run(root / f'kill{k}', args.storage, args.run, signal.SIGKILL))
            ints.append(one_run(root / f'int{k}', args.storage, args.run, signal.SIGINT))
    finally:
        if not args.out:
            shutil.rmtree(root, ignore_errors=True)
    print(f'recorder crash safety: {args.storage}, {len(TOPICS)} topics at {RATE:.0f} Hz, '
          f'{args.repeats} runs of each, signal after {args.run:g} s (+ random phase)')
    print('| stop | figure | median [min, max] | target |')
    print('|---|---|---|---|')
    print(f'| SIGKILL | data lost [s] | {describe([r["lost_s"] for r in kills])} | <= 1 |')
    print(f'| SIGKILL | repair time [s] | {describe([r["repair_s"] for r in kills])} | |')
    print(f'| SIGINT | messages lost (published before the signal) | '
          f'{describe([r["missing"] for r in ints], "d")} | 0 |')
    print(f'| SIGINT | bag closed after [s] | {describe([r["close_s"] for r in ints])} | <= 1 |')
    print(f'| SIGINT | process exited after [s] | {describe([r["exit_s"] for r in ints])} | |')
    ok = all(r['contiguous'] for r in kills + ints)
    print(f'recorded counters in order and contiguous from 0 in every run: {ok}; '
          f'SIGINT exit codes: {sorted({r["returncode"] for r in ints})}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
