"""Command line: ``mr-suspension <command>``; run ``mr-suspension --help`` for the list."""

import argparse
import importlib
import json
from pathlib import Path
import sys
import time

from mr_suspension.cli_common import output_dir, road_spec_from_args, run_command
from mr_suspension.core import road as roads
from mr_suspension.core.metrics import ride_metrics
from mr_suspension.sim.corner import build_corner
from mr_suspension.sim.simulator import simulate

# Commands of the plugins that need more than numpy/scipy (shown as unavailable if those fail).
PLUGIN_COMMANDS = {'mr_suspension.nodes.cli': ('nodes',)}
# Subcommands contributed by the other parts of the package (each has register(subparsers)).
PLUGINS = ('mr_suspension.identification.cli', 'mr_suspension.evaluation.cli',
           'mr_suspension.evaluation.tune_cli', 'mr_suspension.evaluation.full_car_cli',
           'mr_suspension.nodes.cli', 'mr_suspension.bagtools')

METRIC_LABELS = {
    'body_acc_rms': ('body acc. RMS', 'm/s²'),
    'body_acc_peak': ('body acc. peak', 'm/s²'),
    'body_acc_wk_rms': ('Wk-weighted acc. RMS', 'm/s²'),
    'vdv': ('VDV', 'm/s^1.75'),
    'working_space_rms': ('working space RMS', 'm'),
    'working_space_peak': ('working space peak', 'm'),
    'tyre_load_rms': ('dyn. tyre load RMS', 'N'),
    'ntf_rms': ('normalised dyn. tyre load RMS, (F_t - F_t0) / F_t0', '-'),
    'ntf_min': ('min. normalised tyre force, F_t / F_t0', '-'),
    'tyre_force_min': ('min. tyre force', 'N'),
    'lift_off_fraction': ('tyre lift-off fraction', '-'),
    'displacement_difference_peak': ('peak z_s - z_u (seed 003)', 'm'),
    'settling_time': ('settling time', 's'),
    'damper_energy': ('energy dissipated by the damper', 'J'),
}


def _road_from_args(args, dt):
    return roads.from_spec(road_spec_from_args(args), duration=args.duration, dt=dt)


def corner_from_args(args, controller=None):
    """Build a :class:`CornerConfig` from the common ``--vehicle/--damper/...`` options.

    The one builder of the package (:func:`mr_suspension.sim.corner.build_corner`): the
    controller gets this corner's vehicle, damper (inverse model) and driver range, as in the
    node set and the evaluation.
    """
    return build_corner(controller or args.controller, args.vehicle, args.damper, args.driver,
                        dt=args.dt, control_delay=args.control_delay)


def add_corner_options(p):
    """Add the options that select vehicle, damper, driver, controller and time step."""
    p.add_argument('--vehicle', default='city_car',
                   help='vehicle set in config/vehicles or a YAML path (default: %(default)s)')
    p.add_argument('--damper', default='rd1005_bingham',
                   help='damper set in config/dampers or a YAML path (default: %(default)s)')
    p.add_argument('--driver', default='wonder_box',
                   help='driver set in config/drivers or a YAML path (default: %(default)s)')
    p.add_argument('--controller', default='skyhook_onoff',
                   help='controller set in config/controllers or a YAML path '
                        '(default: %(default)s)')
    p.add_argument('--dt', type=float, default=1e-3, help='time step [s] (default: 1 kHz)')
    p.add_argument('--control-delay', type=float, default=0.0,
                   help='sensor and compute delay before the driver [s]')


def add_road_options(p):
    """Add the road options."""
    p.add_argument('--road', default='bump',
                   choices=['step', 'bump', 'iso8608', 'harmonic', 'sweep'],
                   help='road excitation (default: %(default)s)')
    p.add_argument('--road-class', default='C', help='ISO 8608 class A..H (default: C)')
    p.add_argument('--speed', type=float, default=15.0, help='vehicle speed [m/s]')
    p.add_argument('--height', type=float, default=0.05,
                   help='step/bump height or harmonic/sweep amplitude [m]')
    p.add_argument('--freq', type=float, default=1.5, help='harmonic frequency [Hz]')
    p.add_argument('--duration', type=float, default=10.0, help='simulated time [s]')
    p.add_argument('--seed', type=int, default=0, help='random road seed')


def metrics_table(rows, title=''):
    """Return a Markdown table of metrics: ``rows`` maps a label to a metrics dict."""
    labels = list(rows)
    keys = [k for k in METRIC_LABELS if all(k in rows[lab] for lab in labels)]
    out = [f'### {title}', ''] if title else []
    out.append('| metric | unit | ' + ' | '.join(labels) + ' |')
    out.append('|---|---|' + '---|' * len(labels))
    for k in keys:
        name, unit = METRIC_LABELS[k]
        out.append(f'| {name} | {unit} | ' + ' | '.join(f'{rows[lab][k]:.4g}' for lab in labels)
                   + ' |')
    return '\n'.join(out) + '\n'


