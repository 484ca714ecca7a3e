"""Command line: ``diagnose``, ``diagnose-fleet``, ``diagnose-vehicle``, ``predict``, ``doe``.

Standalone: ``python -m mr_suspension.identification.cli diagnose DATA... --out DIR``.
"""

import argparse
from pathlib import Path
import sys
import warnings

import numpy as np

from mr_suspension.cli_common import output_dir, run_command
from mr_suspension.identification import data as dataio
from mr_suspension.identification import engine, fleet, model_io, synthetic
from mr_suspension.identification.pipeline import diagnose_to_dir

LOAD_HELP = ('Column/unit options: --columns force=F,time=t maps file columns (or bag topics) '
             'to quantities; --units displacement=mm,force=kN converts to SI.')


def _add_load_options(p):
    g = p.add_argument_group('input format')
    g.add_argument('--columns', action='append', default=[], metavar='QTY=NAME',
                   help='map a quantity (time, displacement, velocity, force, current_command, '
                        'voltage_command, current, temperature) to a file column or bag topic')
    g.add_argument('--units', action='append', default=[], metavar='QTY=UNIT',
                   help='units of a quantity: s/ms, m/mm/cm, m/s/mm/s/cm/s, N/kN, A/mA, V')
    g.add_argument('--preset', choices=('auto', 'vrths', 'none'), default='auto',
                   help='file-name presets for the vrths rig data (default: auto-detect)')
    g.add_argument('--velocity-cutoff', type=float, default=None, metavar='HZ',
                   help='zero-phase low-pass cut-off of the velocity (default: from the motion '
                        'band, 1.6x its edge, noise above it removed)')
    g.add_argument('--derive-velocity', action='store_true',
                   help='ignore a velocity column and differentiate displacement')
    g.add_argument('--ignore-measured-current', action='store_true',
                   help='use the command even when a measured coil current is recorded')


def _load_options(args):
    from mr_suspension.core.validation import check_range
    if args.velocity_cutoff is not None:
        check_range('diagnose', '--velocity-cutoff', args.velocity_cutoff, 0.01, 1.0e4, 'Hz',
                    'velocity low-pass cut-off')
    return dataio.LoadOptions(columns=dataio.parse_mapping(args.columns, '--columns'),
                              units=dataio.parse_mapping(args.units, '--units'),
                              preset=args.preset, velocity_cutoff=args.velocity_cutoff,
                              derive_velocity=args.derive_velocity,
                              use_measured_current=not args.ignore_measured_current)


def _add_diagnose_options(p, quiet_help):
    p.add_argument('--effects', default=','.join(engine.ALL_EFFECTS),
                   help='comma-separated subset of the catalogue to test')
    p.add_argument('--driver', default='wonder_box',
                   help='nominal driver (config/drivers/NAME.yaml or a YAML path) that a '
                        'measured coil current is compared with (default wonder_box)')
    p.add_argument('--folds', type=int, default=5, help='cross-validation folds (default 5)')
    p.add_argument('--no-plots', action='store_true', help='skip the PNG figures')
    p.add_argument('--quiet', action='store_true', help=quiet_help)


def _diagnose_settings(args):
    """Return the checked ``(LoadOptions, effects, folds, nominal driver)`` options."""
    if not 2 <= args.folds <= 50:
        raise ValueError(f'--folds must be 2..50, got {args.folds}')
    opts = _load_options(args)
    effects = tuple(e.strip() for e in args.effects.split(',') if e.strip())
    bad = [e for e in effects if e not in engine.ALL_EFFECTS]
    if bad:
        raise dataio.DataError(f'unknown effect(s) {bad}; known: '
                               f'{", ".join(engine.ALL_EFFECTS)}')
    from mr_suspension.sim.config import load_driver
    return opts, effects, args.folds, load_driver(args.driver)


