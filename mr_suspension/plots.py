"""Matplotlib figures for simulation results (Agg backend, PNG files)."""

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402  (backend must be chosen first)
import numpy as np  # noqa: E402


def time_histories(results, path, title=''):
    """Plot body acceleration, stroke, dynamic tyre load and currents of labelled runs.

    ``results`` maps a label to a :class:`~mr_suspension.sim.simulator.SimResult`.
    """
    fig, axes = plt.subplots(4, 1, figsize=(9, 9), sharex=True)
    for label, res in results.items():
        t = res.t
        axes[0].plot(t, res.a_s, label=label, lw=0.8)
        axes[1].plot(t, 1e3 * res.stroke, label=label, lw=0.8)
        axes[2].plot(t, res.f_t - res.static_tyre_load, label=label, lw=0.8)
        axes[3].plot(t, res.i_cmd, lw=0.6, ls=':', label=f'{label} command')
        axes[3].plot(t, res.i_field, lw=0.8, label=f'{label} field')
    axes[0].set_ylabel('body acc. [m/s²]')
    axes[1].set_ylabel('stroke [mm]')
    axes[2].set_ylabel('dyn. tyre load [N]')
    axes[3].set_ylabel('current [A]')
    axes[3].set_xlabel('time [s]')
    for ax in axes:
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc='upper right', fontsize=8)
    axes[3].legend(loc='upper right', fontsize=7, ncol=2)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def damper_loops(results, path):
    """Plot force-velocity and force-displacement loops of the damper in each run."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for label, res in results.items():
        axes[0].plot(res.stroke_rate, res.f_d, lw=0.5, label=label)
        axes[1].plot(1e3 * res.stroke, res.f_d, lw=0.5, label=label)
    axes[0].set_xlabel('stroke rate [m/s]')
    axes[1].set_xlabel('stroke [mm]')
    for ax in axes:
        ax.set_ylabel('damper force [N]')
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def frequency_gains(freqs, gains, path, ylabels):
    """Plot gain-versus-frequency families: ``gains[label][quantity] -> array`` (seed 001)."""
    quantities = list(ylabels)
    fig, axes = plt.subplots(len(quantities), 1, figsize=(8, 2.6 * len(quantities)),
                             sharex=True)
    axes = np.atleast_1d(axes)
    for label, g in gains.items():
        for ax, q in zip(axes, quantities):
            ax.semilogx(freqs, g[q], label=label)
    for ax, q in zip(axes, quantities):
        ax.set_ylabel(ylabels[q])
        ax.grid(True, which='both', alpha=0.3)
    axes[-1].set_xlabel('frequency [Hz]')
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
