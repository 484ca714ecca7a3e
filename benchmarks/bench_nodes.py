"""Benchmark of the ROS 2 node set as separate processes (plant, controller, actuator, recorder).

Real time at the default 1 kHz for ``--duration`` seconds (default 30) on an ISO 8608 class C
road: achieved step rate, plant timer jitter (|period - 1 ms|) p50/p99, sensor-to-force loop
latency p50/p99 (plant publishes sample k -> plant receives the damper force for sample k, via
the actuator), late forces, messages lost on every link, CPU per node (fraction of one core
over the run). Then lock-step (simulated time) for ``--lockstep-duration`` seconds: steps per
second across processes with the default one-sample coupling (``coupling_delay`` 1; plant and
actuator work concurrently) and no recorder, ``--repeats`` times (median and range), each run
right after the bare ring below; then once with the recorder, and once in exact mode
(``coupling_delay`` 0, the offline simulator's step order) without it.

Three references, because this is a shared machine whose speed changes from minute to minute:
seconds per million iterations of a Python loop; the CPU per message of a two-process ping-pong
through the same middleware (``benchmarks/pingpong.py``; lock-step CPU per step is also given
in ping-pong messages); and the bare lock-step ring (``benchmarks/ring.py``): the node set's
three processes, topics, QoS and messages with no work in the nodes, the ceiling any ``rclpy``
node set with this contract reaches here at that moment. Node set / ring is the share of that
ceiling the nodes' own work leaves, a figure the machine's load moves much less.

Usage: ``python benchmarks/bench_nodes.py [--duration 30] [--lockstep-duration 5]
[--repeats 3]``.
Targets: 1 kHz with zero loss, loop latency p99 < 2 ms, lock-step >= 3x real time.
"""

import argparse
import json
from pathlib import Path
import random
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

from mr_suspension.nodes import contract as c
from mr_suspension.nodes.launch import _env, run_node_set

ROAD = '{type: iso8608, road_class: C, speed: 20.0, seed: 1}'


def losses(res):
    """Messages lost per link: (link, sent, received)."""
    st = res['stats']
    plant, ctl, act = st['plant'], st['controller'], st['actuator']
    rec = st.get('recorder', {}).get('counts', {})
    ns = '/front_left/'
    n = plant['published']
    rows = []
    for topic in (c.IMU_BODY, c.IMU_WHEEL, c.STROKE):
        rows.append((f'plant -> controller {topic}', n, ctl['received'][topic]))
    rows.append((f'plant -> actuator {c.TRUTH_STATE}', n, act['motion_samples']))
    # The plant needs one force per step; the answer to its final sample may arrive after it
    # has finished (not a loss).
    need = min(act['forces_published'], plant['steps'])
    rows.append((f'actuator -> plant {c.DAMPER_FORCE}', need,
                 min(plant['forces_received'], need)))
    rows.append((f'controller -> actuator {c.CURRENT_COMMAND} (during the run)',
                 ctl['commands_after_start'],
                 min(act['commands_after_start'], ctl['commands_after_start'])))
    for topic in c.published_by('plant'):
        if topic == c.CLOCK and plant['mode'] != 'lockstep':
            continue  # /clock is published in lock-step only
        name = topic if topic.startswith('/') else ns + topic
        if name in rec:
            rows.append((f'plant -> recorder {topic}', n, rec[name]))
    for topic in (c.DAMPER_FORCE, c.COIL_CURRENT):
        if ns + topic in rec:
            rows.append((f'actuator -> recorder {topic}', act['forces_published'],
                         rec[ns + topic]))
    return rows