def run_comparison(cfgs, road, out, stem):
    """Simulate labelled configs on one road; write CSV, PNG and metrics; return metrics."""
    from mr_suspension import plots
    results = {label: simulate(cfg, road) for label, cfg in cfgs.items()}
    transient = road.name in ('step', 'bump')
    metrics = {label: ride_metrics(res, 0.5 if transient else 0.0)
               for label, res in results.items()}
    if not transient:  # settling is defined after a single event, not on a random road
        for m in metrics.values():
            m.pop('settling_time')
    for label, res in results.items():
        res.to_csv(out / f'{stem}_{label}.csv')
    plots.time_histories(results, out / f'{stem}_time.png', title=f'{stem}: {road.name}')
    plots.damper_loops(results, out / f'{stem}_damper.png')
    return metrics


def _label(name):
    """Label of a controller set in file names: the stem of a YAML path, else the name."""
    path = Path(str(name))
    return path.stem if path.suffix in ('.yaml', '.yml', '.json') else str(name)


def cmd_simulate(args):
    """Simulate one corner (and a passive reference) and write CSV, plots and metrics."""
    out = output_dir(args.out)
    cfg = corner_from_args(args)
    cfgs = {_label(args.controller): cfg}
    if args.reference and args.reference != args.controller:
        cfgs[_label(args.reference)] = corner_from_args(args, args.reference)
    road = _road_from_args(args, cfg.dt)
    t0 = time.perf_counter()
    metrics = run_comparison(cfgs, road, out, args.road)
    elapsed = time.perf_counter() - t0
    table = metrics_table(metrics, f'{road.name}, {road.duration:g} s')
    (out / 'metrics.md').write_text(table)
    (out / 'metrics.json').write_text(json.dumps(metrics, indent=2))
    print(table)
    print(f'wrote {out}/ ({len(cfgs)} runs of {road.duration:g} s in {elapsed:.2f} s)')
    return 0


def _law_list(text):
    items = tuple(s.strip() for s in text.split(',') if s.strip())
    if not items:
        raise argparse.ArgumentTypeError('give at least one law')
    return items


def cmd_demo(args):
    """Run the default scenario set: bump and ISO 8608 road, semi-active vs passive.

    Then the quick tuning study (:func:`demo_tuning`), the full car (tuned modal sky-hook,
    carpet plot, one-side bump), the node set and a diagnosis of real rig data
    (``identification.cli.demo``).
    """
    out = output_dir(args.out)
    cfgs = {name: build_corner(name, 'city_car', 'rd1005_bingham', 'wonder_box')
            for name in ('passive_0A', 'passive_1A', 'skyhook_onoff')}
    scenarios = {'bump': roads.bump(height=0.05, length=2.0, speed=10.0, duration=5.0),
                 'random': roads.iso8608('C', speed=20.0, duration=30.0, seed=1)}
    lines = ['# mr_suspension demo', '',
             'City-car corner, RD-1005-3 class damper (smooth Bingham), Wonder Box driver.', '']
    for name, road in scenarios.items():
        metrics = run_comparison(cfgs, road, out, name)
        (out / f'{name}_metrics.json').write_text(json.dumps(metrics, indent=2))
        lines.append(metrics_table(metrics, f'{name} ({road.name}, {road.duration:g} s)'))
    lines += demo_tuning(out / 'tune', args.quick_laws)
    if not args.no_full_car:
        from mr_suspension.evaluation import full_car, full_car_cli
        plant = full_car.FullCarPlant()
        lines += [''] + full_car_cli.demo(plant, ('modal_skyhook', 'skyhook'),
                                          output_dir(out / 'full_car'))
    text = '\n'.join(lines)
    (out / 'metrics.md').write_text(text)
    print(text)
    rc = 0
    if not args.no_nodes:
        try:
            nodes_cli = importlib.import_module('mr_suspension.nodes.cli')
        except ModuleNotFoundError as exc:
            if exc.name != 'mr_suspension.nodes.cli':
                raise
        else:
            rc = nodes_cli.demo(out / 'nodes')
    if not args.no_diagnosis:
        from mr_suspension.identification import cli as diag_cli
        rc = diag_cli.demo(out / 'diagnose', args.vrths) or rc
    print(f'wrote {out}/')
    return rc


DEMO_LAWS = ('skyhook_onoff', 'skyhook', 'hybrid', 'add', 'sh_add', 'pdd', 'clipped_optimal')


