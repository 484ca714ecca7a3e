"""Noise floor of a force record estimated from the data alone (no fitted model).

Repeated inputs (the idea of the Gamma test, Stefansson, Koncar and Jones 1997, and of the
nonparametric noise analysis with periodic excitation, Pintelon and Schoukens 2012 ch. 2): if
the measured force is ``F = g(history of stroke and current) + e``, two samples whose input
histories are the same differ only by noise, ``F_k - F_j = e_k - e_j``, and with independent
noise ``Var(e) = Var(F_k - F_j) / 2``. A rig programme repeats its inputs (harmonic cycles,
repeated current steps): every sample is paired with the earlier sample whose stroke, stroke
rate and current over the last 0.2 s match best (memory, rate and current dynamics are
functions of that history), at least ``t_min`` earlier so that coloured noise (a few ms
correlation) does not look like signal and at most ``t_max`` so that slow drift and heating
stay small. No fitted model enters: the floor is what no model of the inputs can explain.
"""

from dataclasses import dataclass, replace

from numba import njit
import numpy as np


@dataclass(frozen=True)
class NoiseFloor:
    """Estimated noise floor: ``rms`` [N], ``nrmse`` (rms / std of the force), pairs used.

    ``repeats_rms`` [N] is the repeated-input figure itself (default: ``rms``); ``rms`` is
    lower only when a model's held-out error bounded it (:func:`bounded`).
    """

    rms: float
    nrmse: float
    pairs: int
    max_distance: float
    method: str = ('repeats of the input history: every sample paired with the earlier sample '
                   '(50 ms to 12 s before) whose stroke, stroke rate and current over the last '
                   '0.2 s match best; noise RMS = median |force difference| / (0.6745 sqrt 2) '
                   'over the pairs within max_distance (fraction of the input spread)')
    repeats_rms: float = None

    def __post_init__(self):
        """Set ``repeats_rms`` to ``rms`` when not given."""
        if self.repeats_rms is None:
            object.__setattr__(self, 'repeats_rms', self.rms)

    @property
    def bounded(self):
        """True when a model's held-out error lowered the repeated-input figure."""
        return self.rms < self.repeats_rms


def bounded(floor, heldout_rms):
    """Bound a repeated-input floor by a model's held-out RMS error [N].

    With independent noise a model's expected held-out MSE is the noise variance plus its own
    error, so no noise floor lies above it. A repeated-input figure that does is not noise:
    the force keeps a memory longer than the 0.2 s history (a soft series spring's relaxation,
    heating, a drifting load cell between the paired samples). Returns the floor, lowered to
    ``heldout_rms`` and marked ``bounded`` in that case.
    """
    if floor is None or not floor.rms > heldout_rms > 0:
        return floor
    return replace(floor, rms=float(heldout_rms), nrmse=floor.nrmse * heldout_rms / floor.rms,
                   repeats_rms=floor.rms,
                   method=floor.method + "; the repeats gave a higher figure than the model's "
                   'held-out error, which bounds any noise floor: lowered to it (the force keeps '
                   'a memory longer than the 0.2 s history)')


def _best_repeats(x, v, i, rate, t_min, t_max, window):
    """For every sample, the earlier sample whose input history matches best.

    ``d_k(L)^2`` = mean over the last ``window`` of the squared differences of ``x``, ``v`` and
    ``i`` at ``k`` and ``k - L``, each over its spread, for every lag ``L`` in ``[t_min,
    t_max]``; returns ``(best lag, best d^2)`` per sample.
    """
    n = x.size
    sx = np.std(x) or 1.0
    sv = np.std(v) or 1.0
    si = np.std(i) or 1.0
    w = max(1, int(round(window * rate)))
    lo = max(1, int(np.ceil(t_min * rate)))
    hi = min(n - w - 1, int(t_max * rate))
    return _scan(np.ascontiguousarray(x, dtype=float), np.ascontiguousarray(v, dtype=float),
                 np.ascontiguousarray(i, dtype=float), float(sx), float(sv), float(si), w, lo,
                 hi)