def register(subparsers):
    """Add the ``diagnose``, ``diagnose-fleet``, ``predict``, ``doe`` subcommands to a parser."""
    p = subparsers.add_parser(
        'diagnose', help='find what the nominal damper model gets wrong, and why',
        description='Fit the baseline smooth-Bingham rig model, test every catalogue effect '
                    f'({", ".join(engine.EFFECTS)}) on held-out blocks, name the cause(s) '
                    '(or none, or ambiguous), and write report.json, report.md, figures and '
                    'model.json. ' + LOAD_HELP)
    p.add_argument('data', nargs='+', help='CSV/text files, .mat files, rosbag2 bags or '
                                           'directories of them')
    p.add_argument('--out', required=True, help='output directory')
    p.add_argument('--validate', action='append', default=[], metavar='FILE',
                   help='record never used in the fit, scored with the final models '
                        '(repeat for several)')
    _add_diagnose_options(p, 'no progress bar or summary')
    _add_load_options(p)
    p.set_defaults(func=cmd_diagnose)
    p = subparsers.add_parser(
        'diagnose-fleet', help='diagnose many dampers: one report per record set, fleet table',
        description='Find the record sets in the folders (each CSV/text/.mat file, each '
                    'rosbag2 bag, and each sub-folder of record files is one damper), run '
                    'one diagnose per set (serially or on dask.distributed), write each '
                    'report to OUT/<name>/ exactly as diagnose does, and a fleet summary '
                    'OUT/fleet.md and OUT/fleet.csv (a set that fails is an error row). '
                    'See docs/parallel.md for running on a cluster. ' + LOAD_HELP)
    p.add_argument('dirs', nargs='+', metavar='DIR',
                   help='folders of record sets (or single records/bags)')
    p.add_argument('--out', required=True, help='output directory')
    g = p.add_mutually_exclusive_group()
    g.add_argument('--workers', type=int, default=None, metavar='N',
                   help='local dask worker processes (default: one per CPU, at most one per '
                        'record set; serial with one CPU); 0 runs serially in this process')
    g.add_argument('--scheduler', default=None, metavar='ADDRESS',
                   help='run on an existing dask cluster, e.g. tcp://host:8786 (workers '
                        'need this package version and the record paths)')
    _add_diagnose_options(p, 'no per-set progress lines or summary')
    _add_load_options(p)
    p.set_defaults(func=cmd_diagnose_fleet)
    _register_vehicle(subparsers)
    p = subparsers.add_parser(
        'predict', help='evaluate a fitted model on a record; writes time,force',
        description='Evaluate model.json (from diagnose) on new records. ' + LOAD_HELP)
    p.add_argument('input', help='record (CSV/.mat/bag); force column not needed')
    p.add_argument('--model', required=True, help='model.json written by diagnose')
    p.add_argument('--out', required=True, help='output CSV (time,force); with several '
                                                'records, one file per record (_k suffix)')
    _add_load_options(p)
    p.set_defaults(func=cmd_predict)
    p = subparsers.add_parser(
        'doe', help='write a rig programme that makes every catalogue effect identifiable',
        description='Rig programme (seed 000 series and seed 002 DoE): harmonic blocks at '
                    'several frequencies, amplitudes, offsets and constant currents; current '
                    'steps up and down at constant speed; random motion and current; long '
                    'enough to heat the damper. Columns: time, displacement [m], velocity '
                    '[m/s], current_command [A].')
    p.add_argument('--out', required=True, help='output CSV')
    p.add_argument('--duration', type=float, default=120.0, help='seconds (default 120)')
    p.add_argument('--rate', type=float, default=1000.0, help='sample rate Hz (default 1000)')
    p.add_argument('--stroke', type=float, default=0.02, help='amplitude m (default 0.02)')
    p.add_argument('--v-max', type=float, default=0.25, help='peak speed m/s (default 0.25)')
    p.add_argument('--i-max', type=float, default=1.0, help='max current A (default 1.0)')
    p.add_argument('--seed', type=int, default=0)
    p.set_defaults(func=cmd_doe)


