"""Real-time benchmark of the full-car node set: can it hold its rate, what is lost, what is late.

Runs ``mr_suspension.nodes.launch.run_full_car`` in real time (``lockstep: false``) for
``--duration`` seconds on an ISO 8608 class C two-track road with the recorder, and prints per
configuration: achieved step rate, deadline misses (steps taken more than one period after they
were due by the wall clock), step lag p99/max, late forces (steps that used a one-sample-old
force), loop latency (sample k published -> the last of its four damper forces received), the
messages lost on every link (from the nodes' counters and the bag), CPU per process and the
load average before and after. Configurations (``--configs``):

* ``processes``: full-car plant, four corner controllers, four actuators and the recorder, each
  a process (as ``launch/full_car.launch.py`` starts them);
* ``composed``: plant, controllers and actuators in one process and one executor
  (``full_car_composed``), the recorder in its own;
* ``<config>@<rate>``: the same at a lower rate, e.g. ``processes@500``;
* ``<config>-bare``: without the recorder (the loop alone), e.g. ``composed-bare``.

Before each configuration it waits (``--settle``) until the 1-min load average, which counts
the previous run's processes too, is back below a threshold, so that the load "before" is
the machine's other work. Usage: ``python benchmarks/bench_full_car.py [--duration 60]
[--configs processes composed] [--settle 2.5]``.
Target: the rate held with no deadline miss and no message lost.
"""

import argparse
import json
from pathlib import Path
import shutil
import tempfile
import time

from mr_suspension.nodes import contract as c
from mr_suspension.nodes.launch import run_full_car

ROAD = '{type: iso8608, road_class: C, speed: 20.0, seed: 1}'
SENSORS = (c.IMU_BODY, c.IMU_WHEEL, c.STROKE)


def loadavg():
    """Return the 1, 5 and 15 min load averages."""
    with open('/proc/loadavg', encoding='utf-8') as fh:
        return tuple(float(x) for x in fh.read().split()[:3])


def losses(res):
    """Messages lost per link: ``(link, sent, received)``."""
    st = res['stats']
    plant = st['full_car_plant']
    n = plant['published']
    rec = st.get('recorder', {}).get('counts', {})
    rows = []
    forces = 0
    for corner in c.CORNERS:
        act = st[f'{corner}/actuator']
        rows.append((f'plant -> {corner}/actuator {c.TRUTH_STATE}', n, act['motion_samples']))
        forces += min(act['forces_published'], plant['steps'])
        ctl = st.get(f'{corner}/controller')
        if ctl is not None:
            for topic in SENSORS:
                rows.append((f'plant -> {corner}/controller {topic}', n,
                             ctl['received'][topic]))
            rows.append((f'{corner}/controller -> actuator {c.CURRENT_COMMAND} (run)',
                         ctl['commands_after_start'],
                         min(act['commands_after_start'], ctl['commands_after_start'])))
        for topic in (c.IMU_BODY, c.IMU_WHEEL, c.STROKE, c.TRUTH_STATE, c.TRUTH_TYRE_FORCE):
            name = f'/{corner}/{topic}'
            if name in rec:
                rows.append((f'plant -> recorder {corner}/{topic}', n, rec[name]))
        for topic in (c.DAMPER_FORCE, c.COIL_CURRENT):
            name = f'/{corner}/{topic}'
            if name in rec:
                rows.append((f'{corner}/actuator -> recorder {topic}', act['forces_published'],
                             rec[name]))
    modal = st.get('modal_controller')
    if modal is not None:
        for corner in c.CORNERS:
            for topic in SENSORS:
                rows.append((f'plant -> modal_controller {corner}/{topic}', n,
                             modal['received'][corner][topic]))
        rows.append((f'plant -> modal_controller {c.BODY_IMU}', n,
                     modal['received'][c.BODY_IMU]))
    rows.append(('actuators -> plant damper/force (4 corners)', forces,
                 min(plant['forces_received'], forces)))
    if '/' + c.BODY_IMU in rec:
        rows.append((f'plant -> recorder {c.BODY_IMU}', n, rec['/' + c.BODY_IMU]))
    return rows


