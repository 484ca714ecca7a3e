"""``mr-suspension evaluate``: run control laws over scenarios, write tables, plots and studies.

``register(subparsers)`` adds the subcommand to the package CLI; ``main()`` runs it stand-alone
(``python -m mr_suspension.evaluation.cli --help``).
"""

import argparse
import json
import math
import sys
import time

import numpy as np
import yaml

from mr_suspension.cli_common import add_plant_arguments, output_dir, run_command
from mr_suspension.control.laws import LAW_IDS
from mr_suspension.evaluation import plots, runner, scenarios as scn, studies, tables
from mr_suspension.sim import config as cfg
from mr_suspension.sim.frequency import sine_dwell_gains

STUDIES = ('frequency', 'tradeoff', 'seeds', 'bounds', 'degradation', 'noise', 'estimator')

EPILOG = """\
laws: controller sets of config/controllers ({sets}) or bare law names ({laws}).
scenarios: step, bump, sweep, iso_<A..H>_<speed m/s>, harmonic_<Hz>, or the groups
  {groups}.
studies (--study, comma separated or 'all'): {studies}.

examples:
  mr-suspension evaluate --laws passive_0A,skyhook,pdd --scenarios quick
  mr-suspension evaluate --scenarios iso --set skyhook.c_sky=3000 --set '*.estimation=ideal'
  mr-suspension evaluate --actuator-scale 2 --delay 0.01 --study degradation,bounds
  mr-suspension evaluate --laws skyhook --tune skyhook.c_sky=500,1000,2000,4000
"""


def _parse_sets(items):
    out = {}
    for item in items or []:
        if '=' not in item or '.' not in item.split('=', 1)[0]:
            raise ValueError(f'--set expects law.param=value, got {item!r}')
        key, value = item.split('=', 1)
        law, param = key.split('.', 1)
        out.setdefault(law, {})[param] = yaml.safe_load(value)
    return out


def _parse_tune(item):
    if '=' not in item or '.' not in item.split('=', 1)[0]:
        raise ValueError(f'--tune expects law.param=v1,v2,..., got {item!r}')
    key, values = item.split('=', 1)
    law, param = key.split('.', 1)
    vals = [yaml.safe_load(v) for v in values.split(',') if v.strip()]
    if not vals:
        raise ValueError(f'--tune {item!r}: no values')
    return law, param, vals


def _laws(text):
    if text in (None, '', 'all'):
        return list(runner.DEFAULT_LAWS)
    return [s.strip() for s in text.split(',') if s.strip()]


def add_arguments(parser):
    """Add the evaluate options to ``parser``."""
    parser.add_argument('--laws', default='all',
                        help="comma-separated controller sets or law names (default: 'all', "
                             'the sets listed below)')
    parser.add_argument('--scenarios', default='quick',
                        help='comma-separated scenarios or groups (default: %(default)s)')
    add_plant_arguments(parser)
    parser.add_argument('--delay', type=float, default=0.0,
                        help='sensor + compute delay before the driver [s] (default: 0)')
    parser.add_argument('--actuator-scale', type=float, default=1.0,
                        help='multiply driver and fluid time constants and dead time '
                             '(0 = ideal actuator; default: 1)')
    parser.add_argument('--estimation', choices=('sensors', 'ideal'), default=None,
                        help='velocity source for all laws (default: as in each set, '
                             'i.e. sensors)')
    parser.add_argument('--set', action='append', default=[], metavar='LAW.PARAM=VALUE',
                        help="override a gain, e.g. skyhook.c_sky=3000; '*' for all laws "
                             '(repeatable)')
    parser.add_argument('--tune', action='append', default=[], metavar='LAW.PARAM=V1,V2,...',
                        help='grid-search one gain on the first random scenario (or iso_C_20) '
                             'and report the best value for --objective (repeatable)')
    parser.add_argument('--objective', default='body_acc_wk_rms',
                        help='index minimised by --tune (default: %(default)s)')
    parser.add_argument('--reference', default='passive_0A',
                        help='law the relative table compares with (default: %(default)s)')
    parser.add_argument('--study', default='tradeoff',
                        help="extra studies, comma separated or 'all' "
                             f"({', '.join(STUDIES)}; default: %(default)s; 'none' for none)")
    parser.add_argument('--light', action='store_true',
                        help='light studies: bump instead of ISO roads, few frequencies and '
                             'optimiser iterations (smoke runs; the figures are rough)')
    parser.add_argument('--dt', type=float, default=1e-3, help='step [s] (default: 1e-3)')
    parser.add_argument('--no-plots', action='store_true', help='tables only')
    parser.add_argument('--out', default='evaluation_out',
                        help='output directory (default: %(default)s)')
    return parser