def _register_vehicle(subparsers):
    """Add ``diagnose-vehicle`` (``identification/vehicle.py``)."""
    from mr_suspension.identification import vehicle
    p = subparsers.add_parser(
        'diagnose-vehicle', help='diagnose a car corner from its sensor bags/CSV (no load cell)',
        description="Fit the nominal corner (vehicle, damper, driver from config/) to a car's "
                    'sensor data through the body equation m_s a_body = strut force, test the '
                    f'corner catalogue ({", ".join(vehicle.ALL_EFFECTS)}) on held-out blocks, '
                    'name the cause(s) (or none, ambiguous, partly_explained, untestable) and '
                    'write report.json, report.md, figures and vehicle.yaml, damper.yaml, '
                    'driver.yaml for simulate. Inputs: rosbag2 bags of the contract topics '
                    '(imu/body, imu/wheel, stroke, current_command, coil_current) or CSV with '
                    'time, body_acc, wheel_acc (IMU specific force, gravity included, z up, '
                    'm/s^2), stroke (m, + = extension), current_command (A), optional '
                    "coil_current (A) and road (m, a rig's shaker). See "
                    'docs/diagnose_vehicle.md.')
    p.add_argument('data', nargs='+', help='CSV files, rosbag2 bags or directories of them')
    p.add_argument('--out', required=True, help='output directory')
    p.add_argument('--namespace', default=None,
                   help='corner namespace in the bag (e.g. front_left; default: the only one)')
    p.add_argument('--car', default=None,
                   help='a full car (config name such as lisa_full_car, or YAML): diagnose '
                        'its four corners (namespaces front_left .. rear_right) with the '
                        "body's coupling; --vehicle is then not used")
    p.add_argument('--road-topic', default=None,
                   help='bag topic with the known road/shaker displacement (Float64, or a '
                        'JointState with a "road" joint such as truth/state)')
    p.add_argument('--vehicle', default='city_car', help='nominal vehicle (config name or YAML)')
    p.add_argument('--damper', default='rd1005_bingham',
                   help='nominal damper (config name or YAML)')
    p.add_argument('--driver', default='wonder_box', help='nominal driver (config name or YAML)')
    p.add_argument('--effects', default=','.join(vehicle.ALL_EFFECTS),
                   help='comma-separated subset of the catalogue to test')
    p.add_argument('--no-plots', action='store_true', help='skip the PNG figures')
    p.add_argument('--quiet', action='store_true', help='no summary')
    p.set_defaults(func=cmd_diagnose_vehicle)


def cmd_diagnose_vehicle(args):
    """Run ``diagnose-vehicle``."""
    from mr_suspension.identification import vehicle
    output_dir(args.out)
    effects = tuple(e.strip() for e in args.effects.split(',') if e.strip())
    if args.car is not None:
        return _full_car(args, effects)
    nominal = vehicle.Nominal.load(args.vehicle, args.damper, args.driver)
    rep, _ = vehicle.diagnose_vehicle(args.data, args.out, nominal, effects,
                                      namespace=args.namespace, road_topic=args.road_topic,
                                      make_plots=not args.no_plots)
    if not args.quiet:
        h = rep['heldout']
        causes = ', '.join(f'{c["effect"]} ({c["location"]})' for c in rep['causes']) or 'none'
        print(f'verdict: {rep["verdict"]}; causes: {causes}; held-out body-acc NRMSE baseline '
              f'{h["baseline_nrmse"]:.4f} -> extended {h["extended_nrmse"]:.4f}, noise floor '
              f'{rep["noise_floor"]["nrmse"]:.4f}')
        for f in rep['sensor']:
            print(f'sensor: {f["finding"]}: {f.get("detail", "")}')
        if rep['untestable']:
            print('untestable with these data: ' + ', '.join(rep['untestable']))
        print(f'wrote {Path(args.out) / "report.md"} and vehicle.yaml, damper.yaml, driver.yaml')
    return 0


