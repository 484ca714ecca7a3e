"""Fleet diagnosis throughput: serial, 1 and 2 local dask workers; what one task costs.

Generates ``--records`` records of the independent truth (``mr_suspension.truth``: one damper
each, effects cycled, clean sensors, ``--duration`` s at 1 kHz), then runs the fleet exactly as
``mr-suspension diagnose-fleet`` does (``fleet.run_fleet``: load, diagnose, figures, reports
written, summary) serially in this process, and on local clusters of 1 and 2 single-threaded
worker processes. Prints per mode: the end-to-end wall time (cluster start included) and records
per minute, the cluster start alone, and per task: wall and CPU seconds (median, max), the
peak resident memory of the process that ran it, and the bytes returned (reports + figures).
Load average before and after (other jobs on the machine slow every mode).

Usage: ``python benchmarks/bench_fleet.py [--records 8] [--duration 12] [--modes 0,1,2]
[--no-plots] [--json out.json]``.
"""

import argparse
import json
import os
from pathlib import Path
import statistics
import tempfile
import time

from mr_suspension import parallel
from mr_suspension.identification import data as dataio
from mr_suspension.identification import engine, fleet
from mr_suspension.sim.config import load_driver
from mr_suspension.truth import cases

EFFECTS = ((), ('series_stiffness',), ('current_lag',), ('current_saturation',),
           ('gas_spring',), ('hysteresis',), ('direction_asymmetry',), ('current_delay',))


def make_records(folder, n, duration, seed=100):
    """Write ``n`` truth records (CSV) into ``folder``; return the seconds it took."""
    t0 = time.time()
    for k in range(n):
        case = cases.make_case(seed + k, EFFECTS[k % len(EFFECTS)], sensor_faults=(),
                               duration=duration, measured_current=False)
        case.write_csv(Path(folder) / f'damper-{k:03d}.csv')
    return time.time() - t0


def cluster_start(workers):
    """Seconds to start and stop a local cluster of ``workers`` processes."""
    t0 = time.time()
    with parallel.client(workers) as c:
        started = time.time() - t0
        c.run(os.getpid)
    return started


def run_mode(sets, out, settings, workers):
    """One fleet run; return its figures."""
    t0 = time.time()
    rows, _ = fleet.run_fleet(sets, out, settings, workers=workers)
    wall = time.time() - t0
    ok = [r for r in rows if not r.get('error')]
    size = sum(p.stat().st_size for p in Path(out).rglob('*') if p.is_file()
               and p.parent != Path(out))
    task_wall = [r['wall_s'] for r in ok]
    task_cpu = [r['cpu_s'] for r in ok]
    return {'workers': workers, 'records': len(rows), 'failed': len(rows) - len(ok),
            'wall_s': wall, 'records_per_min': 60.0 * len(rows) / wall,
            'task_wall_median_s': statistics.median(task_wall),
            'task_wall_max_s': max(task_wall),
            'task_cpu_median_s': statistics.median(task_cpu),
            # CPU a task got per second of its wall time: 1 = a whole core (below 1: the
            # machine is shared, or the first task of a process loads the package)
            'cpu_per_wall': sum(task_cpu) / sum(task_wall),
            'peak_rss_mb': max(r['peak_rss_mb'] for r in ok),
            'result_kb_per_task': size / 1024.0 / max(1, len(ok))}


def loadavg():
    """Return the 1, 5 and 15 minute load averages."""
    return tuple(round(x, 2) for x in os.getloadavg())


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--records', type=int, default=8)
    ap.add_argument('--duration', type=float, default=12.0, help='record length [s]')
    ap.add_argument('--modes', default='0,1,2', help='worker counts, 0 = serial')
    ap.add_argument('--no-plots', action='store_true')
    ap.add_argument('--json', default=None)
    args = ap.parse_args()
    modes = [int(m) for m in args.modes.split(',')]
    print(f'CPUs {os.cpu_count()}, load average {loadavg()} (1/5/15 min)')
    settings = fleet.Settings(load=dataio.LoadOptions(), effects=tuple(engine.ALL_EFFECTS),
                              nominal=load_driver('wonder_box'), make_plots=not args.no_plots)
    results = {'cpus': os.cpu_count(), 'load_before': loadavg(), 'records': args.records,
               'duration_s': args.duration, 'plots': not args.no_plots, 'modes': []}
    with tempfile.TemporaryDirectory(prefix='bench-fleet-') as tmp:
        src = Path(tmp) / 'in'
        src.mkdir()
        gen = make_records(src, args.records, args.duration)
        print(f'{args.records} records of {args.duration:g} s generated in {gen:.1f} s')
        sets = fleet.find_record_sets([src])
        for w in modes:
            start = cluster_start(w) if w else 0.0
            r = run_mode(sets, Path(tmp) / f'out{w}', settings, w)
            r['cluster_start_s'] = start
            r['load_after'] = loadavg()
            results['modes'].append(r)
            label = 'serial' if w == 0 else f'{w} worker' + 's' * (w > 1)
            print(f'{label:>9}: {r["wall_s"]:6.1f} s for {r["records"]} records = '
                  f'{r["records_per_min"]:5.1f} records/min (cluster start {start:.1f} s); '
                  f'per task wall {r["task_wall_median_s"]:.1f} s median, '
                  f'{r["task_wall_max_s"]:.1f} s max, CPU {r["task_cpu_median_s"]:.1f} s '
                  f'(CPU/wall {r["cpu_per_wall"]:.2f}); '
                  f'peak RSS {r["peak_rss_mb"]:.0f} MB; {r["result_kb_per_task"]:.0f} kB '
                  f'returned per task; load {r["load_after"]}', flush=True)
    results['load_after'] = loadavg()
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2) + '\n')
    return results


if __name__ == '__main__':  # spawned dask workers re-import this script: keep the guard
    main()
