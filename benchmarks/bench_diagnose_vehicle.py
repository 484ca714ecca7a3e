"""Benchmark of ``diagnose-vehicle`` on the independent vehicle truth (``truth/vehicle.py``).

Random cases (one hidden corner effect, a sensor fault, or none) of 60 s at 1 kHz: first cause
right per effect (on effects that change the body acceleration by >= 3x the sensor noise),
false alarms on effect-free cases, the extended model's NRMSE on an unseen record against
the truth model's, two ways (the truth's clean body acceleration, and the truth's strut law fed
the same estimated motion and measured current as the fits: see :func:`truth_nrmse`), and the
wall time of one
diagnosis.

    .venv/bin/python benchmarks/bench_diagnose_vehicle.py [--cases 100] [--duration 60]
"""

import argparse
from collections import defaultdict
import json
import sys
import time

import numpy as np

from mr_suspension.identification import sensors, vehicle, vehicle_data
from mr_suspension.identification.data import DataError

CONTRIB_MIN = 3.0


def _nrmse(rec, y, pred):
    c = sensors.lowpass(pred - pred.mean(), rec.dt, rec.cutoff, order=4)
    e = y - c
    return float(np.sqrt(np.mean((e - e.mean()) ** 2)) / np.std(y))


def truth_nrmse(case, rec, nominal):
    """NRMSE of the truth model against the measured body acceleration (as fitted).

    ``clean``: the truth's own noise-free body acceleration (true motion, so only the IMU's
    noise is left). ``inputs``: the truth's strut law (with its own field current) driven,
    like the fitted models, by the motion ``diagnose-vehicle`` estimates from the measured
    stroke and IMUs (``truth.vehicle.body_acc_from_inputs``). ``inputs_coil``: the same, fed
    the measured coil current too (when there is one) through the truth's own field lags.
    The fitted models see the estimated motion and the measured current; a fitted model can
    beat the truth fed noisy inputs (its refit absorbs part of the input noise), so the
    truth with its own current is the conservative reference.
    """
    from mr_suspension.truth.vehicle import body_acc_from_inputs
    y = sensors.lowpass(rec.body_acc - rec.body_acc.mean(), rec.dt, rec.cutoff, order=4)
    P = vehicle.Prepared([rec], nominal)
    return {'clean': _nrmse(rec, y, case.clean['body_acc']),
            'inputs': _nrmse(rec, y, body_acc_from_inputs(case, P.x[0], P.v[0])),
            'inputs_coil': _nrmse(rec, y, body_acc_from_inputs(case, P.x[0], P.v[0],
                                                               rec.coil_current))}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--cases', type=int, default=100)
    ap.add_argument('--duration', type=float, default=60.0)
    ap.add_argument('--seed0', type=int, default=1000)
    ap.add_argument('--json', default=None, help='write the per-case rows here')
    ap.add_argument('--free', type=int, default=4,
                    help='effect-free slots per cycle of the case kinds (default: %(default)s, '
                         'about a quarter of the cases: enough to resolve a 5 %% false-alarm '
                         'rate)')
    args = ap.parse_args(argv)
    try:
        from mr_suspension.truth.vehicle import EFFECTS, make_vehicle_case
    except ImportError:
        print('mr_suspension/truth/vehicle.py is not available: nothing to benchmark')
        return 1
    nominal = vehicle.Nominal.load()
    kinds = [('none', (), ())] * max(args.free, 0) + [(e, (e,), ()) for e in EFFECTS] \
        + [(f, (), (f,)) for f in ('acc_bias', 'stroke_lag', 'clipping')]
    rng = np.random.default_rng(args.seed0)
    rows = []
    for k in range(args.cases):
        label, eff, faults = kinds[k % len(kinds)]
        seed = args.seed0 + k
        with_road = label == 'sprung_mass' and bool(rng.integers(0, 2))
        case = make_vehicle_case(seed, effects=eff, sensor_faults=faults,
                                 duration=args.duration, with_road=with_road)
        try:
            rec = vehicle_data.build(f'case{seed}', case.columns)
        except DataError as exc:
            rows.append({'seed': seed, 'label': label, 'error': str(exc)})
            continue
        t0 = time.time()
        res, P, _ = vehicle.run([rec], nominal)
        wall = time.time() - t0
        unseen = case.unseen()
        urec = vehicle_data.build('unseen', unseen.columns)
        _, fig = vehicle.predict_records(res, [urec], nominal)
        ref = truth_nrmse(unseen, urec, nominal)
        row = {'seed': seed, 'label': label, 'verdict': res.verdict, 'causes': res.causes,
               'sensor': [f['finding'] for f in res.findings],
               'contribution': case.contributions.get(label),
               'first': res.causes[0] if res.causes else None, 'wall_s': wall,
               'unseen_extended': fig['extended_nrmse'],
               'unseen_baseline': fig['baseline_nrmse'], 'unseen_truth': ref['clean'],
               'unseen_truth_inputs': ref['inputs'],
               'unseen_truth_inputs_coil': ref['inputs_coil'],
               'untestable': sorted(res.untestable)}
        rows.append(row)
        print(json.dumps({k: v for k, v in row.items() if k != 'untestable'}), flush=True)
    summarise(rows)
    if args.json:
        with open(args.json, 'w', encoding='utf-8') as fh:
            json.dump(rows, fh, indent=1)
    return 0