def _full_car(args, effects):
    from mr_suspension.identification import full_car
    if args.namespace is not None:
        raise dataio.DataError('--car diagnoses all four corners; leave out --namespace')
    nominal = full_car.CarNominal.load(args.car, args.damper, args.driver)
    rep, _ = full_car.diagnose_full_car(args.data, args.out, nominal, effects,
                                        make_plots=not args.no_plots)
    if not args.quiet:
        causes = ', '.join(f'{c["effect"]} at {c["corner"]}' for c in rep['causes']) or 'none'
        print(f'verdict: {rep["verdict"]}; causes: {causes}')
        for c, r in rep['corners'].items():
            h = r['heldout']
            print(f'  {c}: {r["verdict"]}; {", ".join(r["causes"]) or "none"}; held-out '
                  f'NRMSE {h["baseline_nrmse"]:.4f} -> {h["extended_nrmse"]:.4f}')
        print(f'wrote {Path(args.out) / "report.md"} and a folder per corner')
    return 0


def cmd_diagnose(args):
    """Run ``diagnose``."""
    output_dir(args.out)
    opts, effects, folds, nominal = _diagnose_settings(args)
    bar = None

    def loaded(notes):
        nonlocal bar
        for msg in notes:
            print(f'warning: {msg}', file=sys.stderr)
        if not args.quiet:
            from tqdm import tqdm
            bar = tqdm(desc='diagnose', unit='fit', file=sys.stderr,
                       disable=not sys.stderr.isatty())

    def tick(label):
        if bar is not None:
            bar.set_postfix_str(label[:40])
            bar.update(1)

    try:
        rep, res, _ = diagnose_to_dir(args.data, args.out, opts, effects, folds, nominal,
                                      args.validate, make_plots=not args.no_plots,
                                      progress=tick, on_load=loaded)
    finally:
        if bar is not None:
            bar.close()
    if 'current' in res.notes:
        print(f'warning: {res.notes["current"]} (c1 and fy1 are not identifiable; record '
              'several current levels, see mr-suspension doe)', file=sys.stderr)
    if not args.quiet:
        print(summary_text(rep))
        print(f'wrote {Path(args.out) / "report.md"}')
    return 0


DEMO_TESTS = ('10mm1Hz0A', '10mm1Hz0x5A', '10mm1Hz1A', '5mm3Hz0A', '5mm3Hz0x5A', '5mm3Hz1A')


def find_vrths(folder=None):
    """Return the vrths rig data folder (holding ``preprocessed_sine``), or None.

    ``folder`` when given; else ``../shared/data/vrths`` from the working directory, then
    from the source tree.
    """
    shared = Path('..') / 'shared' / 'data' / 'vrths'
    cands = [Path(folder)] if folder else [Path.cwd() / shared,
                                           Path(__file__).resolve().parents[2] / shared]
    for d in cands:
        if (d / 'preprocessed_sine').is_dir():
            return d.resolve()
    return None


def demo(out_dir, vrths=None):
    """Demo step: diagnose six real sine tests of vrths, validate on its earthquake record.

    Two sine programmes (10 mm at 1 Hz, 5 mm at 3 Hz) at 0, 0.5 and 1 A; the report (verdict,
    causes, outer-block and kept-back figures, the learned reference) goes to ``out_dir``.
    """
    d = find_vrths(vrths)
    if d is None:
        print('diagnosis demo skipped: no ../shared/data/vrths beside the repository')
        return 0
    files = [d / 'preprocessed_sine' / f'{name}.txt' for name in DEMO_TESTS]
    quake = d / 'validation' / 'validacion.mat'
    from mr_suspension.sim.config import load_driver
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')  # the input notes are in the report
        rep, _, _ = diagnose_to_dir([str(f) for f in files], output_dir(out_dir),
                                    dataio.LoadOptions(), engine.ALL_EFFECTS, 5,
                                    load_driver('wonder_box'),
                                    [str(quake)] if quake.exists() else [], make_plots=True)
    print(summary_text(rep))
    print(f'wrote {Path(out_dir) / "report.md"}')
    return 0


