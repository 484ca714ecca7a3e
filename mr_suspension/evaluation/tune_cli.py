"""``mr-suspension tune``: tune control-law gains over a road set and write the carpet report.

``register(subparsers)`` adds the subcommand; :func:`write_outputs` writes the tuned
``config/controllers`` YAML files, ``report.md``, ``report.json`` and the figures of a
:func:`mr_suspension.evaluation.tune.study` (also used by ``mr-suspension demo``).
"""

import argparse
import json
import math
from pathlib import Path
import time

import numpy as np
import yaml

from mr_suspension.cli_common import add_plant_arguments, output_dir
from mr_suspension.evaluation import scenarios as scn, tune
from mr_suspension.sim import config as cfg

EPILOG = """\
objective (road-set mean, each road normalised by the softest passive setting):
  J = w * mean(a_wk / a_wk,soft) + (1 - w) * mean(dF_t / dF_t,soft),  w = --comfort-weight
subject to working-space RMS <= limit on every road (--ws-limit in m, or --ws-ratio times the
softest passive setting's). Optimiser: scipy differential evolution, fixed --seed.

examples:
  mr-suspension tune --law skyhook
  mr-suspension tune --law all --roads iso_B_30,iso_C_20,bump --ws-ratio 0.9 --out out/tune
  mr-suspension tune --vehicle seed001_military --damper seed002_tanh --law pdd,skyhook \\
      --comfort-weight 0.5 --workers 2
"""


def add_arguments(parser):
    """Add the ``tune`` options to ``parser``."""
    parser.add_argument('--law', default='skyhook',
                        help='law(s) to tune, comma separated: controller sets, law names, '
                             "YAML paths, or 'all' (default: %(default)s)")
    add_plant_arguments(parser)
    parser.add_argument('--roads', default=','.join(tune.DEFAULT_ROADS),
                        help='road set: scenario names or groups (see evaluate --help; '
                             'default: %(default)s)')
    parser.add_argument('--comfort-weight', type=float, default=1.0,
                        help='w in [0, 1]: 1 = comfort (Wk RMS) only, 0 = road holding '
                             '(dynamic tyre load RMS) only (default: %(default)s)')
    parser.add_argument('--ws-limit', type=float, default=None,
                        help='working-space RMS limit on every road [m] (default: '
                             "--ws-ratio times the softest passive setting's)")
    parser.add_argument('--ws-ratio', type=float, default=0.9,
                        help='working-space limit as a share of the softest passive '
                             "setting's, per road (default: %(default)s)")
    parser.add_argument('--passive-points', type=int, default=81,
                        help='constant currents of the passive sweep, 0..i_max '
                             '(>= 11; default: %(default)s)')
    parser.add_argument('--maxiter', type=int, default=25,
                        help='differential-evolution generations (default: %(default)s)')
    parser.add_argument('--seed', type=int, default=1, help='optimiser seed (default: 1)')
    parser.add_argument('--workers', type=int, default=0,
                        help='local dask worker processes (0 = serial; default: 0)')
    parser.add_argument('--scheduler', default=None, metavar='ADDRESS',
                        help='use a running dask scheduler, e.g. tcp://host:8786')
    parser.add_argument('--delay', type=float, default=0.0,
                        help='sensor + compute delay before the driver [s] (default: 0)')
    parser.add_argument('--dt', type=float, default=1e-3, help='step [s] (default: 1e-3)')
    parser.add_argument('--no-plots', action='store_true', help='tables and YAML only')
    parser.add_argument('--out', default='out/tune', help='output directory (default: '
                                                          '%(default)s)')
    return parser