def report_realtime(res, duration):
    """Print the real-time figures."""
    st = res['stats']
    p = st['plant']
    print(f'== real time, separate processes, 1 kHz, {duration:g} s (ISO 8608 C road)')
    print(f'achieved rate:            {p["steps_per_s"]:.1f} steps/s '
          f'({p["steps"]} steps in {p["run_wall_s"]:.2f} s; start-up handshake '
          f'{p["startup_s"]:.3f} s)')
    print(f'timer jitter p50/p99:     {1e3 * p["jitter_p50_s"]:.3f} / '
          f'{1e3 * p["jitter_p99_s"]:.3f} ms')
    print(f'loop latency p50/p99:     {1e3 * p["latency_p50_s"]:.3f} / '
          f'{1e3 * p["latency_p99_s"]:.3f} ms  (sample k published -> force k received)')
    print(f'plant step+publish p50/p99: {1e3 * p["step_cost_p50_s"]:.3f} / '
          f'{1e3 * p["step_cost_p99_s"]:.3f} ms')
    print(f'late forces:              {p["late_forces"]} of {p["steps"]} steps '
          f'(stepped with the previous force after {1e3 * 0.0008:.1f} ms)')
    total_lost = 0
    for link, sent, got in losses(res):
        lost = max(0, sent - got)
        total_lost += lost
        print(f'  lost {lost:6d} of {sent:6d}  {link}')
    print(f'messages lost:            {total_lost}')
    for name in ('plant', 'controller', 'actuator', 'recorder'):
        if name in st:
            print(f'CPU {name:10s}            {100 * st[name]["cpu_fraction"]:.1f} % of a core '
                  f'({st[name]["cpu_s"]:.2f} s over {st[name]["wall_s"]:.2f} s)')
    if 'agreement' in res:
        print('vs offline simulator [%]: ' + ', '.join(
            f'{k} {v:+.3f}' for k, v in res['agreement'].items()))


def report_lockstep(res, duration, label, hop=None):
    """Print the lock-step figures."""
    p = res['stats']['plant']
    print(f'== lock-step, separate processes, {label}: {p["steps"]} steps ({duration:g} s '
          f'simulated) in {p["run_wall_s"]:.2f} s incl. a {p["startup_s"]:.3f} s start-up '
          f'handshake: {p["steps_per_s_sustained"]:.0f} steps/s sustained = '
          f'{p["steps_per_s_sustained"] * 1e-3:.2f}x real time ({p["steps_per_s"]:.0f} steps/s '
          f'overall); loop latency p50/p99 {1e3 * p["latency_p50_s"]:.3f} / '
          f'{1e3 * p["latency_p99_s"]:.3f} ms; lost samples re-sent {p.get("resends", 0)} times')
    cpu = {n: 1e6 * st['cpu_s'] / max(p['steps'], 1) for n, st in res['stats'].items()
           if 'cpu_s' in st}
    hops = f' = {sum(cpu.values()) * 1e-6 / hop:.1f} ping-pong messages' if hop else ''
    print('   CPU per step [us]: ' + ', '.join(f'{n} {v:.0f}' for n, v in cpu.items())
          + f' (total {sum(cpu.values()):.0f} on 2 cores{hops})')
    rows = losses(res)
    print(f'   messages lost: {sum(sent - got for _, sent, got in rows)} over {len(rows)} links '
          f'({sum(sent for _, sent, _ in rows)} messages)')
    if 'agreement' in res:
        print('   vs offline simulator [%]: ' + ', '.join(
            f'{k} {v:+.3f}' for k, v in res['agreement'].items()))


def machine_reference(n=2_000_000):
    """Seconds per million iterations of a plain Python loop (how fast this machine is now).

    The node figures are absolute (steps per second of wall time), so they move with the load
    other tenants put on a shared machine; this reference, measured in the same process just
    before, tells a slow machine from a slow node set.
    """
    t0 = time.perf_counter()
    acc = 0
    for i in range(n):
        acc += i
    return (time.perf_counter() - t0) * 1e6 / n


def _run_roles(script, roles, n):
    """Run ``benchmarks/<script> <role> <n>`` once per role, together on a fresh domain.

    Returns the JSON line each process prints last, in the order of ``roles`` (started in that
    order: the one that starts the exchange last).
    """
    env = _env(random.randint(101, 200))
    path = str(Path(__file__).with_name(script))
    procs = [subprocess.Popen([sys.executable, path, role, str(n)], env=env,
                              stdout=subprocess.PIPE, text=True) for role in roles]
    try:
        return [json.loads(p.communicate(timeout=180)[0].strip().splitlines()[-1])
                for p in procs]
    except subprocess.TimeoutExpired as exc:
        raise RuntimeError(f'{script}: a role did not finish in 180 s (stuck exchange)') from exc
    finally:
        for p in procs:  # never leave a spinning peer behind
            if p.poll() is None:
                p.kill()
                p.wait()


