"""Diagnosis report: ``report.json``, ``report.md``, PNG figures and ``model.json``.

NRMSE = RMS(measured - predicted) / std(measured force), on held-out blocks (cross-validated)
or on separate validation records; ``gain = 1 - NRMSE_extended / NRMSE_baseline``.
"""

import json
from pathlib import Path
import time

import numpy as np

from mr_suspension.identification import diagnose, engine, model_io

BASELINE_MODEL = ('F = F0 + (c0 + c1 i) v + (fy0 + fy1 i) tanh(v / v_y), i = command through '
                  'the static driver map (seed 003 eq. 5.2)')
EFFECT_TEXT = {
    'current_delay': 'dead time between the current command and the field',
    'current_lag': 'first-order lag of the field current (one time constant)',
    'current_lag_asymmetric': 'first-order lag with different rise and fall time constants '
                              '(driver plus fluid demagnetisation, seed 000)',
    'current_saturation': 'yield force saturating with current, Fy = fy0 + fy1 i_s tanh(i/i_s)',
    'hysteresis': 'rate-independent pre-yield loop (Dahl, length x_h) instead of tanh(v/v_y)',
    'series_stiffness': 'compliance k1 in series with the damping element (seed 000)',
    'gas_spring': 'accumulator force kg1 x + kg2 x^2 (seed 000 k2)',
    'thermal_fade': 'force falling as (1 - kappa E) with stored heat E from dissipated energy',
    'direction_asymmetry': 'different force in rebound and compression, (1 + rho tanh(v/v_y))',
}


def _nrmse(mse, std):
    return float(np.sqrt(mse) / std)


def _pad(theta):
    out = np.zeros(7)
    out[:len(theta)] = theta
    return out


def extended_text(effects):
    """One-line description of an extended model."""
    if not effects:
        return 'baseline (no effect added)'
    return 'baseline + ' + ' + '.join(effects)