def demo_tuning(out, laws=DEMO_LAWS):
    """Quick tuning study of the demo: carpet plot and semi-active gain at equal space.

    Tunes ``laws`` for comfort over the default road set (working-space RMS at most 90 % of
    the 0 A damper's on every road, 10 generations) and writes ``out/carpet.png`` and the
    report; returns the Markdown lines for the demo's summary.
    """
    from mr_suspension.evaluation import tune, tune_cli
    t0 = time.perf_counter()
    res = tune.study(list(laws), tune.Plant(), comfort_weight=1.0, ws_ratio=0.9, n_passive=41,
                     maxiter=10, seed=1)
    tune_cli.write_outputs(res, output_dir(out))
    best = min(res['tuned'], key=lambda t: t['equal_space']['wk_change_pct'])
    eq = best['equal_space']
    lines = ['### Tuned laws against the passive damper (carpet plot: tune/carpet.png)', '',
             f'Roads {", ".join(res["roads"])}; gains tuned for Wk RMS with the working-space '
             'RMS at most 90 % of that of the 0 A damper on every road; each law compared with '
             'the best constant current that uses no more working space on any road '
             f'(tuning and sweep {time.perf_counter() - t0:.1f} s).', '',
             '| law | Wk RMS change | tyre load change | passive current [A] |',
             '|---|---|---|---|']
    for t in res['tuned']:
        e = t['equal_space']
        cur = '-' if e['current'] is None else f'{e["current"]:.3f}'
        lines.append(f'| {t["label"]} | {e["wk_change_pct"]:+.1f} % | '
                     f'{e["tyre_change_pct"]:+.1f} % | {cur} |')
    lines += ['', f'Semi-active buys {-eq["wk_change_pct"]:.1f} % lower Wk-weighted body '
              f'acceleration RMS ({best["label"]}, road-set mean) than the best passive '
              f'setting with no more working space, at {eq["tyre_change_pct"]:+.1f} % dynamic '
              'tyre load.', '']
    return lines


def build_parser():
    """Return the argument parser with every subcommand."""
    parser = argparse.ArgumentParser(
        prog='mr-suspension',
        description='Semi-active MR-damper quarter-car suspension: simulate, evaluate control '
                    'laws, and diagnose what a damper model gets wrong on measured data.')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND')
    sub.required = True

    p = sub.add_parser('simulate', help='simulate one corner over a road',
                       description='Simulate one quarter-car corner with the MR damper, '
                                   'driver and controller over a road; write CSV time '
                                   'histories, PNG plots and a metrics table.')
    add_corner_options(p)
    add_road_options(p)
    p.add_argument('--reference', default='passive_0A',
                   help='also run this controller set for comparison ("" for none)')
    p.add_argument('--out', default='out/simulate', help='output directory')
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser('demo', help='default scenarios (bump and random road)',
                       description='Run the default demo: bump and ISO 8608 class C road, '
                                   'skyhook vs passive at 0 A and 1 A; a quick tuning of the '
                                   'laws with the carpet plot against the passive damper '
                                   '(out/tune); the full car tuned with modal sky-hook '
                                   '(out/full_car); then the ROS 2 node set with a recorded bag '
                                   'when available; finally a diagnosis of real rig data '
                                   '(six vrths sine tests, validated on its earthquake '
                                   'record) into out/diagnose.')
    p.add_argument('--out', default='out/demo', help='output directory')
    p.add_argument('--no-nodes', action='store_true', help='skip the ROS 2 node-set run')
    p.add_argument('--no-full-car', action='store_true',
                   help='skip the full-car tuning and one-side bump (out/full_car)')
    p.add_argument('--no-diagnosis', action='store_true',
                   help='skip the diagnosis of the shared vrths rig data')
    p.add_argument('--vrths', default=None, metavar='DIR',
                   help='the vrths data folder (default: ../shared/data/vrths from the working '
                        'directory, then from the source tree)')
    p.add_argument('--quick-laws', default=','.join(DEMO_LAWS), type=_law_list,
                   help='laws tuned for the carpet plot (default: %(default)s)')
    p.set_defaults(func=cmd_demo)

    for name in PLUGINS:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name != name:
                _unavailable(sub, name, exc)
            continue
        except ImportError as exc:  # e.g. the ROS client library but not its C libraries
            _unavailable(sub, name, exc)
            continue
        module.register(sub)
    return parser


def _unavailable(sub, plugin, exc):
    """Register the commands of a plugin that failed to import; using one says why."""
    reason = ' '.join(str(exc).split())[:200]

    def fail(args):
        raise ValueError(f'{args.command} is unavailable: {plugin} cannot be imported '
                         f'({type(exc).__name__}: {reason}); install or source its '
                         'dependencies (e.g. ROS 2 for the nodes)')
    for cmd in PLUGIN_COMMANDS.get(plugin, ()):
        p = sub.add_parser(cmd, help=f'(unavailable: {type(exc).__name__})',
                           prefix_chars='+', add_help=False)  # any options: report, not parse
        p.add_argument('rest', nargs='*')
        p.set_defaults(func=fail)


def main(argv=None):
    """Entry point of ``mr-suspension``."""
    parser = build_parser()
    args = parser.parse_args(argv)
    return run_command(args)


if __name__ == '__main__':
    sys.exit(main())