def register(subparsers):
    """Add the ``tune`` subcommand to an argparse subparsers object."""
    parser = subparsers.add_parser(
        'tune', help='tune law gains over a road set; carpet plot against the passive damper',
        description='Tune the gains of semi-active laws for comfort (Wk-weighted body '
                    'acceleration RMS) and/or road holding (dynamic tyre load RMS) over a '
                    'road set with a working-space limit; write the tuned config/controllers '
                    'YAML, report.md, report.json and the carpet plot of every law against '
                    'the passive damper swept over its current range.',
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(parser)
    parser.set_defaults(func=run_tune)
    return parser


def _laws(text):
    items = [s.strip() for s in str(text).split(',') if s.strip()]
    if items == ['all']:
        return list(tune.LAWS)
    if not items:
        raise ValueError('--law: give at least one law')
    return items


def run_tune(args, log=print):
    """Run the ``tune`` command; return 0."""
    if args.workers < 0:
        raise ValueError(f'--workers must be >= 0, got {args.workers}')
    if args.maxiter < 1:
        raise ValueError(f'--maxiter must be >= 1, got {args.maxiter}')
    laws = _laws(args.law)
    roads = [s for s in str(args.roads).split(',') if s.strip()]
    plant = tune.Plant(args.vehicle, args.damper, args.driver, tuple(roads), args.dt,
                       args.delay)
    t0 = time.perf_counter()
    res = tune.study(laws, plant, args.comfort_weight, args.ws_limit, args.ws_ratio,
                     args.passive_points, args.maxiter, args.seed, args.workers,
                     args.scheduler, log=log)
    out = output_dir(args.out)
    write_outputs(res, out, plots=not args.no_plots)
    log(headline(res))
    log(f'wrote {out}/report.md, report.json, controllers/*.yaml'
        f'{"" if args.no_plots else ", carpet.png, transmissibility.png"} in '
        f'{time.perf_counter() - t0:.1f} s')
    return 0


def tuned_yaml(result, study):
    """Return the ``config/controllers`` mapping of a tuned law (loadable back)."""
    label = result['label']
    base = {}
    if label in cfg.available('controllers'):
        base = cfg.load_yaml('controllers', label)
    data = {'description': f'{label} tuned by mr-suspension tune ({_objective_text(study)})',
            'source': f'roads {", ".join(study["roads"])}; vehicle {study["plant"]["vehicle"]}, '
                      f'damper {study["plant"]["damper"]}, driver {study["plant"]["driver"]}; '
                      f'default J {result["default"]["J"]:.4f} -> tuned '
                      f'{result["tuned"]["J"]:.4f}'}
    ctrl = result['controller']
    data['law'] = ctrl.law
    data['i_min'] = float(ctrl.i_min)
    data['i_max'] = float(ctrl.i_max)
    for key, value in base.items():
        if key not in data:
            data[key] = value
    for key, value in result['tuned']['changes'].items():
        data[key] = [float(v) for v in value] if isinstance(value, (tuple, list)) \
            else float(value)
    return data


def _objective_text(study):
    w = study['objective']['comfort_weight']
    lim = ', '.join(f'{1e3 * x:.2f}' for x in study['objective']['ws_limit_m'])
    return f'comfort weight {w:g}, working-space RMS limit [{lim}] mm'


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()
                if not str(k).endswith('_obj') and k != 'controller'}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def _pct(value):
    return '-' if value is None or not math.isfinite(value) else f'{value:+.1f} %'


def headline(study):
    """One line per tuned law: what it buys over the best passive setting at equal space."""
    lines = []
    for t in study['tuned']:
        eq = t['equal_space']
        if eq['current'] is None:
            lines.append(f'{t["label"]}: no passive setting uses as little working space')
            continue
        lines.append(
            f'{t["label"]} (tuned): Wk RMS {_pct(eq["wk_change_pct"])}, dynamic tyre load '
            f'{_pct(eq["tyre_change_pct"])} against the best passive setting with no more '
            f'working space on any road ({eq["current"]:.3f} A), road-set mean')
    return '\n'.join(lines)