def build(res, records, validate=(), elapsed=None):
    """Return ``(report dict, model dict, predictions)`` from ``diagnose.run`` output."""
    ds = res['dataset']
    std = ds.f_std
    base = res['baseline']
    final = res['final']
    # Per-fold MSE are means over equal-size folds; pool them weighted by sample counts.
    w = base.n_test / base.n_test.sum()
    base_n = _nrmse(float(np.sum(res['base_exact'] * w)), std)
    ext_n = _nrmse(float(np.sum(res['final_exact'] * w)), std)
    bp = base.params().to_dict()
    causes = []
    for e in res['causes']:
        single = res['singles'].get(e)
        single_n = None
        if e in res.get('cause_test', {}):
            ct = res['cause_test'][e]
            single_n = _nrmse(float(ct.sum() / base.n_test.sum()), std)
        pooled, t, d = (diagnose.fold_stats(single.test, res['singles_base_test'])
                        if single else (0, 0, []))
        causes.append({
            'effect': e, 'description': EFFECT_TEXT[e],
            'parameters': final.effect_params(e),
            'heldout_nrmse': single_n,
            'gain': None if single_n is None else 1.0 - single_n / base_n,
            'evidence': {
                'heldout_mse_reduction_alone': round(float(pooled), 4),
                'fold_t_alone': round(float(t), 2),
                'fold_mse_reductions_alone': [round(float(x), 4) for x in d],
                'mse_loss_if_dropped_from_extended': round(float(res['drop_loss'].get(e, 0)),
                                                           4),
            }})
    amb = [list(p) for p in res['ambiguous']]
    separating = {'/'.join(p): diagnose.SEPARATING_EXPERIMENT.get(
        frozenset(p), 'run the rig programme of mr-suspension doe') for p in res['ambiguous']}
    report = {
        'baseline': {'model': BASELINE_MODEL, 'parameters': bp, 'heldout_nrmse': base_n},
        'verdict': res['verdict'],
        'causes': causes,
        'ambiguous': amb,
        'separating_experiments': separating,
        'untestable': list(res['untestable']),
        'extended': {'model': extended_text(final.effects if res['causes'] else ()),
                     'effects': list(res['causes']), 'heldout_nrmse': ext_n,
                     'parameters': final.params().to_dict() if res['causes'] else bp,
                     'current_dynamics': final.dynamics() if res['causes'] else
                     engine.current_dynamics((), base.eta)},
        'gain': 1.0 - ext_n / base_n,
        'method': {
            'heldout': f'{ds.n_folds}-fold cross-validation over contiguous blocks '
                       f'({4 * ds.n_folds} blocks per record dealt to folds in turn, gaps of '
                       'up to 0.1 s at every block edge); states run from the inputs only',
            'accept': f'pooled held-out MSE reduction >= {diagnose.G_MIN} and fold '
                      f't-statistic >= {diagnose.T_MIN}',
            'ambiguous': f'not separable by that rule and contributions correlated >= '
                         f'{diagnose.CORR_AMBIG}, and the swap of the two in the final model '
                         'is not rejected',
            'nrmse': 'RMS error / std of the measured force',
            'rates': f'selection on records decimated to about {diagnose.SEARCH_RATE:g} Hz '
                     '(the fold statistics in the evidence come from it); baseline, '
                     'extended and per-cause NRMSE are scored at the full rate',
        },
        'evidence': {'selection_steps': res['steps'], 'swap_tests': res['swaps'],
                     'excitation': res['notes']},
        'data': [{'name': r.name, 'samples': r.n, 'dt': r.dt, 'input': r.input_kind,
                  'velocity': r.velocity_source} for r in records],
    }
    if res.get('driver'):
        report['driver'] = {**res['driver'], 'note': (
            'command -> measured coil current; the extended model current dynamics are '
            'then the fluid part (core.driver: driver tau_rise/tau_fall/dead_time, fluid '
            'fluid_tau_rise/fluid_tau_fall)')}
    if res['untestable']:
        report['doe'] = ('mr-suspension doe --out programme.csv writes a rig programme '
                         '(displacement and current command) that makes every catalogue '
                         'effect identifiable')
    if elapsed is not None:
        report['timing_s'] = round(float(elapsed), 2)
    ext_params = final.params() if res['causes'] else base.params()
    ext_dyn = final.dynamics() if res['causes'] else engine.current_dynamics((), base.eta)
    kinds = sorted({r.input_kind for r in records})
    extra = {'heldout_nrmse': ext_n, 'baseline_heldout_nrmse': base_n}
    if res.get('driver'):
        extra['driver'] = {k: res['driver'][k] for k in ('dead_time', 'tau_rise', 'tau_fall')}
    model = model_io.model_dict(ext_params, ext_dyn, res['causes'], kinds[0],
                                [r.name for r in records], extra)
    if validate:
        vstd = float(np.std(np.concatenate([r.force for r in validate])))
        bdyn = engine.current_dynamics((), base.eta)

        def vn(params, dyn):
            err = [r.force - engine.simulate(r, params, dyn) for r in validate]
            return _nrmse(float(np.mean(np.concatenate(err) ** 2)), vstd)

        vb = vn(base.params(), bdyn)
        ve = vn(ext_params, ext_dyn)
        per = {}
        for e in res['causes']:
            s = res['singles'].get(e)
            if s is not None:
                per[e] = vn(s.params(), s.dynamics())
        report['validation'] = {
            'records': [r.name for r in validate], 'baseline_nrmse': vb,
            'extended_nrmse': ve, 'gain': 1.0 - ve / vb, 'single_effect_nrmse': per}
    return report, model


def _predictions(res, records):
    base = res['baseline']
    final = res['final']
    bdyn = engine.current_dynamics((), base.eta)
    out = []
    for r in records:
        fb = engine.simulate(r, base.params(), bdyn)
        fe = engine.simulate(r, final.params(), final.dynamics()) if res['causes'] else fb
        out.append((r, fb, fe))
    return out


