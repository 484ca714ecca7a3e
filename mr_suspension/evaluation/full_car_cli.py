"""Command line: ``mr-suspension full-car``: tune the full car, carpet plot, single-side bump.

Tunes the laws for seat comfort within the working-space limit
(:mod:`~mr_suspension.evaluation.full_car`), draws the carpet plot against the passive damper
swept over its current range, then drives the car over a single-side bump with the passive
damper at the current that uses the same working space and with the tuned modal sky-hook,
and plots heave, pitch and roll acceleration. Writes ``report.md``, ``report.json``,
``carpet.png`` and ``bump.png``.
"""

import json
import time

import numpy as np

from mr_suspension.cli_common import output_dir
from mr_suspension.control.laws import ControllerParams
from mr_suspension.evaluation import full_car as fce
from mr_suspension.sim import full_car_sim as fs

DEMO_ROAD = 'bump_left'


def register(subparsers):
    """Add the ``full-car`` subcommand."""
    p = subparsers.add_parser(
        'full-car', help='full car: tune laws, carpet plot, single-side bump',
        description='Tune semi-active laws of the full car (four MR corners on one body) for '
                    'seat comfort (ISO 2631-1 total with pitch and roll) with the working '
                    'space limited; carpet plot against the passive damper; a single-side '
                    'bump, passive against the tuned modal sky-hook.')
    p.add_argument('--vehicle', default='lisa_full_car', help='full-car file or name')
    p.add_argument('--damper', default='rd1005_bingham')
    p.add_argument('--driver', default='wonder_box')
    p.add_argument('--roads', default=','.join(fce.DEFAULT_ROADS),
                   help='tuning roads: iso_<class>_<speed>, bump_left, bump_right, bump_both')
    p.add_argument('--laws', default='modal_skyhook,skyhook',
                   help=f'laws to tune (any of {", ".join(fce.FULL_CAR_LAWS)})')
    p.add_argument('--ws-ratio', type=float, default=0.9,
                   help='working-space limit: this times the 0 A car on every road')
    p.add_argument('--maxiter', type=int, default=8, help='generations of the search')
    p.add_argument('--passive-points', type=int, default=21)
    p.add_argument('--duration', type=float, default=fce.SCENARIO_DURATION,
                   help='seconds of each random road (bumps: at most 5 s)')
    p.add_argument('--out', default='out/full_car')
    p.set_defaults(func=run)
    return p


def run(args, log=print):
    """Run the ``full-car`` command; return 0."""
    if args.maxiter < 1:
        raise ValueError(f'--maxiter must be >= 1, got {args.maxiter}')
    laws = [s.strip() for s in str(args.laws).split(',') if s.strip()]
    roads = tuple(s.strip() for s in str(args.roads).split(',') if s.strip())
    if not laws or not roads:
        raise ValueError('full-car: give at least one law and one road')
    plant = fce.FullCarPlant(args.vehicle, args.damper, args.driver, roads,
                             duration=args.duration)
    for name in roads:
        plant.road(name)  # unknown names fail before the search
    lines = demo(plant, laws, output_dir(args.out), args.ws_ratio, args.passive_points,
                 args.maxiter)
    log('\n'.join(lines))
    return 0


def demo(plant, laws, out, ws_ratio=0.9, n_passive=21, maxiter=8):
    """Study, carpet plot and the single-side bump; returns the report's Markdown lines."""
    t0 = time.perf_counter()
    res = fce.study(laws, plant, ws_ratio=ws_ratio, n_passive=n_passive, maxiter=maxiter)
    carpet(res, out / 'carpet.png')
    modal = next((t for t in res.tuned if t.law == 'modal_skyhook'), None)
    lines = ['# Full car', '',
             f'{plant.vehicle}, four {plant.damper} dampers, {plant.driver} drivers; roads '
             f'{", ".join(plant.roads)}. Gains tuned for the seat\'s ISO 2631-1 total '
             "(vertical Wk, pitch and roll We) with every corner's working-space RMS at most "
             f'{ws_ratio:g} x that of the 0 A car; each law against the best constant current '
             f'that uses no more working space on any road ({time.perf_counter() - t0:.0f} s).',
             '', '| law | gains | comfort change | tyre load change | passive current [A] |',
             '|---|---|---|---|---|']
    for t in res.tuned:
        e = t.equal_space
        gains = ', '.join(f'{k} {v:.4g}' for k, v in t.gains.items())
        if e.get('current') is None:
            lines.append(f'| {t.law} | {gains} | - | - | none uses as little space |')
        else:
            lines.append(f'| {t.law} | {gains} | {e["comfort_change_pct"]:+.1f} % | '
                         f'{e["tyre_change_pct"]:+.1f} % | {e["current"]:.3f} |')
    lines += ['', 'Carpet plot: carpet.png.', '']
    report = {'plant': {'vehicle': str(plant.vehicle), 'damper': str(plant.damper),
                        'driver': str(plant.driver), 'roads': list(plant.roads)},
              'passive': {k: np.asarray(v).tolist() for k, v in res.passive.items()},
              'tuned': [{'law': t.law, 'gains': t.gains, 'figures': t.figures,
                         'objective': t.objective, 'violation': t.violation,
                         'equal_space': t.equal_space} for t in res.tuned]}
    if modal is not None and modal.equal_space.get('current') is not None:
        lines += bump_demo(plant, modal, out)
        report['bump'] = lines[-2]
    (out / 'report.json').write_text(json.dumps(report, indent=2, default=float))
    (out / 'report.md').write_text('\n'.join(lines) + '\n')
    return lines


