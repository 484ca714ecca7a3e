"""Learned black-box reference of the damper force: how much of it the inputs predict at all.

Beside the physical model the diagnosis fits gradient-boosted trees (``scikit-learn``'s
``HistGradientBoostingRegressor``) to the measured force from the same inputs (displacement,
velocity, input current or command) and their recent history, trained on the samples the
physics is trained on and scored on the same held-out samples. A reference clearly better
than the physics says that part of the force is predictable but not modelled; one no better
says the rest is noise or lies beyond the reference's reach: history longer than ``LAG_MAX``
(heating, slow drift) and input ranges absent from the training samples (trees do not
extrapolate). It is evidence, never the delivered model. It learns whatever ``force`` the
records carry: the diagnosis passes the physical model's residual (``diagnose``).

Lags are physical times (``LAG_MIN`` to ``LAG_MAX``, geometric), rounded to whole samples of
each record's ``dt`` (at least one), so records at different rates get comparable features.
"""

from dataclasses import dataclass
import math

import numpy as np
from sklearn.ensemble import HistGradientBoostingRegressor
from threadpoolctl import threadpool_limits

LAG_MIN = 1e-3   # [s] shortest lag: current and force dynamics of a few ms
LAG_MAX = 0.05   # [s] longest lag: pre-yield loops, current lags of up to tens of ms
N_LAGS = 6
ACCEL_LAGS = (0, 2)  # velocity differences over the shortest and a middle lag
MIN_TRAIN = 500      # fewest training samples
MAX_ROWS = 200_000   # above this the training rows are thinned (every k-th)
CHANNELS = ('displacement', 'velocity', 'input')
PARAMS = {'loss': 'squared_error', 'learning_rate': 0.1, 'max_iter': 250, 'max_leaf_nodes': 31,
          'min_samples_leaf': 40, 'l2_regularization': 1.0, 'max_bins': 255,
          'early_stopping': False, 'random_state': 0}


def lag_times(n_lags=N_LAGS, lag_min=LAG_MIN, lag_max=LAG_MAX):
    """Nominal lags [s]: ``n_lags`` geometrically spaced from ``lag_min`` to ``lag_max``."""
    return tuple(float(t) for t in np.geomspace(lag_min, lag_max, n_lags))


def lag_samples(dt, lags=None):
    """Lags in samples of ``dt`` [s]: each nominal lag rounded, at least one sample."""
    lags = lag_times() if lags is None else lags
    return tuple(max(1, int(round(t / dt))) for t in lags)


def feature_names(lags=None):
    """Column names of :func:`features` (nominal lags in ms)."""
    lags = lag_times() if lags is None else lags
    names = list(CHANNELS)
    for t in lags:
        names += [f'{c}@-{1e3 * t:.3g}ms' for c in CHANNELS]
    names += [f'accel@{1e3 * lags[j]:.3g}ms' for j in ACCEL_LAGS]
    return tuple(names)


def _past(a, k):
    """Return ``a`` delayed by ``k`` samples; the first ``k`` repeat the first sample."""
    out = np.empty_like(a)
    out[k:] = a[:-k]
    out[:k] = a[0]
    return out


def features(record, lags=None):
    """Feature matrix (n, p) of a record; columns as :func:`feature_names`.

    Displacement [m], velocity [m/s] and input (``i_in``) now and ``lag_samples(dt)`` samples
    before, then velocity differences over the shortest and a middle lag divided by the lag's
    time [m/s^2] (an acceleration proxy in physical units). Non-finite inputs stay non-finite
    in every feature that reads them.
    """
    lags = lag_times() if lags is None else lags
    if len(lags) <= max(ACCEL_LAGS):
        raise ValueError(f'reference: need at least {max(ACCEL_LAGS) + 1} lags, got {len(lags)}')
    chans = [np.asarray(getattr(record, 'i_in' if c == 'input' else c), dtype=float)
             for c in CHANNELS]
    ks = lag_samples(record.dt, lags)
    cols = list(chans)
    for k in ks:
        cols += [_past(a, k) for a in chans]
    v = chans[1]
    cols += [(v - _past(v, ks[j])) / (ks[j] * record.dt) for j in ACCEL_LAGS]
    return np.column_stack(cols)


@dataclass(frozen=True)
class Reference:
    """A fitted reference: ``estimator``, nominal ``lags`` [s], column ``names``, ``n_train``."""

    estimator: HistGradientBoostingRegressor
    lags: tuple
    names: tuple
    n_train: int

    def predict(self, record, rows=None):
        """Force [N] for every sample of ``record``, or only at ``rows`` (NaN elsewhere).

        Non-finite features go the NaN way. One thread: the prediction is a parallel region
        per tree, and with the cores busy (the fits run on threads) OpenMP's spinning made
        it 30x slower than one thread (12,000 rows, 250 trees: 2.9 s against 0.09 s).
        """
        x = features(record, self.lags)
        x[~np.isfinite(x)] = np.nan
        rows = np.ones(x.shape[0], dtype=bool) if rows is None else np.asarray(rows)
        out = np.full(x.shape[0], np.nan)
        if np.any(rows):
            with threadpool_limits(1):
                out[rows] = self.estimator.predict(x[rows])
        return out