def report(name, res, before, after):
    """Print one configuration's figures."""
    st = res['stats']
    p = st['full_car_plant']
    rate = p['rate']
    print(f'== {name}: {rate:g} Hz real time, {p["steps"]} steps; load average '
          f'{before[0]:.2f} before, {after[0]:.2f} after ({after[1]:.2f} over 5 min)')
    print(f'achieved rate        {p["steps_per_s"]:.1f} steps/s ({p["steps"]} steps in '
          f'{p["run_wall_s"]:.2f} s)')
    print(f'deadline misses      {p["deadline_misses"]} of {p["steps"]} steps taken more than '
          f'{1e3 / rate:g} ms late; lag p99/max {1e3 * p["lag_p99_s"]:.2f} / '
          f'{1e3 * p["lag_max_s"]:.1f} ms')
    print(f'late forces          {p["late_forces"]} steps used a one-sample-old force')
    print(f'loop latency p50/p99 {1e3 * p["latency_p50_s"]:.2f} / '
          f'{1e3 * p["latency_p99_s"]:.2f} ms (sample k out -> its 4th force in)')
    total = 0
    worst = []
    for link, sent, got in losses(res):
        lost = max(0, sent - got)
        total += lost
        if lost:
            worst.append((lost, sent, link))
    print(f'messages lost        {total} on {len(losses(res))} links' + (
        ': ' + '; '.join(f'{lost}/{sent} {link}' for lost, sent, link in
                         sorted(worst, reverse=True)[:6]) if worst else ''))
    cpu = {k: v['cpu_fraction'] for k, v in st.items() if 'cpu_fraction' in v}
    print('CPU [% of a core]    ' + ', '.join(f'{k} {100 * v:.0f}' for k, v in cpu.items()))
    if 'agreement' in res:
        print('agreement [%]        max |diff| {:.2f} (real time vs the offline simulator)'
              .format(max(abs(v) for v in res['agreement'].values())))
    episodes = {k: v['fallback_episodes'] for k, v in st.items() if 'fallback_episodes' in v}
    print('fallback episodes    ' + ', '.join(f'{k} {v}' for k, v in episodes.items())
          + ' (1 at start-up, 1 when the plant stops at the end)')


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--duration', type=float, default=60.0)
    ap.add_argument('--configs', nargs='+', default=['processes', 'composed'])
    ap.add_argument('--modal', action='store_true', help='the modal controller')
    ap.add_argument('--out', default='', help='keep the runs here (default: a temp dir)')
    ap.add_argument('--settle', type=float, default=0.0,
                    help='before each run wait (at most 3 min) for the 1-min load average to '
                         'fall below this (0: do not wait)')
    args = ap.parse_args()
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix='bench_full_car_'))
    summary = {}
    for config in args.configs:
        kind, _, rate = config.partition('@')
        kind, _, bare = kind.partition('-')
        if kind not in ('processes', 'composed') or bare not in ('', 'bare'):
            raise SystemExit(f'unknown config {config!r}')
        run = out / config.replace('@', '_')
        if run.exists():
            shutil.rmtree(run)
        end = time.monotonic() + 180.0
        while args.settle and loadavg()[0] > args.settle and time.monotonic() < end:
            time.sleep(5.0)
        before = loadavg()
        try:
            res = run_full_car(run, duration=args.duration, road=ROAD, modal=args.modal,
                               lockstep=False, rate=float(rate or 1000.0),
                               composed=kind == 'composed', domain_id='random',
                               record=not bare)
        except (RuntimeError, TimeoutError) as exc:  # a node died: that is the result
            print(f'== {config}: FAILED, load average {before[0]:.2f} before: '
                  + str(exc).splitlines()[0])
            summary[config] = {'load_before': before, 'failed': str(exc)}
            continue
        after = loadavg()
        report(config, res, before, after)
        summary[config] = {'load_before': before, 'load_after': after, 'stats': res['stats'],
                           'losses': losses(res), 'agreement': res.get('agreement')}
    (out / 'summary.json').write_text(json.dumps(summary, indent=1, default=str),
                                      encoding='utf-8')
    print(f'wrote {out}/summary.json')


if __name__ == '__main__':
    main()
