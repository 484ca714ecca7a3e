"""Evaluation figures (matplotlib, Agg backend): time histories, frequency responses, trade-off.

Frequency responses come from :func:`mr_suspension.core.frequency.sine_dwell_gains` (seed 001
Figs 7-10: body acceleration, body amplitude, working space and normalised tyre force gains).
"""

import matplotlib
import numpy as np

from mr_suspension.core.frequency import RESPONSES

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