def _stack(records, masks, lags):
    xs, ys = [], []
    for r, m in zip(records, masks):
        m = np.asarray(m, dtype=bool)
        if m.shape != (r.n,):
            raise ValueError(f'reference: {r.name}: mask has shape {m.shape}, record has '
                             f'{r.n} samples')
        x = features(r, lags)
        y = np.asarray(r.force, dtype=float)
        keep = m & np.asarray(r.mask, dtype=bool)
        xs.append(x[keep])
        ys.append(y[keep])
    return np.concatenate(xs), np.concatenate(ys)


def fit_reference(records, train_masks, lags=None):
    """Fit the reference on the samples ``train_masks[j] & records[j].mask``.

    Hyper-parameters (``PARAMS``), chosen once from the data's scale, not tuned to a record:
    a learning rate of 0.1 with 250 trees is the usual converged regime of boosting on
    smooth targets (the fit is a sum of many small corrections, each shrunk), fixed in
    number (no early stopping) so no random validation split enters; 31 leaves (the
    default) let a tree split velocity, input and their lags jointly (about 5 levels:
    yield x current x lag interactions). ``min_samples_leaf`` 40 makes every leaf an average
    of 40 or more samples (40 ms at 1 kHz), so one tree's leaf carries at most sigma/sqrt(40)
    (16 %) of the noise and no tree can follow single noise samples; ``l2_regularization`` 1
    (a sample's weight; the squared loss's hessian is one per sample) shrinks only leaves
    of few samples. 255 quantile bins resolve the steep yield near zero velocity, where the
    samples are dense. Above ``MAX_ROWS`` rows every k-th is kept (deterministic, time spread).
    The held-out error is flat around this choice (100-500 trees, leaves of 20-40 samples:
    within 5 % on drawn truth records); what limits it is the training data's coverage.

    Rows whose features or force are not finite are left out (a NaN sample also spoils the
    rows that read it at a lag, up to ``LAG_MAX`` later). Raises ``ValueError`` when fewer
    than ``MIN_TRAIN`` rows are left or ``lags`` has fewer than 3 entries.

    One thread, for speed: the fit opens a parallel region per node, and on shared cores
    OpenMP's spinning at their barriers made it up to 80x slower (42,000 rows, 23 features,
    2 busy cores: 126 s against 1.6 s). Not for determinism: the estimator's parallel loops
    run over features (each histogram summed in sample order), samples or leaves, with
    stable partitions, and reduce nothing across threads, so the thread count does not
    change the result.
    """
    records = list(records)
    masks = list(train_masks)
    if not records or len(records) != len(masks):
        raise ValueError(f'reference: need one train mask per record, got {len(records)} '
                         f'records and {len(masks)} masks')
    lags = lag_times() if lags is None else tuple(float(t) for t in lags)
    x, y = _stack(records, masks, lags)
    finite = np.isfinite(x).all(axis=1) & np.isfinite(y)
    n_bad = int(np.count_nonzero(~finite))
    x, y = x[finite], y[finite]
    if y.size < MIN_TRAIN:
        raise ValueError(f'reference: {y.size} usable training samples (train mask and record '
                         f'mask, {n_bad} more with non-finite features or force); need at '
                         f'least {MIN_TRAIN}')
    step = math.ceil(y.size / MAX_ROWS)
    x, y = x[::step], y[::step]
    est = HistGradientBoostingRegressor(**PARAMS)
    with threadpool_limits(1):
        est.fit(x, y)
    return Reference(estimator=est, lags=lags, names=feature_names(lags), n_train=int(y.size))


def score_blocks(pred, records, masks, n_blocks):
    """Mean squared error [N^2] per block of the scored samples, shape (records, n_blocks).

    ``pred``: a :class:`Reference` or one prediction array per record (the physics' too,
    so both are scored on the same blocks). A record's scored samples (``masks[j] &
    record.mask``, finite prediction) are cut in time order into ``n_blocks`` runs of equal
    count; a block without samples is NaN.
    """
    records = list(records)
    if isinstance(pred, Reference):
        pred = [pred.predict(r) for r in records]
    out = np.full((len(records), int(n_blocks)), np.nan)
    for j, (r, p, m) in enumerate(zip(records, pred, masks)):
        e = np.asarray(r.force, dtype=float) - np.asarray(p, dtype=float)
        idx = np.flatnonzero(np.asarray(m, dtype=bool) & r.mask & np.isfinite(e))
        for b, part in enumerate(np.array_split(idx, int(n_blocks))):
            if part.size:
                out[j, b] = float(np.mean(e[part] ** 2))
    return out
