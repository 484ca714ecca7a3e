"""Forward validation: data kept back from every fit and selection, after the data fitted.

Outer blocks interleave with the training blocks, so they share a run's slow changes
(heating, wear, drift) and flatter a model that will be asked about the *next* stretch of
data. Forward validation keeps back what comes after: the final ``FORWARD_SHARE`` of every
record of at least ``FORWARD_MIN_S`` seconds, or, for a set of ``WHOLE_MIN`` records or more,
``WHOLE_SHARE`` of its records, whole (``whole_records``: unseen tests of the programme). The
report then compares the two figures with their block-to-block uncertainty (``compare``) and
takes the more pessimistic one where they differ by more than it.
"""

from dataclasses import dataclass

import numpy as np

FORWARD_SHARE = 0.2   # final share of a long record kept back
FORWARD_MIN_S = 30.0  # shorter records keep no final segment (>= 6 s forward, 24 s fitted)
WHOLE_MIN = 5         # a set of this many records keeps back whole records
WHOLE_SHARE = 0.2     # share of a set's records kept back (``whole_records``)
N_BLOCKS = 6          # blocks of the forward data for its uncertainty
SE_FACTOR = 2.0       # figures differ when apart by more than 2 combined standard errors


@dataclass(frozen=True)
class Split:
    """Records to fit on, and kept-back parts: ``held`` pairs ``(record, first sample)``.

    A kept-back part is scored from its first sample on, the model simulated over the whole
    record so that its states (loop, current) arrive at the segment with their history.
    """

    train: tuple
    held: tuple
    how: str

    @property
    def seconds(self):
        """Kept-back time [s]."""
        return float(sum((r.n - k) * r.dt for r, k in self.held))


@dataclass(frozen=True)
class Score:
    """NRMSE of a prediction on some samples, its standard error from blocks, samples used."""

    nrmse: float
    se: float
    samples: int
    std: float

    @property
    def mse(self):
        """Mean squared error [N^2]."""
        return float((self.nrmse * self.std) ** 2)


def _extent(r):
    """Input extent of a record's usable samples: p99 ``|v|``, max ``|i|``, stroke range."""
    m = np.asarray(r.mask, dtype=bool)
    if not m.any():
        return None
    v = np.abs(np.asarray(r.velocity, dtype=float)[m])
    x = np.asarray(r.displacement, dtype=float)[m]
    return (float(np.percentile(v, 99)), float(np.max(np.abs(np.asarray(r.i_in)[m]))),
            float(np.min(x)), float(np.max(x)))


def _covered(e, others, slack=0.05):
    """Tell whether the extents ``others`` together cover ``e`` (``slack`` of each range)."""
    if e is None or not others:
        return False
    v = max(o[0] for o in others)
    i = max(o[1] for o in others)
    lo, hi = min(o[2] for o in others), max(o[3] for o in others)
    pad = slack * (hi - lo)
    return (e[0] <= (1 + slack) * v and e[1] <= (1 + slack) * i + 1e-9
            and e[2] >= lo - pad and e[3] <= hi + pad)


def whole_records(records, share=WHOLE_SHARE):
    """Return the indices of the records a set keeps back: ``share`` of them, inside the rest.

    Records are tried in a fixed pseudo-random order (``numpy.random.default_rng`` seeded
    with the number of records: the same on every machine, and no alias with a programme's
    own period, as every k-th record would be: a programme of five currents per test would
    keep back the highest current of every test). A record is kept back only when the
    records still fitted cover its speed, current and stroke: a kept-back record measures
    prediction, not extrapolation (which ``domain`` flags on its own).
    """
    n = len(records)
    want = max(1, int(round(share * n)))
    ext = [_extent(r) for r in records]
    held = []
    for k in np.random.default_rng(n).permutation(n):
        rest = [ext[j] for j in range(n) if j != k and j not in held and ext[j] is not None]
        if _covered(ext[k], rest):
            held.append(int(k))
            if len(held) == want:
                break
    return sorted(held)


def split(records, window):
    """Split ``records`` into fitted and kept-back parts (see the module docstring).

    ``window(record, start, stop)`` cuts a record (``data.window``). Returns a ``Split``.
    """
    records = list(records)
    if len(records) >= WHOLE_MIN:
        held = whole_records(records)
        if held:
            return Split(train=tuple(r for k, r in enumerate(records) if k not in held),
                         held=tuple((records[k], 0) for k in held),
                         how=f'{len(held)} whole records of {len(records)} kept back')
    train, held = [], []
    for r in records:
        if r.duration >= FORWARD_MIN_S:
            cut = int(round(r.n * (1.0 - FORWARD_SHARE)))
            train.append(window(r, 0, cut, name=r.name))
            held.append((r, cut))
        else:
            train.append(r)
    if not held:
        return Split(tuple(train), (), 'none')
    return Split(tuple(train), tuple(held),
                 f'final {FORWARD_SHARE:.0%} of {len(held)} record(s) of at least '
                 f'{FORWARD_MIN_S:g} s kept back')