def bump_demo(plant, modal, out):
    """Single-side bump: passive at the equal-space current against the tuned modal law."""
    road = fce.scenario(DEMO_ROAD, plant.car, plant.dt, plant.duration)
    current = modal.equal_space['current']
    runs = {f'passive {current:.2f} A': fs.simulate(plant.config(
                ControllerParams(law='constant', current=current)), road),
            'modal sky-hook (tuned)': fs.simulate(fce.law_config(
                plant, 'modal_skyhook', tuple(modal.gains[g] for g in fce.MODAL_GAINS)), road)}
    lines = ['### Single-side bump (5 cm, 2 m, left wheels, 10 m/s): bump.png', '',
             '| run | seat total [m/s²] | heave Wk [m/s²] | pitch We [rad/s²] | '
             'roll We [rad/s²] | peak roll acc. [rad/s²] |', '|---|---|---|---|---|---|']
    for label, r in runs.items():
        c = r.comfort('seat')
        lines.append(f'| {label} | {c.total:.3f} | {c.heave_wk_rms:.3f} | '
                     f'{c.pitch_we_rms:.3f} | {c.roll_we_rms:.3f} | '
                     f'{np.abs(r.channel("alpha_roll")).max():.2f} |')
    lines.append('')
    bump_plot(runs, out / 'bump.png')
    return lines


def carpet(res, path):
    """Comfort against working space: the passive family and the tuned laws (road-set mean)."""
    from mr_suspension.plots import plt
    obj = res.objective
    p = res.passive
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    ws_p = np.max(np.asarray(p['working_space_rms']) / obj.limit, axis=1)
    axes[0].plot(ws_p, obj.comfort(p), 'k.-', label='passive, 0 to max current')
    axes[1].plot(obj.road_holding(p), obj.comfort(p), 'k.-', label='passive')
    for t in res.tuned:
        met = {k: np.asarray(v)[None, :] for k, v in t.figures.items()}
        ws = np.max(np.asarray(t.figures['working_space_rms']) / obj.limit)
        axes[0].plot(ws, obj.comfort(met)[0], 'o', label=t.law)
        axes[1].plot(obj.road_holding(met)[0], obj.comfort(met)[0], 'o', label=t.law)
    axes[0].axvline(1.0, color='grey', ls=':', lw=1)
    axes[0].set_xlabel('largest working-space RMS / limit')
    axes[1].set_xlabel('dynamic tyre load RMS / 0 A car')
    for ax in axes:
        ax.set_ylabel('seat comfort total / 0 A car')
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle('Full car: tuned laws against the passive damper (road-set means)')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def bump_plot(runs, path):
    """Heave, pitch and roll acceleration of labelled full-car runs."""
    from mr_suspension.plots import plt
    fig, axes = plt.subplots(3, 1, figsize=(9, 7.5), sharex=True)
    for label, r in runs.items():
        for ax, name in zip(axes, ('a_z', 'alpha_pitch', 'alpha_roll')):
            ax.plot(r.t, r.channel(name), lw=0.9, label=label)
    axes[0].set_ylabel('heave acc. [m/s²]')
    axes[1].set_ylabel('pitch acc. [rad/s²]')
    axes[2].set_ylabel('roll acc. [rad/s²]')
    axes[2].set_xlabel('time [s]')
    for ax in axes:
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle('Single-side bump under the left wheels')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