def plots(res, records, out_dir, validate=()):
    """Write the PNG figures; return their file names."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    preds = _predictions(res, records)
    names = []
    # Record with the largest baseline error carries the time and loop plots.
    r, fb, fe = max(preds, key=lambda q: np.mean((q[0].force - q[1]) ** 2) * q[0].n)
    n = r.n
    win = min(n, int(4.0 / r.dt))
    err = np.convolve((r.force - fb) ** 2, np.ones(win) / win, mode='valid')
    k0 = int(np.argmax(err)) if err.size else 0
    sl = slice(k0, k0 + win)
    fig, ax = plt.subplots(figsize=(9, 3.5))
    ax.plot(r.time[sl], r.force[sl], 'k', lw=1.0, label='measured')
    ax.plot(r.time[sl], fb[sl], 'C0', lw=1.0, label='baseline')
    ax.plot(r.time[sl], fe[sl], 'C3--', lw=1.0, label='extended')
    ax.set_xlabel('time [s]')
    ax.set_ylabel('force [N]')
    ax.set_title(f'{r.name}: measured vs baseline vs extended')
    ax.legend(loc='upper right', fontsize=8)
    fig.tight_layout()
    fig.savefig(out_dir / 'force_time.png', dpi=90)
    plt.close(fig)
    names.append('force_time.png')
    fig, axs = plt.subplots(1, 2, figsize=(10, 4))
    for ax, xq, lab in ((axs[0], r.velocity, 'velocity [m/s]'),
                        (axs[1], r.displacement, 'displacement [m]')):
        ax.plot(xq[sl], r.force[sl], 'k', lw=0.8, label='measured')
        ax.plot(xq[sl], fb[sl], 'C0', lw=0.8, label='baseline')
        ax.plot(xq[sl], fe[sl], 'C3--', lw=0.8, label='extended')
        ax.set_xlabel(lab)
        ax.set_ylabel('force [N]')
    axs[0].legend(fontsize=8)
    fig.suptitle('force-velocity and force-displacement loops')
    fig.tight_layout()
    fig.savefig(out_dir / 'loops.png', dpi=90)
    plt.close(fig)
    names.append('loops.png')
    v = np.concatenate([q[0].velocity for q in preds])
    i = np.concatenate([q[0].i_in for q in preds])
    rb = np.concatenate([q[0].force - q[1] for q in preds])
    re_ = np.concatenate([q[0].force - q[2] for q in preds])
    tt = np.concatenate([q[0].time for q in preds])
    step = max(1, v.size // 20000)
    fig, axs = plt.subplots(1, 3, figsize=(13, 3.8))
    for ax, xq, lab in ((axs[0], v, 'velocity [m/s]'), (axs[1], i, 'input current [A]'),
                        (axs[2], tt, 'time in record [s]')):
        ax.plot(xq[::step], rb[::step], '.', ms=1, color='C0', alpha=0.4, label='baseline')
        ax.plot(xq[::step], re_[::step], '.', ms=1, color='C3', alpha=0.4, label='extended')
        ax.set_xlabel(lab)
        ax.set_ylabel('residual [N]')
    axs[0].legend(markerscale=8, fontsize=8)
    fig.tight_layout()
    fig.savefig(out_dir / 'residuals.png', dpi=90)
    plt.close(fig)
    names.append('residuals.png')
    edges = {'rising': [], 'falling': []}
    for rr, b_, e_ in preds:
        di = np.diff(rr.i_in)
        rng_ = np.ptp(rr.i_in)
        if rng_ <= 0:
            continue
        pre, post = int(0.02 / rr.dt), int(0.15 / rr.dt)
        for k in np.nonzero(np.abs(di) > 0.2 * rng_)[0]:
            if k < pre or k + post >= rr.n or abs(rr.velocity[k]) < 1e-3:
                continue
            sg = np.sign(rr.velocity[k])
            seg = slice(k - pre, k + post)
            kind = 'rising' if di[k] > 0 else 'falling'
            edges[kind].append((sg * rr.force[seg], sg * b_[seg], sg * e_[seg], rr.dt))
    if edges['rising'] or edges['falling']:
        fig, axs = plt.subplots(1, 2, figsize=(10, 3.8))
        for ax, kind in zip(axs, ('rising', 'falling')):
            evs = edges[kind]
            if not evs:
                ax.set_title(f'no {kind} edges')
                continue
            m = min(len(e[0]) for e in evs)
            dt = evs[0][3]
            tq = (np.arange(m) - int(0.02 / dt)) * dt * 1e3
            for j, (lab, sty) in enumerate((('measured', 'k'), ('baseline', 'C0'),
                                            ('extended', 'C3--'))):
                ax.plot(tq, np.mean([e[j][:m] for e in evs], axis=0), sty, label=lab)
            ax.set_title(f'{len(evs)} {kind} current edges (sign of v removed)')
            ax.set_xlabel('time after edge [ms]')
            ax.set_ylabel('force [N]')
        axs[0].legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(out_dir / 'current_edges.png', dpi=90)
        plt.close(fig)
        names.append('current_edges.png')
    if validate:
        vp = _predictions(res, validate)
        fig, axs = plt.subplots(len(vp), 1, figsize=(10, 1.9 * len(vp) + 0.6), squeeze=False)
        for ax, (rr, b_, e_) in zip(axs[:, 0], vp):
            w = min(rr.n, int(6.0 / rr.dt))
            err = np.convolve((rr.force - b_) ** 2, np.ones(w) / w, mode='valid')
            k0 = int(np.argmax(err)) if err.size else 0
            q = slice(k0, k0 + w)
            ax.plot(rr.time[q], rr.force[q], 'k', lw=0.8, label='measured')
            ax.plot(rr.time[q], b_[q], 'C0', lw=0.8, label='baseline')
            ax.plot(rr.time[q], e_[q], 'C3--', lw=0.8, label='extended')
            ax.set_ylabel('force [N]')
            ax.set_title(rr.name, fontsize=8)
        axs[0, 0].legend(fontsize=7, loc='upper right')
        axs[-1, 0].set_xlabel('time [s]')
        fig.tight_layout()
        fig.savefig(out_dir / 'validation.png', dpi=90)
        plt.close(fig)
        names.append('validation.png')
    return names


def markdown(report, figures):
    """Human-readable report."""
    lines = ['# Damper diagnosis', '',
             f'**Verdict: {report["verdict"]}.** Baseline held-out NRMSE '
             f'{report["baseline"]["heldout_nrmse"]:.4f}, extended '
             f'{report["extended"]["heldout_nrmse"]:.4f}, gain {report["gain"]:.1%}.', '',
             f'Baseline: `{report["baseline"]["model"]}`', '', '## Causes (most important first)',
             '']
    if not report['causes']:
        lines.append('None: no candidate effect improves the held-out error materially and '
                     'consistently.')
    else:
        lines += ['| effect | parameters | held-out NRMSE alone | gain alone | '
                  'MSE loss if dropped |', '|---|---|---|---|---|']
        for c in report['causes']:
            par = ', '.join(f'{k}={v:.4g}' for k, v in c['parameters'].items()) or '-'
            hn = '-' if c['heldout_nrmse'] is None else f'{c["heldout_nrmse"]:.4f}'
            gn = '-' if c['gain'] is None else f'{c["gain"]:.1%}'
            lines.append(f'| `{c["effect"]}` ({c["description"]}) | {par} | {hn} | {gn} | '
                         f'{c["evidence"]["mse_loss_if_dropped_from_extended"]:.1%} |')
    if report['ambiguous']:
        lines += ['', '## Ambiguous', '']
        for p in report['ambiguous']:
            key = '/'.join(p)
            lines.append(f'- `{p[0]}` vs `{p[1]}`: {report["separating_experiments"][key]}')
    if report['untestable']:
        lines += ['', '## Untestable with these data', '',
                  ', '.join(f'`{e}`' for e in report['untestable']) + '.', '',
                  report.get('doe', '')]
    if 'validation' in report:
        v = report['validation']
        lines += ['', '## Validation records', '',
                  f'Baseline NRMSE {v["baseline_nrmse"]:.4f}, extended {v["extended_nrmse"]:.4f}'
                  f', gain {v["gain"]:.1%} on {len(v["records"])} record(s) never used in the '
                  'fit.']
    if report.get('input_warnings'):
        lines += ['', '## Input warnings', '']
        lines += [f'- {w}' for w in report['input_warnings']]
    lines += ['', '## Method', '']
    lines += [f'- {k}: {v}' for k, v in report['method'].items()]
    lines += ['', '## Figures', '']
    lines += [f'![{f}]({f})' for f in figures]
    return '\n'.join(lines) + '\n'


def write(res, records, out_dir, validate=(), elapsed=None, make_plots=True,
          input_warnings=()):
    """Write report.json, report.md, model.json and the figures into ``out_dir``."""
    t0 = time.time()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    report, model = build(res, records, validate, elapsed)
    report['input_warnings'] = list(input_warnings)
    figures = plots(res, records, out_dir, validate) if make_plots else []
    report['figures'] = figures
    (out_dir / 'report.json').write_text(json.dumps(report, indent=2, default=_jsonable) + '\n')
    (out_dir / 'report.md').write_text(markdown(report, figures))
    model_io.save_model(out_dir / 'model.json', model)
    report['_write_s'] = time.time() - t0
    return report, model


def _jsonable(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o).__name__)