def block_score(errors, forces, n_blocks=None):
    """Score from error arrays, one per contiguous stretch (a block each unless ``n_blocks``).

    ``n_blocks``: the stretches are joined and cut into that many contiguous blocks instead.
    The standard error of the MSE is the blocks' spread over the root of their number; the
    NRMSE's follows by the delta method, ``se(sqrt m) = se(m) / (2 sqrt m)``.
    """
    errors = [np.asarray(e, dtype=float) for e in errors if np.size(e)]
    if not errors:
        return None
    f = np.concatenate([np.asarray(x, dtype=float) for x in forces if np.size(x)])
    if n_blocks:
        errors = [b for b in np.array_split(np.concatenate(errors), n_blocks) if b.size]
    mses = np.array([np.mean(e ** 2) for e in errors])
    n = np.array([e.size for e in errors])
    mse = float(np.sum(mses * n) / n.sum())
    std = float(np.std(f)) or 1.0
    se_mse = float(np.std(mses, ddof=1) / np.sqrt(mses.size)) if mses.size > 1 else mse
    nrmse = np.sqrt(mse) / std
    se = se_mse / (2.0 * np.sqrt(mse) * std) if mse > 0 else 0.0
    return Score(nrmse=float(nrmse), se=float(se), samples=int(n.sum()), std=std)


def compare(blocks, fwd):
    """Which figure heads the report: ``'forward'``, ``'outer'`` or ``'pooled'``.

    The more pessimistic one where the two differ by more than ``SE_FACTOR`` combined
    standard errors; their samples pooled where they agree.
    """
    if fwd is None:
        return 'outer'
    if blocks is None:
        return 'forward'
    gap = fwd.nrmse - blocks.nrmse
    unc = SE_FACTOR * float(np.hypot(fwd.se, blocks.se))
    if gap > unc:
        return 'forward'
    if -gap > unc:
        return 'outer'
    return 'pooled'


def pooled(a, b):
    """NRMSE over the samples of two scores (each normalised by its own force spread)."""
    n = a.samples + b.samples
    mse = (a.mse * a.samples + b.mse * b.samples) / n
    std = float(np.sqrt((a.std ** 2 * a.samples + b.std ** 2 * b.samples) / n))
    return float(np.sqrt(mse) / std)


def drift(segments, n_windows=12):
    """How the prediction's force scale moves over a run, and which channel follows it.

    ``segments``: ``(time, force, prediction, mask, temperature or None)`` per record, in
    run order. Per window of equal length the force scale error is
    ``s = <e, f_hat> / <f_hat, f_hat>`` (``e = f - f_hat``: +0.05 means the measured force is
    5 % above the prediction). Returns ``{'scale_change', 'by_time_r', 'by_temperature_r',
    'channel'}``: the scale's range over the run and its correlation with time and
    temperature; ``channel`` names the one with ``|r| >= 0.7``, the larger, else None.
    """
    s, tm, temp = [], [], []
    t0 = 0.0
    for t, f, fh, m, th in segments:
        for idx in np.array_split(np.arange(t.size), n_windows):
            idx = idx[m[idx]]
            den = float(np.dot(fh[idx], fh[idx]))
            if idx.size < 10 or not den > 0:
                continue
            s.append(float(np.dot(f[idx] - fh[idx], fh[idx]) / den))
            tm.append(t0 + float(np.mean(t[idx])))
            temp.append(float(np.mean(th[idx])) if th is not None else np.nan)
        t0 += float(t[-1]) if t.size else 0.0
    if len(s) < 4:
        return None
    s, tm, temp = np.array(s), np.array(tm), np.array(temp)

    def r(q):
        ok = np.isfinite(q)
        if ok.sum() < 4 or np.std(q[ok]) == 0 or np.std(s[ok]) == 0:
            return None
        return float(np.corrcoef(s[ok], q[ok])[0, 1])

    out = {'scale_change': float(s.max() - s.min()), 'by_time_r': r(tm),
           'by_temperature_r': r(temp)}
    cands = [(abs(v), k) for k, v in (('time', out['by_time_r']),
                                      ('temperature', out['by_temperature_r']))
             if v is not None and abs(v) >= 0.7]
    out['channel'] = max(cands)[1] if cands else None
    return out
