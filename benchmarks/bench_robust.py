"""Robustness check: a diagnosis must not depend on round-off.

Every benchmark record is diagnosed as is (two fit threads, the machine's CPU) and under each
perturbation below; causes and verdicts must not change, and the held-out figures may move
only by round-off:

* ``perturbed``: every measured channel but time multiplied by ``1 + 1e-9 u``,
  ``u ~ U(-1, 1)`` per sample (a million times below any sensor's noise);
* ``threads1``: one fit thread, one BLAS and numba thread (the baseline runs two);
* ``generic``: the compiled kernels built for a generic x86-64 CPU
  (``NUMBA_CPU_NAME=generic``, a cache folder of their own).

Each variant runs in a fresh process of its own (the environment must be set before numpy
and numba load). Records are the rig benchmark's (``bench_diagnose``: out-of-model cases of
``--seed``) the car benchmark's (``bench_diagnose_vehicle``) and the full-car benchmark's
(``bench_diagnose_full_car``).

    .venv/bin/python benchmarks/bench_robust.py --family rig --cases 300 --seed 0
    .venv/bin/python benchmarks/bench_robust.py --family car --cases 200 --duration 60
    .venv/bin/python benchmarks/bench_robust.py --family full_car --cases 40 --seed0 5000
    .venv/bin/python benchmarks/bench_robust.py --family rig --cases 12 --first 0  # a subset
"""

import argparse
import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time

HERE = Path(__file__).resolve().parent
VARIANTS = ('perturbed', 'threads1', 'generic')
EPS = 1e-9


def _env(variant, cache_root):
    """Environment of a variant's process (threads, CPU name, cache folder)."""
    env = dict(os.environ)
    threads = '1' if variant == 'threads1' else '2'
    for k in ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS',
              'NUMBA_NUM_THREADS'):
        env[k] = threads
    env['MR_ROBUST_FIT_THREADS'] = threads
    if variant == 'generic':
        env['NUMBA_CPU_NAME'] = 'generic'
        env['NUMBA_CACHE_DIR'] = str(Path(cache_root) / 'generic')
    return env


def _perturb(columns, seed):
    """Columns with every channel but time scaled by ``1 + EPS u`` (NaNs kept)."""
    import numpy as np
    rng = np.random.default_rng(seed)
    out = {}
    for k, v in columns.items():
        a = np.asarray(v)
        if k == 'time' or a.dtype.kind != 'f':
            out[k] = a
        else:
            out[k] = a * (1.0 + EPS * rng.uniform(-1.0, 1.0, a.shape))
    return out


def _rig_outcome(seed, effects, duration, perturb):
    import warnings
    from mr_suspension.identification import data as dataio
    from mr_suspension.identification import diagnose
    from mr_suspension.truth import cases
    diagnose.JOBS = int(os.environ.get('MR_ROBUST_FIT_THREADS', '2'))
    try:
        case = cases.make_case(seed, effects, sensor_faults=None, duration=duration,
                               measured_current=None)
        cols = _perturb(case.columns, seed) if perturb else case.columns
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            rec = dataio.build_record(f'truth-{seed}', cols)
            res = diagnose.Diagnosis().fit([rec])
    except ValueError as exc:  # refused by the input checks (DataError included)
        return {'error': str(exc)[:80]}
    return {'causes': list(res.causes), 'verdict': res.verdict,
            'ambiguous': sorted('+'.join(p) for p in res.ambiguous),
            'heldout': float(res.heldout['extended_nrmse'])}


def _car_outcome(seed, kind, duration, perturb):
    from mr_suspension.identification import vehicle, vehicle_data
    from mr_suspension.identification.data import DataError
    from mr_suspension.truth.vehicle import make_vehicle_case
    label, eff, faults, with_road = kind
    case = make_vehicle_case(seed, effects=tuple(eff), sensor_faults=tuple(faults),
                             duration=duration, with_road=with_road)
    cols = _perturb(case.columns, seed) if perturb else case.columns
    try:
        rec = vehicle_data.build(f'case{seed}', cols)
    except DataError as exc:
        return {'error': str(exc)[:80]}
    res, _, _ = vehicle.run([rec], vehicle.Nominal.load())
    return {'causes': list(res.causes), 'verdict': res.verdict,
            'ambiguous': sorted('+'.join(p) for p in res.ambiguous),
            'heldout': float(res.heldout['extended_nrmse'])}


def _full_car_outcome(seed, effects, duration, perturb):
    from mr_suspension.identification import full_car, vehicle_data
    from mr_suspension.identification.data import DataError
    from mr_suspension.truth.full_car import make_full_car_case
    case = make_full_car_case(seed, effects=tuple(effects), duration=duration)
    try:
        recs = {c: [vehicle_data.build(c, _perturb(cols, seed + i) if perturb else cols)]
                for i, (c, cols) in enumerate(case.columns.items())}
    except DataError as exc:
        return {'error': str(exc)[:80]}
    diag, _ = full_car.run(recs, full_car.CarNominal.load())
    res = diag.corners.values()
    return {'causes': [f'{c}/{e}' for c, e in diag.causes],
            'verdict': ','.join(r.verdict for r in res),
            'ambiguous': sorted(f'{c}/' + '+'.join(p) for c, r in diag.corners.items()
                                for p in r.ambiguous),
            'heldout': float(sum(r.heldout['extended_nrmse'] for r in res))}