def summary_text(rep):
    """Short summary of a rig diagnosis report: verdict, causes, the held-out figures."""
    causes = ', '.join(f'{c["effect"]} ({c["location"]})' for c in rep['causes']) or 'none'
    nf = rep['noise_floor']
    floor = f', noise floor {nf["nrmse"]:.4f}' if nf else ', noise floor not estimable'
    ho = rep['heldout']
    lines = [f'verdict: {rep["verdict"]}; causes: {causes}; held-out NRMSE baseline '
             f'{rep["baseline"]["heldout_nrmse"]:.4f} -> extended '
             f'{rep["extended"]["heldout_nrmse"]:.4f} (gain {rep["gain"]:.1%}; {ho["source"]})'
             + floor]
    for key, what in (('outer_blocks', 'outer blocks'), ('forward', 'kept back')):
        if key in ho:
            f = ho[key]
            lines.append(f'  {what}: baseline {f["baseline_nrmse"]:.4f}, extended '
                         f'{f["extended_nrmse"]:.4f} +- {f["extended_se"]:.4f}')
    ref = rep.get('reference')
    if ref:
        lines.append(f'  learned reference ({ref["model"]}): {ref["heldout_nrmse"]:.4f} '
                     f'({ref["verdict_note"]})')
    if rep['ambiguous']:
        lines.append('ambiguous: ' + '; '.join('/'.join(p) for p in rep['ambiguous']))
    if rep['untestable']:
        lines.append('untestable with these data: ' + ', '.join(rep['untestable'])
                     + ' (see mr-suspension doe)')
    if 'validation' in rep and 'baseline_nrmse' not in rep['validation']:
        lines.append(f'validation: {rep["validation"]["note"]}')
    elif 'validation' in rep:
        v = rep['validation']
        ref_v = (f', learned reference {v["reference_nrmse"]:.4f}'
                 if v.get('reference_nrmse') is not None else '')
        lines.append(f'validation NRMSE baseline {v["baseline_nrmse"]:.4f} -> extended as '
                     f'selected {v["selected_nrmse"]:.4f} (gain {v["selected_gain"]:.1%}); '
                     f'handed on ({v["model"]}, cross-fitted) {v["extended_nrmse"]:.4f} '
                     f'(gain {v["gain"]:.1%}){ref_v}')
        if v['dropped']:
            lines.append('  not transferring to the validation records (left out of '
                         'model.json): ' + ', '.join(v['dropped']))
        for line in v.get('domain', ()):
            lines.append(f'  outside the fitted domain: {line}')
    return '\n'.join(lines)


def cmd_diagnose_fleet(args):
    """Run ``diagnose-fleet``: one diagnosis per record set, reports and a fleet table."""
    from mr_suspension import parallel

    out = output_dir(args.out)
    opts, effects, folds, nominal = _diagnose_settings(args)
    if args.workers is not None and args.workers < 0:
        raise ValueError(f'--workers must be >= 0, got {args.workers}')
    sets = fleet.find_record_sets(args.dirs, exclude=[out])
    workers = 0
    if not args.scheduler:
        workers = parallel.default_workers() if args.workers is None else args.workers
        if args.workers is None:
            workers = min(workers, len(sets)) if workers > 1 and len(sets) > 1 else 0
    where = (f'dask scheduler {args.scheduler}' if args.scheduler else
             f'a local dask cluster of {workers} worker process{"es" * (workers > 1)}'
             if workers else 'serially in this process')
    log = None if args.quiet else (lambda line: print(line, flush=True))
    if not args.quiet:
        print(f'{len(sets)} record sets, running {where}', flush=True)
    settings = fleet.Settings(load=opts, effects=effects, folds=folds, nominal=nominal,
                              make_plots=not args.no_plots)
    rows, wall = fleet.run_fleet(sets, out, settings, workers=workers,
                                 scheduler=args.scheduler, log=log)
    rate = 60.0 * len(rows) / wall if wall > 0 else float('nan')
    failed = sum(1 for r in rows if r.get('error'))
    fleet.write_summary(out, rows, header=[
        f'{len(rows)} record sets from {", ".join(args.dirs)}, run {where}: {wall:.1f} s '
        f'wall, {rate:.1f} record sets per minute; {failed} failed.'])
    if not args.quiet:
        print(f'{len(rows)} record sets in {wall:.1f} s ({rate:.1f} per minute), {failed} '
              f'failed; wrote {out / "fleet.md"} and {out / "fleet.csv"}')
    return 0


