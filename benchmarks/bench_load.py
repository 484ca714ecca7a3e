"""Load + input checks of a 2-million-row rig CSV: wall time and peak memory (printed).

Usage: ``python benchmarks/bench_load.py [ROWS] [--diagnose]``. Writes a temporary 1 kHz CSV
(time, displacement, velocity, force, current_command), then times ``data.load_records`` on it
(and with ``--diagnose`` the whole diagnosis after it) in a fresh process so that the peak RSS
(``resource.getrusage``) is its own.
"""

import os
import subprocess
import sys
import tempfile
import time

import numpy as np

CHILD = """
import resource, sys, time, warnings
t0, c0 = time.perf_counter(), time.process_time()
from mr_suspension.identification import data
t1, c1 = time.perf_counter(), time.process_time()
rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter('always')
    (rec,) = data.load_records([sys.argv[1]])
t2, c2 = time.perf_counter(), time.process_time()
rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(f'{rec.n} rows: import {t1 - t0:.2f} s wall ({c1 - c0:.2f} s CPU, {rss0:.0f} MB RSS); '
      f'load + checks {t2 - t1:.2f} s wall ({c2 - c1:.2f} s CPU); peak RSS {rss:.0f} MB; '
      f'findings {[f["finding"] for f in rec.findings]}; {len(caught)} warning(s)')
if len(sys.argv) > 2:
    from mr_suspension.identification import diagnose
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        res = diagnose.run([rec])
    t3, c3 = time.perf_counter(), time.process_time()
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f'diagnose: {t3 - t2:.2f} s wall ({c3 - c2:.2f} s CPU); load + diagnose '
          f'{t3 - t1:.2f} s wall; peak RSS {rss:.0f} MB; verdict {res.verdict}; '
          f'{res.notes.get("long_records")}')
"""


def write_csv(path, rows, rate=1000.0, seed=0):
    """Write a synthetic rig CSV with ``rows`` samples (sine motion, noisy force)."""
    rng = np.random.default_rng(seed)
    t = np.arange(rows) / rate
    x = 0.01 * np.sin(2 * np.pi * 1.3 * t) + 0.003 * np.sin(2 * np.pi * 4.1 * t)
    v = 0.01 * 2 * np.pi * 1.3 * np.cos(2 * np.pi * 1.3 * t) \
        + 0.003 * 2 * np.pi * 4.1 * np.cos(2 * np.pi * 4.1 * t)
    i = np.where((t % 2.0) < 1.0, 0.8, 0.2)
    f = (800 + 1200 * i) * v + (80 + 600 * i) * np.tanh(v / 0.01) + 3 * rng.standard_normal(rows)
    np.savetxt(path, np.column_stack([t, x, v, f, i]), delimiter=',', comments='', fmt='%.9g',
               header='time,displacement,velocity,force,current_command')


def main():
    """Write the CSV, run the timed child process, print its figures."""
    args = [a for a in sys.argv[1:] if not a.startswith('--')]
    rows = int(float(args[0])) if args else 2_000_000
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, 'big.csv')
        t0 = time.perf_counter()
        write_csv(path, rows)
        size = os.path.getsize(path) / 2 ** 20
        print(f'wrote {rows} rows ({size:.0f} MB) in {time.perf_counter() - t0:.1f} s')
        extra = ['diagnose'] if '--diagnose' in sys.argv else []
        out = subprocess.run([sys.executable, '-c', CHILD, path] + extra, capture_output=True,
                             text=True, check=False)
        print(out.stdout.strip() or out.stderr.strip())


if __name__ == '__main__':
    main()
