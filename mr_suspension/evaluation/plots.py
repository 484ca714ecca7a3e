"""Evaluation figures (matplotlib, Agg backend): time histories, frequency responses, trade-off.

Frequency responses come from :func:`mr_suspension.sim.frequency.sine_dwell_gains` (seed 001
Figs 7-10: body acceleration, body amplitude, working space and normalised tyre force gains).
"""

import matplotlib
import numpy as np

from mr_suspension.sim.frequency import RESPONSES

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402, I100  (backend must be chosen first)

MARKERS = ('o', 's', '^', 'v', 'D', 'P', 'X', '*', '<', '>', 'h', 'p')


def _save(fig, path, title=''):
    """Add the title, lay out, write the PNG and close the figure."""
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _comfort_axes(axes):
    """Label the comfort axis of trade-off panels and add the legend."""
    for ax in axes:
        ax.set_ylabel('Wk body acceleration RMS [m/s^2]')
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=7, ncol=2)


def response_figure(families, path, title=''):
    """Four-panel frequency-response figure; ``families``: ``{label: (freqs, responses)}``.

    ``responses`` is a dict keyed like :data:`RESPONSES`; a label starting with ``'~'`` is
    drawn dashed (e.g. the linear closed form next to the simulated curve).
    """
    fig, axes = plt.subplots(2, 2, figsize=(10, 7))
    solid = [k for k in families if not k.startswith('~')]
    colours = plt.cm.tab20(np.linspace(0.0, 1.0, max(len(solid), 1), endpoint=False))
    for ax, (key, ylabel) in zip(axes.ravel(), RESPONSES):
        for k, (label, (freqs, resp)) in enumerate(families.items()):
            style = '--' if label.startswith('~') else '-'
            colour = colours[k % len(colours)] if len(solid) > 10 else None
            ax.semilogy(freqs, resp[key], style, color=colour, label=label.lstrip('~'))
        ax.set_xlabel('frequency [Hz]')
        ax.set_ylabel(ylabel)
        ax.grid(True, which='both', alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    _save(fig, path, title)


def time_histories(results, path, title='', t_max=None):
    """Body displacement and acceleration, stroke and current command of several runs.

    ``results``: ``{label: SimResult}``.
    """
    fig, axes = plt.subplots(4, 1, figsize=(9, 9), sharex=True)
    chans = (('z_s', 'z_s [mm]', 1e3), ('a_s', 'a_s [m/s^2]', 1.0), ('stroke', 'x [mm]', 1e3),
             ('i_cmd', 'i_cmd [A]', 1.0))
    for label, res in results.items():
        t = res.t
        sel = t <= t_max if t_max else slice(None)
        for ax, (ch, _, scale) in zip(axes, chans):
            ax.plot(t[sel], getattr(res, ch)[sel] * scale, lw=0.9, label=label)
    for ax, (_, ylabel, _) in zip(axes, chans):
        ax.set_ylabel(ylabel)
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel('time [s]')
    axes[0].legend(fontsize=7, ncol=3)
    _save(fig, path, title)


def tradeoff(rows, path, passive=None, scenario=None, title=''):
    """Comfort (Wk RMS) against working space RMS and dynamic tyre load RMS.

    ``rows``: metric rows of the laws; ``passive``: optional dict of metric arrays of a
    passive sweep (drawn as the passive trade-off curve) with a ``label`` entry.
    """
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    sel = [r for r in rows if scenario is None or r['scenario'] == scenario]
    for ax, key, xlabel, scale in ((axes[0], 'working_space_rms', 'working space RMS [mm]',
                                    1e3),
                                   (axes[1], 'tyre_load_rms', 'dynamic tyre load RMS [N]', 1.0)):
        if passive is not None:
            ax.plot(np.asarray(passive[key]) * scale, passive['body_acc_wk_rms'], 'k.-',
                    lw=0.8, label=passive.get('label', 'passive'))
        for k, r in enumerate(sel):
            ax.plot(r[key] * scale, r['body_acc_wk_rms'], MARKERS[k % len(MARKERS)],
                    label=r['law'])
        ax.set_xlabel(xlabel)
    _comfort_axes(axes)
    _save(fig, path, title)


def tradeoff_families(families, path, passive, title=''):
    """Comfort against working space and tyre load for gain sweeps of each law.

    ``families``: ``{label: metric arrays}`` (one point per gain value, e.g. from
    :func:`~mr_suspension.evaluation.runner.tune`); ``passive``: the constant-current family.
    """
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    colours = plt.cm.tab10(np.linspace(0.0, 1.0, 10, endpoint=False))
    for ax, key, xlabel, scale in ((axes[0], 'working_space_rms', 'working space RMS [mm]',
                                    1e3),
                                   (axes[1], 'tyre_load_rms', 'dynamic tyre load RMS [N]', 1.0)):
        ax.plot(np.asarray(passive[key]) * scale, passive['body_acc_wk_rms'], 'k.-', lw=1.2,
                label=passive.get('label', 'passive'))
        for k, (label, met) in enumerate(families.items()):
            ax.plot(np.asarray(met[key]) * scale, met['body_acc_wk_rms'],
                    MARKERS[k % len(MARKERS)] + '-', color=colours[k % 10], lw=0.8, ms=4,
                    label=label)
        ax.set_xlabel(xlabel)
    _comfort_axes(axes)
    _save(fig, path, title)


def lines(xs, series, path, xlabel, ylabel, title='', logx=False):
    """Draw a simple line figure: ``series`` is ``{label: y}`` over ``xs``."""
    fig, ax = plt.subplots(figsize=(7, 4.5))
    colours = plt.cm.tab10(np.linspace(0.0, 1.0, 10, endpoint=False))
    for k, (label, ys) in enumerate(series.items()):
        ax.plot(xs, ys, MARKERS[k % len(MARKERS)] + '-', color=colours[k % 10], label=label)
    if logx:
        ax.set_xscale('symlog', linthresh=0.5)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    if title:
        ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _law_colours(labels):
    colours = plt.cm.tab10(np.linspace(0.0, 1.0, 10, endpoint=False))
    return {lab: colours[k % 10] for k, lab in enumerate(labels)}


def carpet(study, path, title=''):
    """Carpet plot of a tuning study: comfort against road holding, working space as limit.

    Panel 1: road-set means normalised by the softest passive setting (the tuning objective's
    terms); one panel per road in SI units. The passive family (constant currents) is coloured
    by its working space relative to the limit (hollow: over the limit); each law at its
    default gains (small hollow marker), tuned (large marker, arrow from the default) and the
    non-dominated feasible candidates the optimiser visited (thin line).
    """
    from mr_suspension.evaluation.tune import pareto_front
    obj = study['objective_obj']
    roads = study['roads']
    sweep = study['passive']
    tuned = study['tuned']
    labels = list(study['defaults']) + [t['label'] for t in tuned
                                        if t['label'] not in study['defaults']]
    colour = _law_colours(labels)
    n = 1 + len(roads)
    cols = 2 if n > 1 else 1
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(6.2 * cols, 4.8 * rows), squeeze=False,
                             layout='constrained')
    axes = axes.ravel()
    ratio = np.max(np.asarray(sweep['working_space_rms']) / obj.limit, axis=1)
    norm = matplotlib.colors.Normalize(vmin=min(0.5, ratio.min()), vmax=max(1.5, ratio.max()))
    cmap = plt.cm.viridis

    def xy(met, panel):
        if panel == 0:
            return obj.road_holding(met), obj.comfort(met)
        return (np.asarray(met['tyre_load_rms'])[..., panel - 1],
                np.asarray(met['body_acc_wk_rms'])[..., panel - 1])

    for panel in range(n):
        ax = axes[panel]
        x, y = xy(sweep, panel)
        # View: the laws, the soft and the best passive settings (the stiff tail runs off).
        px = [x[0]] + [xy({k: np.asarray(v) for k, v in m.items()}, panel)[0]
                       for m in list(study['defaults'].values())
                       + [t['tuned']['metrics'] for t in tuned]]
        py = [y[0]] + [xy({k: np.asarray(v) for k, v in m.items()}, panel)[1]
                       for m in list(study['defaults'].values())
                       + [t['tuned']['metrics'] for t in tuned]]
        for vals, setter in ((px, ax.set_xlim), (py, ax.set_ylim)):
            lo, hi = float(np.min(vals)), float(np.max(vals))
            pad = 0.15 * (hi - lo) + 1e-9
            setter(lo - pad, hi + pad)
        ax.plot(x, y, '-', color='0.6', lw=0.8, zorder=1)
        ok = ratio <= 1.0 + 1e-9
        ax.scatter(x[ok], y[ok], c=ratio[ok], cmap=cmap, norm=norm, s=14, zorder=2,
                   label=f'passive, 0..{sweep["current"][-1]:.2f} A')
        ax.scatter(x[~ok], y[~ok], facecolors='none', edgecolors=cmap(norm(ratio[~ok])),
                   s=14, zorder=2, label='passive over the limit')
        for target in (0.0, 0.05, 0.1, 0.15, 0.2, 0.3, 0.5, 1.0):
            k = int(np.argmin(np.abs(sweep['current'] - target)))
            if abs(sweep['current'][k] - target) < 0.01:
                ax.annotate(f'{sweep["current"][k]:.2f} A', (x[k], y[k]), fontsize=6,
                            xytext=(4, -9), textcoords='offset points', color='0.3',
                            annotation_clip=True)
        best = study.get('best_passive')
        if best is not None:
            bx, by = xy({k: np.asarray(v) for k, v in best['metrics'].items()}, panel)
            ax.plot(bx, by, 'k*', ms=11, zorder=4,
                    label=f'best passive at the limit ({best["current"]:.2f} A)')
        for k, (law, met) in enumerate(study['defaults'].items()):
            dx, dy = xy({kk: np.asarray(v) for kk, v in met.items()}, panel)
            ax.plot(dx, dy, MARKERS[k % len(MARKERS)], mfc='none', color=colour[law], ms=6,
                    zorder=3, label=f'{law} (default)' if panel == 0 else None)
        for t in tuned:
            c = colour[t['label']]
            hist = {key: np.asarray(v) for key, v in t['history'].items() if key != 'gains'}
            feas = obj.violation(hist) <= 1e-9
            if np.any(feas):
                hx, hy = xy({key: v[feas] for key, v in hist.items()}, panel)
                front = pareto_front(hy, hx)
                ax.plot(hx[front], hy[front], '-', color=c, lw=0.8, alpha=0.7, zorder=2)
            tx, ty = xy({key: np.asarray(v) for key, v in t['tuned']['metrics'].items()},
                        panel)
            dx, dy = xy({key: np.asarray(v) for key, v in t['default']['metrics'].items()},
                        panel)
            ax.annotate('', (tx, ty), (dx, dy),
                        arrowprops={'arrowstyle': '->', 'color': c, 'lw': 0.8})
            ax.plot(tx, ty, 'o', color=c, ms=9, mec='k', zorder=5,
                    label=f'{t["label"]} (tuned)')
        if panel == 0:
            ax.set_xlabel('dynamic tyre load RMS / softest passive (road-set mean)')
            ax.set_ylabel('Wk body acc. RMS / softest passive (road-set mean)')
            ax.set_title('all roads, normalised')
        else:
            ax.set_xlabel('dynamic tyre load RMS [N]')
            ax.set_ylabel('Wk body acceleration RMS [m/s^2]')
            ax.set_title(f'{roads[panel - 1]}: working-space limit '
                         f'{1e3 * obj.limit[panel - 1]:.2f} mm RMS')
        ax.grid(True, alpha=0.3)
    for ax in axes[n:]:
        ax.axis('off')
    axes[0].legend(fontsize=6, ncol=2, loc='upper right')
    sm = plt.cm.ScalarMappable(norm=norm, cmap=cmap)
    fig.colorbar(sm, ax=list(axes[:n]), shrink=0.6,
                 label='passive: working space RMS / limit (max over roads)')
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def transmissibility(curves, path, title=''):
    """Body-acceleration and tyre-load transmissibility; ``curves``: ``{label: (f, Ha, Ht)}``."""
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    for k, (label, (f, ha, ht)) in enumerate(curves.items()):
        style = '--' if label.startswith('passive') else '-'
        axes[0].loglog(f, ha, style, lw=1.0, label=label)
        axes[1].loglog(f, ht, style, lw=1.0, label=label)
    axes[0].set_ylabel('|a_s / z_r| [1/s^2]')
    axes[1].set_ylabel('|dF_t / z_r| [N/m]')
    for ax in axes:
        ax.set_xlabel('frequency [Hz]')
        ax.grid(True, which='both', alpha=0.3)
    axes[0].legend(fontsize=7)
    _save(fig, path, title)