def middleware_reference(n=5000):
    """CPU per message [s] and wall time per round trip [s] of a two-process ping-pong.

    ``benchmarks/pingpong.py``: one message in and one out per message, the same middleware
    path as a lock-step hop. Measured just before the node set, it tells a machine whose
    wake-ups are slow right now (which the Python loop reference does not show) from a slow
    node set.
    """
    rows = _run_roles('pingpong.py', ('b', 'a'), n)
    return (sum(r['cpu_per_message_s'] for r in rows) / len(rows),
            sum(r['round_trip_s'] for r in rows) / len(rows))


def ring_reference(n=10000):
    """Return steps per second and CPU per step [s] of the bare ring (``benchmarks/ring.py``).

    Three processes with the node set's topics, types, QoS and message pattern but no work:
    what any ``rclpy`` node set with this contract reaches on this machine right now.
    """
    rows = _run_roles('ring.py', ('a', 'c', 'p'), n)
    if not all(r['ok'] for r in rows):
        raise RuntimeError(f'ring reference failed: {rows}')
    plant = next(r for r in rows if r['role'] == 'p')
    return plant['steps_per_s'], sum(r['cpu_per_step_s'] for r in rows)


def lockstep_rounds(out, args, hop):
    """Alternate the bare ring and the node set (delay 1, no recorder); return speeds, ratios."""
    speeds, ratios = [], []
    for i in range(args.repeats):
        ring, ring_cpu = ring_reference()
        res = run_node_set(out / f'lockstep_round_{i}', duration=args.lockstep_duration,
                           road=ROAD, controller=args.controller, lockstep=True, record=False,
                           coupling_delay=1, timeout=120.0 + 20.0 * args.lockstep_duration)
        report_lockstep(res, args.lockstep_duration,
                        f'coupling delay 1 (default), without recorder, round {i + 1}', hop)
        nodes = res['stats']['plant']['steps_per_s_sustained']
        speeds.append(nodes)
        ratios.append(nodes / ring)
        print(f'   bare ring just before: {ring:.0f} steps/s = {ring * 1e-3:.2f}x real time, '
              f'{ring_cpu * 1e6:.0f} us CPU per step; node set / ring = {nodes / ring:.2f}')
    return speeds, ratios


def main(argv=None):
    """Run the benchmark and print the figures."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--duration', type=float, default=30.0, help='real-time run [s]')
    ap.add_argument('--lockstep-duration', type=float, default=5.0, help='lock-step run [s]')
    ap.add_argument('--repeats', type=int, default=3, help='lock-step rounds (ring, then '
                    'node set) for the median')
    ap.add_argument('--controller', default='skyhook_onoff')
    ap.add_argument('--out', default='', help='keep bags and logs here (default: temporary)')
    args = ap.parse_args(argv)
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix='bench_nodes_'))
    print(f'machine reference: {machine_reference():.3f} s per million Python loop iterations '
          '(larger = slower machine right now)')
    hop, round_trip = middleware_reference()
    print(f'middleware reference: {hop * 1e6:.1f} us of CPU per message (one in, one out) and '
          f'{round_trip * 1e6:.0f} us per round trip, two-process ping-pong')
    try:
        res = run_node_set(out / 'realtime', duration=args.duration, road=ROAD,
                           controller=args.controller, lockstep=False,
                           timeout=120.0 + 3.0 * args.duration)
        report_realtime(res, args.duration)
        speeds, ratios = lockstep_rounds(out, args, hop)
        print(f'== lock-step, delay 1, no recorder, median of {len(speeds)} rounds: '
              f'{statistics.median(speeds) * 1e-3:.2f}x real time (range '
              f'{min(speeds) * 1e-3:.2f}-{max(speeds) * 1e-3:.2f}x); node set / bare ring '
              f'{statistics.median(ratios):.2f} (range {min(ratios):.2f}-{max(ratios):.2f})')
        for label, record, delay in (
                ('coupling delay 1 (default), with recorder', True, 1),
                ('coupling delay 0 (exact), without recorder', False, 0)):
            res = run_node_set(out / f'lockstep_{record}_{delay}',
                               duration=args.lockstep_duration, road=ROAD,
                               controller=args.controller, lockstep=True, record=record,
                               coupling_delay=delay,
                               timeout=120.0 + 20.0 * args.lockstep_duration)
            report_lockstep(res, args.lockstep_duration, label, hop)
    finally:
        if not args.out:
            shutil.rmtree(out, ignore_errors=True)
    return 0


if __name__ == '__main__':
    main()