@njit(cache=True, nogil=True)
def _scan(x, v, i, sx, sv, si, w, lo, hi):
    """Scan of ``_best_repeats``: one compiled pass per lag, running sums, without the GIL.

    The same sums in the same order as numpy's ``cumsum`` of the squared differences (it
    held the GIL the diagnosis's threaded fits share for half a second on a 60 s record).
    """
    n = x.size
    best = np.full(n, np.inf)
    lag = np.zeros(n, dtype=np.int64)
    c = np.empty(n + 1)
    c[0] = 0.0
    for L in range(lo, hi + 1):
        m = n - L
        for j in range(m):
            a = (x[L + j] - x[j]) / sx
            b = (v[L + j] - v[j]) / sv
            e = (i[L + j] - i[j]) / si
            c[j + 1] = c[j] + (a * a + b * b + e * e)
        for j in range(m - w + 1):
            d = (c[j + w] - c[j]) / w  # window ending at sample L + w - 1 + j
            k = L + w - 1 + j
            if d < best[k]:
                best[k] = d
                lag[k] = L
    return lag, best


def _refine(r, kf, lf, q, window):
    """At the full rate, move each coarse lag by up to ``q`` samples to the best match.

    Returns ``(d^2, sample, lag)`` at the record's own rate (the coarse search runs on thinned
    signals, whose repeats are off by up to half a thinned sample).
    """
    x, v, i = r.displacement, r.velocity, r.i_in
    sc = [np.std(a) or 1.0 for a in (x, v, i)]
    w = max(1, int(round(window / r.dt)))
    step = max(1, w // 20)
    offs = np.arange(-w + 1, 1, step)
    best = np.full(kf.size, np.inf)
    lag = lf.copy()
    for j in range(-q, q + 1):
        L = lf + j
        a = kf[:, None] + offs[None, :]
        b = a - L[:, None]
        ok = (b.min(axis=1) >= 0) & (L > 0)
        a = np.clip(a, 0, r.n - 1)
        b = np.clip(b, 0, r.n - 1)
        d = sum(np.mean(((s[a] - s[b]) / c) ** 2, axis=1) for s, c in zip((x, v, i), sc))
        d = np.where(ok, d, np.inf)
        better = d < best
        best[better] = d[better]
        lag[better] = L[better]
    keep = np.isfinite(best)
    return best[keep], kf[keep], lag[keep]


def estimate(records, rate=250.0, t_min=0.05, t_max=12.0, window=0.2,
             d_ladder=(0.002, 0.005, 0.01, 0.02, 0.05), min_pairs=300):
    """Estimate the noise floor of records of one damper (see the module docstring).

    Every sample is paired with the earlier sample (``t_min`` to ``t_max`` before it) whose
    stroke and current over the last ``window`` s match best. The tightest history distance in
    ``d_ladder`` that leaves ``min_pairs`` pairs is used, and the noise RMS is the robust
    ``median |F_k - F_k-L| / (0.6745 sqrt 2)`` (exact for Gaussian noise; a few pairs that are no
    true repeats cannot move it). Returns ``None`` when even the loosest distance leaves too few
    pairs: the inputs never repeat, and the floor is not estimable from these data.
    """
    d2s, dfs, fs = [], [], []
    for r in records:
        q = max(1, int(round(1.0 / (r.dt * rate))))
        x = r.displacement[::q]
        i = r.i_in[::q]
        fs.append(r.force)
        v = r.velocity[::q]
        lag, d2 = _best_repeats(x, v, i, 1.0 / (r.dt * q), t_min, t_max, window)
        k = np.nonzero(np.isfinite(d2) & (d2 <= (4 * d_ladder[-1]) ** 2))[0]
        d2, kf, lf = _refine(r, k * q, lag[k] * q, q, window)
        mask = getattr(r, 'mask', None)
        if mask is not None:
            m = np.asarray(mask, dtype=bool)
            ok = m[kf] & m[kf - lf]
            d2, kf, lf = d2[ok], kf[ok], lf[ok]
        d2s.append(d2)
        dfs.append(r.force[kf] - r.force[kf - lf])
    d2 = np.concatenate(d2s)
    df = np.concatenate(dfs)
    std = float(np.std(np.concatenate(fs)))
    if std <= 0:
        return None
    for d in d_ladder:
        sel = d2 <= d * d
        if np.count_nonzero(sel) >= min_pairs:
            rms = float(np.median(np.abs(df[sel])) / (0.6745 * np.sqrt(2.0)))
            return NoiseFloor(rms=rms, nrmse=rms / std, pairs=int(np.count_nonzero(sel)),
                              max_distance=float(d))
    return None