def report_markdown(study, figures=True):
    """Return the ``report.md`` text of a study."""
    roads = study['roads']
    obj = study['objective']
    p = study['plant']
    lines = ['# Tuning report', '',
             f'Vehicle `{p["vehicle"]}`, damper `{p["damper"]}`, driver `{p["driver"]}`, '
             f'dt {p["dt"]:g} s, delay {1e3 * p["control_delay"]:g} ms. Roads: '
             f'{", ".join(roads)}.', '',
             'Objective (road-set mean, each road normalised by the softest passive setting, '
             'the damper at 0 A): `J = w mean(a_wk / a_wk,soft) + (1 - w) mean(dF_t / '
             f'dF_t,soft)`, w = {obj["comfort_weight"]:g}; working-space RMS limit per road: '
             + ', '.join(f'{r} {1e3 * lim:.2f} mm' for r, lim in zip(roads, obj['ws_limit_m']))
             + f'. Optimiser: {study["optimiser"]["method"]} (seed '
             f'{study["optimiser"]["seed"]}, {study["optimiser"]["maxiter"]} generations max, '
             'penalty 1000 x violation). Run time '
             f'{study["wall_s"]:.1f} s.', '']
    best = study['best_passive']
    if best is not None:
        lines += [f'Best passive setting within the limit: {best["current"]:.3f} A, J = '
                  f'{best["J"]:.4f} (Wk RMS '
                  + ', '.join(f'{v:.3f}' for v in best['metrics']['body_acc_wk_rms'])
                  + ' m/s²).', '']
    lines += ['## Tuned gains', '', '| law | gain | default | tuned | bounds |',
              '|---|---|---|---|---|']
    for t in study['tuned']:
        for g in t['gains']:
            lines.append(f'| {t["label"]} | {g["name"]} [{g["unit"]}] | '
                         f'{t["default"]["gains"][g["name"]]:.4g} | '
                         f'{t["tuned"]["gains"][g["name"]]:.4g} | {g["lo"]:.3g}..{g["hi"]:.3g} '
                         f'({g["scale"]}) |')
    lines += ['', '| law | J default | J tuned | comfort term | road-holding term | '
              'max working space / limit | evaluations | time [s] |',
              '|---|---|---|---|---|---|---|---|']
    for t in study['tuned']:
        lines.append(f'| {t["label"]} | {t["default"]["J"]:.4f} | {t["tuned"]["J"]:.4f} | '
                     f'{t["tuned"]["comfort"]:.4f} | {t["tuned"]["road_holding"]:.4f} | '
                     f'{1.0 + t["tuned"]["g"]:.3f} | {t["evaluations"]} | '
                     f'{t["wall_s"]:.1f} |')
    for bad in study.get('infeasible', []):
        lines.append(f'\n{bad["message"]}')
    lines += ['', '## What semi-active control buys over the best passive setting at equal '
              'working space', '',
              'Best passive = the constant current with the lowest Wk RMS (road-set mean) '
              'among those using no more working-space RMS than the law on every road; '
              'negative = the law is better.', '',
              '| law | gains | passive current [A] | Wk RMS change | tyre load change | '
              + ' | '.join(f'{r}: Wk change (passive A)' for r in roads) + ' |',
              '|---|---|---|---|---|' + '---|' * len(roads)]
    for t in study['tuned']:
        for which in ('default', 'tuned'):
            eq = t['equal_space'] if which == 'tuned' else t['default']['equal_space']
            cur = '-' if eq['current'] is None else f'{eq["current"]:.3f}'
            per = [f'{_pct(r["wk_change_pct"])} ({r["current"]:.3f})'
                   if r['current'] is not None else '-' for r in eq['per_road']]
            lines.append(f'| {t["label"]} | {which} | {cur} | {_pct(eq["wk_change_pct"])} | '
                         f'{_pct(eq["tyre_change_pct"])} | ' + ' | '.join(per) + ' |')
    lines += ['', '## Metrics per road (tuned laws, default laws, passive)', '',
              '| setting | '
              + ' | '.join(f'{r}: Wk [m/s²] / dF_t [N] / x [mm]' for r in roads) + ' |',
              '|---|' + '---|' * len(roads)]

    def cells(met):
        return ' | '.join(f'{met["body_acc_wk_rms"][k]:.3f} / {met["tyre_load_rms"][k]:.0f} / '
                          f'{1e3 * met["working_space_rms"][k]:.2f}' for k in range(len(roads)))

    for t in study['tuned']:
        lines.append(f'| {t["label"]} (tuned) | {cells(t["tuned"]["metrics"])} |')
    for law, met in study['defaults'].items():
        lines.append(f'| {law} (default) | {cells(met)} |')
    sweep = study['passive']
    for target in (0.0, 0.05, 0.1, 0.2, 0.3, 0.5, 1.0, 2.0):
        k = int(np.argmin(np.abs(sweep['current'] - target)))
        if abs(sweep['current'][k] - target) < 0.02:
            lines.append(f'| passive {sweep["current"][k]:.3f} A | '
                         f'{cells({key: sweep[key][k] for key in tune.KEYS})} |')
    if figures:
        lines += ['', '## Figures', '', '![carpet](carpet.png)', '',
                  '![transmissibility](transmissibility.png)']
    return '\n'.join(lines) + '\n'


def transmissibility_curves(study):
    """Transmissibility of the soft and best passive settings and the tuned laws (1st road)."""
    plant = study['plant_obj']
    random_roads = [r for r in study['roads'] if scn.make(r, plant.dt).kind == 'random']
    if not random_roads:
        return None, {}
    road = scn.make(random_roads[0], plant.dt).road
    from mr_suspension.control.laws import ControllerParams
    curves = {'passive 0 A': tune.transmissibility(
        plant.corner(ControllerParams(law='constant', current=0.0)), road)}
    best = study['best_passive']
    if best is not None:
        curves[f'passive {best["current"]:.2f} A (best at the limit)'] = tune.transmissibility(
            plant.corner(ControllerParams(law='constant', current=best['current'])), road)
    for t in study['tuned']:
        curves[f'{t["label"]} (tuned)'] = tune.transmissibility(
            plant.corner(t['controller']), road)
    return random_roads[0], curves


def write_outputs(study, out, plots=True):
    """Write tuned YAMLs, ``report.md``, ``report.json`` and (with ``plots``) the figures."""
    out = Path(out)
    (out / 'controllers').mkdir(parents=True, exist_ok=True)
    for t in study['tuned']:
        path = out / 'controllers' / f'{t["label"]}.yaml'
        path.write_text(yaml.safe_dump(tuned_yaml(t, study), sort_keys=False),
                        encoding='utf-8')
        t['yaml'] = str(path)
    if plots:
        from mr_suspension.evaluation import plots as figs
        figs.carpet(study, out / 'carpet.png',
                    f'comfort vs road holding, {", ".join(study["roads"])}; '
                    f'{_objective_text(study)}')
        road, curves = transmissibility_curves(study)
        if curves:
            figs.transmissibility(curves, out / 'transmissibility.png',
                                  f'transmissibility from the random road {road} (H1, Welch)')
    (out / 'report.md').write_text(report_markdown(study, plots), encoding='utf-8')
    (out / 'report.json').write_text(json.dumps(_jsonable(study), indent=1), encoding='utf-8')
    return out