def _write_csv(path, t, f):
    np.savetxt(path, np.column_stack([t, f]), delimiter=',', header='time,force', comments='',
               fmt='%.9g')


def cmd_predict(args):
    """Run ``predict``."""
    model = model_io.load_model(args.model)
    opts = _load_options(args)
    records = _load_for_predict(args.input, opts)
    out = Path(args.out)
    fitted_with = model.get('input', {}).get('signal')
    for k, r in enumerate(records):
        if fitted_with and r.input_kind != fitted_with:
            print(f'warning: model fitted with {fitted_with} input, record {r.name} gives '
                  f'{r.input_kind}; the prediction uses it as the same current',
                  file=sys.stderr)
        stamps, f = dataio.at_stamps(r, _warning_lines(model_io.predict, model, r))
        path = out if len(records) == 1 else out.with_name(f'{out.stem}_{k}{out.suffix}')
        _write_csv(path, stamps, f)
        print(f'wrote {path} ({stamps.size} rows at the input time stamps)')
    return 0


def _load_for_predict(path, opts):
    """Load records for prediction (any force column is ignored); print input warnings."""
    from dataclasses import replace

    return _warning_lines(dataio.load_records, [path], replace(opts, need_force=False))


def _warning_lines(fn, *args):
    """Return ``fn(*args)``, printing each warning it raises as one ``warning:`` line."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        out = fn(*args)
    for w in caught:
        print(f'warning: {w.message}', file=sys.stderr)
    return out


def cmd_doe(args):
    """Run ``doe``."""
    from mr_suspension.core.validation import check_range
    check_range('doe', '--duration', args.duration, 1.0, 36000.0, 's', 'programme length')
    check_range('doe', '--rate', args.rate, 10.0, 1.0e5, 'Hz', 'sample rate')
    check_range('doe', '--stroke', args.stroke, 1.0e-4, 0.5, 'm', 'amplitude')
    check_range('doe', '--v-max', args.v_max, 1.0e-3, 20.0, 'm/s', 'peak speed')
    check_range('doe', '--i-max', args.i_max, 1.0e-3, 20.0, 'A', 'largest current')
    if args.duration * args.rate > 5.0e7:
        raise ValueError(f'doe: {args.duration * args.rate:.3g} samples is too many; lower '
                         '--duration or --rate (at most 5e7 samples)')
    t, x, i = synthetic.doe_programme(args.duration, args.rate, args.stroke, args.v_max,
                                      args.i_max, args.seed)
    v = np.gradient(x, 1.0 / args.rate)
    np.savetxt(args.out, np.column_stack([t, x, v, i]), delimiter=',',
               header='time,displacement,velocity,current_command', comments='', fmt='%.9g')
    print(f'wrote {args.out}: {t.size} samples, {args.duration:g} s. 40 % harmonic blocks '
          '(0.5-6 Hz, amplitude and offset varied, 4 current levels: saturation, hysteresis vs '
          'series stiffness, gas spring), 30 % current steps up and down at constant speed '
          '(delay, lag, rise vs fall), 30 % random motion and current; the whole run heats '
          'the damper (thermal fade). Record the coil current too to separate driver and '
          'fluid lags.')
    return 0


def main(argv=None):
    """Entry point for ``python -m mr_suspension.identification.cli``."""
    ap = argparse.ArgumentParser(prog='mr-suspension', description='MR damper diagnosis tools')
    sub = ap.add_subparsers(dest='command', required=True)
    register(sub)
    args = ap.parse_args(argv)
    return run_command(args)


if __name__ == '__main__':
    sys.exit(main())