def summarise(rows):
    """Print the figures of the issue."""
    per = defaultdict(lambda: [0, 0])
    alarms = [0, 0]
    sensor_alarms = [0, 0]
    ratios, ratios_in, ratios_coil = [], defaultdict(list), []
    walls = []
    for r in rows:
        if 'error' in r:
            continue
        walls.append(r['wall_s'])
        if r['unseen_truth'] > 0:
            ratios.append(r['unseen_extended'] / r['unseen_truth'])
        if r.get('unseen_truth_inputs'):
            ratios_in[r['label']].append(r['unseen_extended'] / r['unseen_truth_inputs'])
        if r.get('unseen_truth_inputs_coil'):
            ratios_coil.append(r['unseen_extended'] / r['unseen_truth_inputs_coil'])
        if r['label'] == 'none':
            alarms[1] += 1
            alarms[0] += bool(r['causes'])
            continue
        if r['label'] in ('acc_bias', 'stroke_lag', 'clipping'):
            sensor_alarms[1] += 1
            sensor_alarms[0] += bool(r['causes'])
            per[r['label']][1] += 1
            name = {'acc_bias': 'accelerometer_bias'}.get(r['label'], r['label'])
            per[r['label']][0] += name in r['sensor']
            continue
        if (r['contribution'] or 0) < CONTRIB_MIN or r['label'] in r['untestable']:
            continue
        per[r['label']][1] += 1
        per[r['label']][0] += r['first'] == r['label']
    print('\nfirst cause right (effects >= 3x noise, testable):')
    tot = [0, 0]
    for k, (a, n) in sorted(per.items()):
        print(f'  {k:24s} {a}/{n}')
        if k not in ('acc_bias', 'stroke_lag', 'clipping'):
            tot[0] += a
            tot[1] += n
    if tot[1]:
        print(f'  all corner/driver effects: {100 * tot[0] / tot[1]:.0f} %')
    if alarms[1]:
        print(f'false alarms on effect-free cases: {alarms[0]}/{alarms[1]}')
    if alarms[1] + sensor_alarms[1]:
        a, n = alarms[0] + sensor_alarms[0], alarms[1] + sensor_alarms[1]
        print(f'false alarms counting sensor-fault-only cases (a physical cause named): '
              f'{a}/{n} = {100 * a / n:.1f} %')
    if ratios:
        print(f'extended unseen NRMSE / truth model NRMSE (truth on the true motion): median '
              f'{np.median(ratios):.2f}')
    if ratios_in:
        every = np.concatenate(list(ratios_in.values()))
        print(f'extended unseen NRMSE / truth model NRMSE (truth fed the same estimated motion): '
              f'median {np.median(every):.2f}, p90 {np.percentile(every, 90):.2f}')
        for k, v in sorted(ratios_in.items()):
            print(f'  {k:24s} median {np.median(v):.2f}, max {np.max(v):.2f} ({len(v)} cases)')
    if ratios_coil:
        print(f'extended unseen NRMSE / truth model NRMSE (truth fed the same motion and the '
              f'measured coil current): median {np.median(ratios_coil):.2f}')
    if walls:
        print(f'diagnosis wall time: median {np.median(walls):.1f} s, max {np.max(walls):.1f} s')


if __name__ == '__main__':
    sys.exit(main())