def _jobs(args):
    """``[(seed, spec)]`` of the records, as the two benchmarks draw them."""
    if args.family == 'rig':
        sys.path.insert(0, str(HERE))
        import bench_diagnose
        from mr_suspension.truth import rig
        effs = bench_diagnose.case_list(args.first + args.cases, args.seed, rig.EFFECTS)
        return [(args.seed * 100003 + k, list(effs[k]))
                for k in range(args.first, args.first + args.cases)]
    if args.family == 'full_car':
        from mr_suspension.truth.full_car import FULL_CAR_EFFECTS
        kinds = [[]] * 2 + [[e] for e in FULL_CAR_EFFECTS]
        return [(args.seed0 + k, kinds[k % len(kinds)])
                for k in range(args.first, args.first + args.cases)]
    import numpy as np
    from mr_suspension.truth.vehicle import EFFECTS
    kinds = [('none', (), ())] * 4 + [(e, (e,), ()) for e in EFFECTS] \
        + [(f, (), (f,)) for f in ('acc_bias', 'stroke_lag', 'clipping')]
    rng = np.random.default_rng(args.seed0)
    out = []
    for k in range(args.first + args.cases):
        label, eff, faults = kinds[k % len(kinds)]
        with_road = label == 'sprung_mass' and bool(rng.integers(0, 2))
        if k >= args.first:
            out.append((args.seed0 + k, [label, list(eff), list(faults), with_road]))
    return out


def _one(job):
    family, seed, spec, duration, perturb = job
    t0 = time.time()
    if family == 'rig':
        out = _rig_outcome(seed, tuple(spec), duration, perturb)
    elif family == 'full_car':
        out = _full_car_outcome(seed, spec, duration, perturb)
    else:
        out = _car_outcome(seed, spec, duration, perturb)
    out['seed'] = seed
    out['seconds'] = time.time() - t0
    return out


def run_variant(args):
    """Diagnose every record of one variant (in this process's environment); write JSON."""
    from concurrent.futures import ProcessPoolExecutor
    jobs = [(args.family, s, spec, args.duration, args.variant == 'perturbed')
            for s, spec in _jobs(args)]
    if args.jobs > 1:
        with ProcessPoolExecutor(max_workers=args.jobs) as pool:
            rows = list(pool.map(_one, jobs, chunksize=1))
    else:
        rows = [_one(j) for j in jobs]
    Path(args.out).write_text(json.dumps(rows, indent=1))


def _key(row):
    if 'error' in row:
        return ('error', row['error'])
    return (tuple(row['causes']), row['verdict'], tuple(row['ambiguous']))


def compare(base, other):
    """Return the changed records ``(seed, base, other)`` and the largest held-out change."""
    changed, worst = [], 0.0
    for a, b in zip(base, other):
        if _key(a) != _key(b):
            changed.append((a['seed'], _key(a), _key(b)))
        elif 'heldout' in a and a['heldout'] == a['heldout']:
            worst = max(worst, abs(b['heldout'] / a['heldout'] - 1.0))
    return changed, worst


def main(argv=None):
    """Run the baseline and each variant in processes of their own; print the changes."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--family', choices=('rig', 'car', 'full_car'), default='rig')
    ap.add_argument('--cases', type=int, default=300)
    ap.add_argument('--first', type=int, default=0, help='index of the first record')
    ap.add_argument('--seed', type=int, default=0, help='rig benchmark seed set')
    ap.add_argument('--seed0', type=int, default=1000,
                    help='car benchmark first seed (full car: bench_diagnose_full_car uses 5000)')
    ap.add_argument('--duration', type=float, default=None,
                    help='record length [s] (default: 12 rig, 60 car)')
    ap.add_argument('--jobs', type=int, default=1, help='records diagnosed at once')
    ap.add_argument('--variants', default=','.join(VARIANTS))
    ap.add_argument('--json', default=None,
                    help='write the outcomes of every variant and record to this JSON file')
    ap.add_argument('--variant', default=None, help=argparse.SUPPRESS)
    ap.add_argument('--out', default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.duration is None:
        args.duration = {'rig': 12.0, 'car': 60.0, 'full_car': 30.0}[args.family]
    if args.variant is not None:
        run_variant(args)
        return 0
    variants = [v for v in args.variants.split(',') if v]
    unknown = set(variants) - set(VARIANTS)
    if unknown:
        ap.error(f'unknown variants {sorted(unknown)}; choose from {VARIANTS}')
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for v in ('baseline',) + tuple(variants):
            out = Path(tmp) / f'{v}.json'
            cmd = [sys.executable, __file__, '--variant', v, '--out', str(out)]
            cmd += [f'--{k}={getattr(args, k)}' for k in
                    ('family', 'cases', 'first', 'seed', 'seed0', 'duration', 'jobs')]
            t0 = time.time()
            subprocess.run(cmd, check=True, env=_env(v, tmp))
            results[v] = json.loads(out.read_text())
            print(f'{v:10s} {len(results[v])} records in {time.time() - t0:.0f} s', flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    base = results['baseline']
    total = 0
    for v in variants:
        changed, worst = compare(base, results[v])
        total += len(changed)
        print(f'{v:10s} changed causes or verdicts: {len(changed)}/{len(base)}; largest '
              f'relative change of an unchanged held-out NRMSE: {worst:.1e}')
        for seed, a, b in changed:
            print(f'    record {seed}: {a} -> {b}')
    print(f'robustness: {total} changed outcomes over {len(variants)} variants x {len(base)} '
          f'{args.family} records')
    return 1 if total else 0


if __name__ == '__main__':
    sys.exit(main())