def register(subparsers):
    """Add the ``evaluate`` subcommand to an argparse subparsers object."""
    epilog = EPILOG.format(sets=', '.join(_safe_sets()), laws=', '.join(sorted(LAW_IDS)),
                           groups=', '.join(sorted(scn.GROUPS)), studies=', '.join(STUDIES))
    parser = subparsers.add_parser(
        'evaluate', help='compare semi-active control laws over road scenarios',
        description='Run control laws through the offline simulator (driver, fluid and '
                    'sensor-based estimation in the loop) and write a metrics table (RMS and '
                    'Wk-weighted body acceleration, VDV, working space RMS/peak, dynamic tyre '
                    'load RMS, settling time), plots and optional studies.',
        epilog=epilog, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(parser)
    parser.set_defaults(func=run_evaluate)
    return parser


def _safe_sets():
    try:
        return cfg.available('controllers')
    except (FileNotFoundError, OSError):
        return []


def _studies(text):
    if text in (None, '', 'none'):
        return []
    if text == 'all':
        return list(STUDIES)
    items = [s.strip() for s in text.split(',') if s.strip()]
    bad = sorted(set(items) - set(STUDIES))
    if bad:
        raise ValueError(f'unknown study {bad}; known: {STUDIES}')
    return items


def _fmt_rows(rows, keys, scale=None):
    scale = scale or {}
    head = '| ' + ' | '.join(keys) + ' |'
    lines = [head, '|' + '---|' * len(keys)]
    for r in rows:
        cells = []
        for k in keys:
            v = r.get(k, '')
            if isinstance(v, float):
                v = v * scale.get(k, 1.0)
                cells.append(f'{v:.4g}' if math.isfinite(v) else ('inf' if v > 0 else '-'))
            else:
                cells.append(str(v))
        lines.append('| ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines)


def run_evaluate(args, log=print):
    """Run the ``evaluate`` command; return its exit code (0: success).

    A command returns an exit code: returning the metric rows made ``sys.exit(rows)`` exit
    with 1 after a successful run. :func:`evaluate` returns the rows.
    """
    evaluate(args, log)
    return 0


def evaluate(args, log=print):
    """Run the evaluation described by parsed ``args``; returns the metric rows."""
    laws = _laws(args.laws)
    overrides = _parse_sets(args.set)
    if args.estimation:
        overrides.setdefault('*', {})['estimation'] = args.estimation
    names = scn.expand(args.scenarios)
    studies_ = _studies(args.study)
    out = output_dir(args.out)
    common = {'vehicle': args.vehicle, 'damper': args.damper, 'driver': args.driver}
    study_road = 'bump' if args.light else 'iso_C_20'
    t0 = time.perf_counter()
    rows, kept = runner.run(laws, names, control_delay=args.delay,
                            actuator_scale=args.actuator_scale, overrides=overrides, dt=args.dt,
                            keep=True, **common)
    report = ['# Evaluation', '', f'vehicle {args.vehicle}, damper {args.damper}, driver '
              f'{args.driver} (x{args.actuator_scale:g}), delay {1e3 * args.delay:g} ms', '',
              tables.markdown(rows)]
    rel = tables.relative(rows, args.reference)
    report += ['', f'Change relative to {args.reference} [%]:', '',
               tables.markdown(rel, percent=True)]
    tables.write_csv(rows, out / 'metrics.csv')
    log(tables.markdown(rows))
    if not args.no_plots:
        for name in names:
            sc_kind = scn.make(name, args.dt).kind
            if sc_kind == 'transient':
                plots.time_histories({law: kept[(law, name)] for law in laws},
                                     out / f'time_{name}.png', f'{name}', t_max=6.0)
    if 'tradeoff' in studies_:
        ref = 'iso_C_20' if 'iso_C_20' in names else names[-1]
        sweep = runner.passive_sweep(np.linspace(0.0, 2.0, 21), ref, args.vehicle, args.damper)
        sweep['label'] = 'passive 0..2 A'
        if not args.no_plots:
            plots.tradeoff(rows, out / f'tradeoff_{ref}.png', sweep, ref,
                           f'comfort vs working space and road holding, {ref}')
        fams = {}
        for law in laws:
            name = law if law in runner.GAIN_SWEEPS else cfg.load_controller(law).law \
                if law in _safe_sets() else law
            if name not in runner.GAIN_SWEEPS:
                continue
            param, values = runner.GAIN_SWEEPS[name]
            values = values[::2] if args.light else values
            fams[f'{law} ({param})'] = runner.tune(
                law, param, values, ref, control_delay=args.delay, overrides=overrides,
                dt=args.dt, **common)[3]
        if fams and not args.no_plots:
            plots.tradeoff_families(fams, out / f'tradeoff_families_{ref}.png', sweep,
                                    f'gain families vs the passive family, {ref}')
        eq = studies.equal_space_comparison(rows, sweep, ref)
        report += ['', f'## Comfort at equal working space vs the passive family ({ref})', '',
                   _fmt_rows(eq, ['law', 'working_space_rms', 'body_acc_wk_rms',
                                  'passive_wk_same_space', 'change_pct'],
                             {'working_space_rms': 1e3})]
    if 'frequency' in studies_:
        freqs = np.geomspace(0.5, 20.0, 18)
        fam = {}
        for law in laws:
            conf = runner.build_config(law, control_delay=args.delay,
                                       actuator_scale=args.actuator_scale, overrides=overrides,
                                       dt=args.dt, **common)
            fam[law] = (freqs, sine_dwell_gains(conf, freqs, 0.005))
        if not args.no_plots:
            plots.response_figure(fam, out / 'frequency_response.png',
                                  'rig-style frequency responses, 5 mm road')
    for item in args.tune:
        law, param, values = _parse_tune(item)
        target = next((n for n in names if n.startswith('iso_')), 'iso_C_20')
        best, vals, obj, met = runner.tune(law, param, values, target, args.objective,
                                           control_delay=args.delay, overrides=overrides,
                                           dt=args.dt, **common)
        tune_rows = [{param: v, args.objective: float(o),
                      'working_space_rms': float(w), 'tyre_load_rms': float(t)}
                     for v, o, w, t in zip(vals, obj, met['working_space_rms'],
                                           met['tyre_load_rms'])]
        text = _fmt_rows(tune_rows, list(tune_rows[0]), {'working_space_rms': 1e3})
        report += ['', f'## Tuning {law}.{param} on {target} ({args.objective}); best '
                   f'{best}', '', text]
        log(f'tune {law}.{param} on {target}: best {best}\n{text}')
    if 'seeds' in studies_:
        from mr_suspension.evaluation import seeds
        r1 = seeds.seed001_reproduction(None if args.no_plots else out,
                                        n_sim=6 if args.light else 24)
        report += ['', '## Seed 001', '', 'C_eq [N s/m] per current (rows 0..0.5 A) and '
                   'frequency (0.4..3.6 Hz):', '', '```', np.array2string(np.round(r1['ceq'])),
                   '```', '']
        for key in ('claims_linear', 'claims_simulated'):
            report.append(f'{key}:')
            report += [f'- {"AGREES" if ok else "DIFFERS"}: {text} ({detail})'
                       for text, ok, detail in r1[key]]
        r3 = seeds.seed003_reproduction(laws=[law for law in laws if law != 'passive_0A'][:3],
                                        out_dir=None if args.no_plots else out)
        report += ['', '## Seed 003', '', _fmt_rows(seeds.seed003_summary(r3), [
            'road', 'passive_peak_cm', 'sa_peak_cm', 'reported_sa_peak_cm', 'improvement_ours',
            'improvement_reported', 'body_acc_rms_change', 'passive_settle', 'sa_settle']), '',
            _fmt_rows(r3, ['road', 'suspension', 'stroke_peak', 'settling_time',
                           'body_acc_rms', 'body_acc_peak', 'tyre_load_rms'],
                      {'stroke_peak': 100.0})]
    if 'bounds' in studies_:
        best, _, _ = studies.best_passive(study_road, args.vehicle, args.damper)
        report += ['', f'## Best passive settings ({study_road})', '',
                   _fmt_rows([{'index': k, 'best current [A]': v['current'][0],
                               'value': v['current'][1], 'best linear c [N s/m]':
                               v['linear'][0], 'value (linear)': v['linear'][1]}
                              for k, v in best.items()],
                             ['index', 'best current [A]', 'value', 'best linear c [N s/m]',
                              'value (linear)'])]
        for road in (('bump',) if args.light else ('bump', 'iso_C_20')):
            bc = studies.bound_comparison(laws, road, driver=args.driver,
                                          vehicle=args.vehicle, damper=args.damper,
                                          duration=1.0 if args.light else 3.0,
                                          block=0.1 if args.light else 0.02,
                                          maxiter=5 if args.light else 40)
            report += ['', f'## Laws vs best passive and the offline semi-active reference '
                       f'({road}, 3 s)', '',
                       _fmt_rows(bc, ['objective', 'law', 'value', 'closeness'])]
    if 'degradation' in studies_:
        rs, rdl = studies.degradation(laws, study_road, scales=(0.0, 1.0, 4.0) if args.light
                                      else (0.0, 0.5, 1.0, 2.0, 4.0), **common)
        report += ['', f'## Degradation with actuator speed ({study_road})', '',
                   _fmt_rows(rs, ['law', 'scale', 'body_acc_wk_rms', 'working_space_rms',
                                  'tyre_load_rms'], {'working_space_rms': 1e3}), '',
                   f'## Degradation with sensor + compute delay ({study_road})', '',
                   _fmt_rows(rdl, ['law', 'delay', 'body_acc_wk_rms', 'working_space_rms',
                                   'tyre_load_rms'], {'working_space_rms': 1e3,
                                                      'delay': 1e3})]
        if not args.no_plots:
            scales = sorted({r['scale'] for r in rs})
            series = {}
            for law in laws:
                wk = [r['body_acc_wk_rms'] for r in rs if r['law'] == law]
                if max(wk) - min(wk) > 1e-4 * max(wk):       # constant currents: flat, skip
                    series[law] = [100.0 * (w / wk[0] - 1.0) for w in wk]
            plots.lines(scales, series, out / 'degradation_actuator.png',
                        'actuator time-constant scale (0 = ideal, 1 = Wonder Box + fluid)',
                        'Wk body acceleration RMS change vs ideal actuator [%]', study_road)
    if 'noise' in studies_:
        levels = studies.NOISE_LEVELS[::3] if args.light else studies.NOISE_LEVELS
        nr = studies.noise_study(laws, study_road, levels, **common)
        report += ['', f'## Sensor noise ({study_road}; accelerometers m/s^2 RMS, stroke mm '
                   'RMS)', '', _fmt_rows(nr, ['law', 'noise_acc', 'noise_stroke',
                                              'body_acc_wk_rms', 'working_space_rms',
                                              'tyre_load_rms'],
                                         {'noise_stroke': 1e3, 'working_space_rms': 1e3})]
    if 'estimator' in studies_:
        er = studies.estimator_delays(freqs=(1.0, 5.0) if args.light
                                      else (0.5, 1.0, 2.0, 5.0, 10.0))
        report += ['', '## Estimator delays (positive = lag)', '', _fmt_rows(er, list(er[0]))]
        report += ['', f'body-velocity error after 60 s of a 0.05 m/s^2 accelerometer bias: '
                   f'{studies.bias_drift():.4f} m/s (bound 0.05 / (2 pi 0.1) = '
                   f'{0.05 / (2 * math.pi * 0.1):.4f} m/s)']
    (out / 'report.md').write_text('\n'.join(report) + '\n', encoding='utf-8')
    (out / 'metrics.json').write_text(json.dumps(rows, indent=1), encoding='utf-8')
    log(f'wrote {out}/report.md, metrics.csv, metrics.json and figures '
        f'in {time.perf_counter() - t0:.1f} s')
    return rows


def main(argv=None):
    """Stand-alone entry point: ``python -m mr_suspension.evaluation.cli [options]``."""
    parser = argparse.ArgumentParser(prog='mr-suspension')
    sub = parser.add_subparsers(dest='command', required=True)
    register(sub)
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] != 'evaluate':
        argv = ['evaluate'] + argv
    args = parser.parse_args(argv)
    code = run_command(args)
    if code:
        raise SystemExit(code)  # as argparse's own errors: the caller exits with the code
    return 0


if __name__ == '__main__':
    sys.exit(main())
