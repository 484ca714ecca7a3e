"""Sensor checks on rig records: time base, dropouts, clipping, spikes, velocity consistency.

Pure functions on numpy arrays. Each returns ``(mask or corrected array, finding or None)``;
a finding is a dict ``{'finding': NAME, 'location': 'sensor', 'channel': ..., 'action':
'corrected' | 'excluded' | 'warned', 'detail': one sentence with numbers, ...numbers}``.
A mask is a bool array, True = usable sample.

* ``uniform_time``: stamps rounded to a quantum (dt taking a few values, multiples of ``q``)
  are put back on the straight line ``t_k = t0 + k dt`` (least squares over the sample index,
  so missing rows count as steps of 2, 3 ... samples); truly irregular stamps are resampled.
* ``missing_rows``: the grid samples no input row fell on (``dropout``).
* ``clipping`` / ``dropouts``: runs of one repeated value longer than the channel's repeat
  statistics allow *and* not explained by its dynamics (a quadratic through the neighbours
  leaves the held value by more than the channel's resolution): at the channel's max or min
  that is a clipped sensor, elsewhere a frozen one. NaN/inf runs are dropouts too.
* ``spikes``: non-physical magnitudes and isolated samples far from a running median.
* ``velocity_check``: a measured velocity against the zero-phase derivative of displacement
  (gain, fractional time shift by normalised cross-correlation with parabolic peak
  interpolation, excess high-frequency noise).
"""

from dataclasses import dataclass
import math

import numpy as np
from scipy import ndimage, signal

from mr_suspension.identification.errors import DataError

# Magnitudes no rig sensor reports in SI units (a value beyond is a glitch, not a measurement).
LIMITS = {'force': 1e7, 'displacement': 100.0, 'velocity': 1e3, 'current': 1e3,
          'current_command': 1e3, 'voltage_command': 1e4, 'temperature': 1e4}
FALSE_RUNS = 1e-3        # expected number of chance runs tolerated per channel
MIN_RUN = 5              # shortest repeated run that can be a fault
SPIKE_SIGMAS = 10.0      # a spike leaves the running median by this many robust sigmas ...
SPIKE_SPREAD = 0.5       # ... and leaves the 0.5-99.5 % range by this fraction of it
GAIN_TOL = 0.05          # measured / derived velocity gain off by more: corrected
UNIT_TOL = 0.25          # gain off by more (a unit or sign error): refused
SHIFT_TOL = 0.3          # velocity time shift [samples] that is reported and corrected
NOISE_TOL = 0.05         # velocity HF noise / velocity RMS that is reported and corrected


def finding(name, channel, action, detail, **numbers):
    """Build a finding dict (numbers are converted to plain floats/ints)."""
    out = {'finding': name, 'location': 'sensor', 'channel': channel, 'action': action,
           'detail': detail}
    for k, v in numbers.items():
        out[k] = int(v) if isinstance(v, (bool, np.bool_, int, np.integer)) else float(v)
    return out


def runs(flags):
    """Start indices and lengths of the runs of True in a bool array."""
    d = np.diff(np.concatenate(([0], np.asarray(flags, dtype=np.int8), [0])))
    start = np.flatnonzero(d == 1)
    return start, np.flatnonzero(d == -1) - start


def fill(x, mask):
    """``x`` with the samples where ``mask`` is False linearly interpolated from the others."""
    if mask.all() or not mask.any():
        return x
    idx = np.flatnonzero(mask)
    out = x.copy()
    bad = np.flatnonzero(~mask)
    out[bad] = np.interp(bad, idx, x[idx])
    return out


FILL_SIDE = 20   # usable samples each side of a gap that the motion's fill is fitted to
FILL_DEG = 3     # degree of that local polynomial


def fill_motion(y, mask):
    """``y`` (a displacement or velocity) with its unusable samples bridged smoothly.

    Each run of samples where ``mask`` is False is filled by a least-squares cubic through
    up to ``FILL_SIDE`` usable samples on each side (sample index as abscissa), which keeps
    the motion's slope and curvature across the gap; a straight line (``fill``) leaves a
    kink at both ends, and frozen frames left as they are a step: the velocity derived or
    fused from such a displacement erred up to 12x (median 5x) more within 15 samples of
    the gaps than elsewhere. Runs with fewer than ``FILL_DEG + 2`` usable samples around
    them, or at an end of the record, are filled linearly (held at the end).
    """
    if mask.all() or not mask.any():
        return y
    out = fill(y, mask)
    n = y.size
    for a, length in zip(*runs(~mask)):
        b = a + length
        left = np.flatnonzero(mask[max(0, a - FILL_SIDE):a]) + max(0, a - FILL_SIDE)
        right = np.flatnonzero(mask[b:min(n, b + FILL_SIDE)]) + b
        idx = np.concatenate([left, right])
        if idx.size < FILL_DEG + 2 or not (left.size and right.size):
            continue
        c = 0.5 * (a + b - 1)
        coef = np.polyfit(idx - c, y[idx], FILL_DEG)
        out[a:b] = np.polyval(coef, np.arange(a, b) - c)
    return out


@dataclass(frozen=True)
class TimeBase:
    """A uniform time base: ``time`` (from 0, step ``dt``) and where the input rows sit on it.

    ``stamps`` are the input stamps relative to the first; ``index[k]`` is the grid sample of
    input row ``k`` (None when the rows were resampled).
    """

    time: np.ndarray
    dt: float
    index: np.ndarray = None
    stamps: np.ndarray = None

    @property
    def resampled(self):
        """True when the rows had to be interpolated onto the grid."""
        return self.index is None


def _quantum(d, slop):
    """Stamp quantum of step values ``d``: the spacing of their few distinct values (or 0)."""
    vals = np.unique(d)
    if vals.size > 1:
        cut = np.flatnonzero(np.diff(vals) > 4 * slop)
        centres = [g.mean() for g in np.split(vals, cut + 1)]
    else:
        centres = [vals[0]]
    if len(centres) == 1:
        return 0.0, 1
    if len(centres) > 12:
        return None, len(centres)
    q = float(np.min(np.diff(centres)))
    if np.max(np.abs(np.array(centres) / q - np.round(np.array(centres) / q))) > 0.05:
        return None, len(centres)
    return q, len(centres)


def uniform_time(t):
    """Recover a uniform time base from stamps ``t`` (finite, strictly increasing).

    Returns ``(TimeBase, finding)``. Clean stamps give ``(raw stamps - t0, median dt)`` and no
    finding; rounded or jittery stamps the least-squares line ``k dt`` (``stamp_rounding`` /
    ``stamp_jitter``, corrected); missing rows leave grid samples without a row (see
    ``missing_rows``); irregular stamps a resampled grid (``irregular_sampling``).
    """
    t = np.asarray(t, dtype=float)
    rel = t - t[0]
    dts = np.diff(rel)
    d0 = float(np.median(dts))
    m = np.maximum(np.rint(dts / d0), 1.0)
    if np.any(m == 1):
        d1 = float(np.mean(dts[m == 1]))
        m = np.maximum(np.rint(dts / d1), 1.0)
    k = np.concatenate(([0.0], np.cumsum(m)))
    del m
    km, rm = float(k.mean()), float(rel.mean())
    kc = k - km
    dt = float(np.dot(kc, rel - rm) / np.dot(kc, kc))
    del kc
    a = rm - dt * km
    rmax = float(np.max(np.abs(rel - (a + dt * k))))
    index = k.astype(np.int32 if k[-1] < 2 ** 31 - 1 else np.int64)
    del k
    slop = 8 * np.finfo(float).eps * max(abs(t[0]), abs(t[-1])) + 1e-15
    gaps = bool(index[-1] + 1 > index.size)
    if rmax <= 1e-3 * dt + slop:
        if not gaps:
            return TimeBase(rel, d0, index, rel), None
        return TimeBase(dt * np.arange(index[-1] + 1), dt, index, rel), None
    q, nvals = _quantum(dts[np.diff(index) == 1], slop)
    grid = dt * np.arange(index[-1] + 1)
    if q is not None and q < dt and rmax <= q + 4 * slop:
        return TimeBase(grid, dt, index, rel), finding(
            'stamp_rounding', 'time', 'corrected',
            f'time stamps are rounded to {q:.3g} s (steps take {nvals} values, residuals from '
            f'a uniform {1 / dt:.6g} Hz line within {rmax:.3g} s); the uniform grid '
            f'dt = {dt:.9g} s is used, no resampling', quantum=q, dt=dt, max_residual=rmax)
    if rmax <= 0.1 * dt:
        return TimeBase(grid, dt, index, rel), finding(
            'stamp_jitter', 'time', 'corrected',
            f'time stamps jitter by up to {rmax:.3g} s ({100 * rmax / dt:.1f} % of the '
            f'{dt:.6g} s step) around a uniform line; the uniform grid is used',
            dt=dt, max_residual=rmax)
    grid = d0 * np.arange(int(math.ceil(rel[-1] / d0 - 1e-9)) + 1)
    return TimeBase(grid, d0, None, rel), finding(
        'irregular_sampling', 'time', 'corrected',
        f'irregular sampling (steps {dts.min():.3g}..{dts.max():.3g} s, {rmax:.3g} s from any '
        f'uniform line); resampled to a uniform {d0:.3g} s grid by linear interpolation',
        dt=d0, step_min=float(dts.min()), step_max=float(dts.max()))


def missing_rows(base):
    """Mask the grid samples without an input row; ``dropout`` finding if there are any."""
    n = base.time.size
    mask = np.ones(n, dtype=bool)
    if base.index is None or base.index.size == n:
        return mask, None
    mask[:] = False
    mask[base.index] = True
    start, length = runs(~mask)
    miss = int(n - base.index.size)
    j = int(np.argmax(length))
    return mask, finding(
        'dropout', 'all', 'excluded',
        f'{miss} missing row(s) in {start.size} gap(s) (longest {length[j]} samples at '
        f't = {base.time[start[j]]:.4g} s); put on the uniform grid, masked',
        samples=miss, runs=start.size, longest=int(length[j]))


REPEAT_TOL = 1e-8  # relative to the values: far below any converter's resolution


def repeats(x):
    """``r[k]``: ``x[k + 1]`` repeats ``x[k]`` (equal to within ``REPEAT_TOL`` of their size).

    A held sample repeats its value; a difference far below any sensor's resolution (round-off
    of a unit conversion or a scale) must not decide whether it does. NaN repeats nothing.
    """
    x = np.asarray(x, dtype=float)
    a, b = x[1:], x[:-1]
    with np.errstate(invalid='ignore'):
        return (a == b) | (np.abs(a - b) <= REPEAT_TOL * np.maximum(np.abs(a), np.abs(b)))


def _resolution(x):
    """Smallest step of ``x`` that is not a repeat (its quantisation, or a tiny number)."""
    d = np.abs(np.diff(x))
    d = d[np.isfinite(d) & ~repeats(x)]
    return float(d.min()) if d.size else 0.0


def _held_runs(x, consistent=None, suspects=()):
    """Repeated-value runs of ``x`` not explained by chance, resolution or dynamics.

    Returns a list of ``(start, length, value)``. ``consistent`` (bool array, optional) marks
    samples where another sensor agrees with a hold (e.g. the velocity is ~0 while the
    displacement holds); a run that is mostly consistent is genuine. Otherwise a run is a
    fault when a quadratic through its neighbours leaves the held value by more than 1.5
    resolution steps plus 3 noise sigmas (from the second differences). The chance of a run
    is judged from the channel's repeats at values other than ``suspects`` (the rails when
    looking for clipping: many long runs at a rail would otherwise raise the repeat rate they
    are judged by, and hide themselves).
    """
    n = x.size
    eq = repeats(x)
    if not eq.any():
        return []
    own = eq & ~np.isin(x[1:], suspects) if len(suspects) else eq
    p = float(own.mean())
    start, length = runs(eq)
    length = length + 1
    lmin = MIN_RUN
    if 0.0 < p < 1.0:
        # chance runs if samples repeat independently with probability p ...
        lmin = max(lmin, int(math.ceil(1 + math.log(FALSE_RUNS / n) / math.log(p))))
        # ... and if runs extend geometrically as the channel's short runs do (quantised,
        # slowly varying signals cluster their repeats)
        own_length = runs(own)[1] + 1
        cnt = [int(np.sum(own_length >= j)) for j in (2, 3, 4)]
        if cnt[0] >= 20:
            rho = max(cnt[1] / cnt[0], cnt[2] / max(cnt[1], 1), p)
            if 0.0 < rho < 1.0:
                lmin = max(lmin, int(math.ceil(2 + math.log(FALSE_RUNS / cnt[0])
                                               / math.log(rho))))
    keep = length >= lmin
    start, length = start[keep], length[keep]
    if start.size == 0:
        return []
    res = _resolution(x)
    scale = float(np.nanpercentile(np.abs(x), 99))
    d2 = np.diff(x, 2)
    d2 = d2[np.isfinite(d2)]
    noise = 1.4826 * float(np.median(np.abs(d2))) / math.sqrt(6.0) if d2.size else 0.0
    tol = 1.5 * res + 3.0 * noise + 1e-9 * scale
    out = []
    for s, ln in zip(start[:10000], length[:10000]):
        e = s + ln
        val = x[s]
        if consistent is not None and np.mean(consistent[s:e]) >= 0.8:
            continue
        w = int(min(max(ln, 10), 200))
        ib = np.arange(max(0, s - w), s)
        ia = np.arange(e, min(n, e + w))
        idx = np.concatenate((ib, ia))
        idx = idx[np.isfinite(x[idx])]
        if idx.size < 4:
            out.append((int(s), int(ln), float(val)))
            continue
        deg = 2 if ib.size >= 2 and ia.size >= 2 else 1
        c = (s + e) / 2.0
        coef = np.polyfit((idx - c) / ln, x[idx], deg)
        path = np.polyval(coef, (np.arange(s, e) - c) / ln)
        if np.max(np.abs(path - val)) > tol:
            out.append((int(s), int(ln), float(val)))
    return out


RAIL_TOL = 1e-7  # relative to the larger extreme: far below any sensor's resolution


def snap_rails(x, hi, lo):
    """Return ``x`` with the values within ``RAIL_TOL`` of its extremes put on them.

    A rail holds one value; a difference far below any sensor's resolution (round-off of a
    unit conversion or a filter) must not decide whether a sample is at it.
    """
    tol = RAIL_TOL * max(abs(hi), abs(lo))
    out = np.array(x, dtype=float)
    with np.errstate(invalid='ignore'):
        out[out >= hi - tol] = hi
        out[out <= lo + tol] = lo
    return out


def clipping(name, x, consistent=None):
    """Mask samples at a clipped extreme (max or min held longer than noise and dynamics allow).

    Every sample at a clipped rail is masked, not only the long runs: the true value there is
    unknown (at or beyond the rail). Returns ``(mask, finding or None)``.
    """
    x = np.asarray(x, dtype=float)
    mask = np.ones(x.size, dtype=bool)
    ok = np.isfinite(x)
    if not ok.any():
        return mask, None
    hi, lo = float(np.max(x[ok])), float(np.min(x[ok]))
    if hi == lo:
        return mask, None        # a constant channel is judged by the caller, not masked
    x = snap_rails(x, hi, lo)
    held = _held_runs(x, consistent, suspects=(hi, lo))
    rails = sorted({v for _, _, v in held if v in (hi, lo)})
    if not rails:
        return mask, None
    for v in rails:
        mask &= x != v
    longest = max(ln for _, ln, v in held if v in rails)
    nbad = int((~mask).sum())
    where = ' and '.join(('max' if v == hi else 'min') + f' {v:.6g}' for v in rails)
    return mask, finding(
        'clipping', name, 'excluded',
        f'{name} clipped at its {where}: {nbad} samples ({100 * nbad / x.size:.2f} %) at the '
        f'rail, longest run {longest} samples; masked', samples=nbad, longest=longest,
        fraction=nbad / x.size, rail_high=hi if hi in rails else math.nan,
        rail_low=lo if lo in rails else math.nan)


def dropouts(name, x, consistent=None, frozen=True, exclude=None):
    """Mask NaN/inf runs and (``frozen=True``) frozen runs: one value held away from the extremes.

    ``exclude`` marks samples already masked by another check (ignored here, not counted).
    Returns ``(mask, finding or None)``; the finding counts both kinds.
    """
    x = np.asarray(x, dtype=float)
    bad = ~np.isfinite(x)
    nan_start, nan_len = runs(bad)
    mask = ~bad
    held = []
    xs = x if exclude is None else np.where(exclude, np.nan, x)
    ok = np.isfinite(xs)
    if frozen and ok.any() and np.ptp(xs[ok]) > 0:
        hi, lo = float(np.max(xs[ok])), float(np.min(xs[ok]))
        held = [(s, ln) for s, ln, v in _held_runs(xs, consistent) if v not in (hi, lo)]
    frozen = held
    for s, ln in frozen:
        mask[s:s + ln] = False
    if not bad.any() and not frozen:
        return mask, None
    nf = sum(ln for _, ln in frozen)
    longest = max([ln for _, ln in frozen] + list(nan_len))
    parts = []
    if bad.any():
        parts.append(f'{int(bad.sum())} NaN/inf sample(s) in {nan_start.size} run(s)')
    if frozen:
        parts.append(f'{nf} frozen sample(s) in {len(frozen)} run(s) of one repeated value')
    return mask, finding(
        'dropout', name, 'excluded',
        f'{name}: ' + ' and '.join(parts) + f' (longest {longest}); masked, linearly '
        'interpolated only to keep the model states running', samples=int((~mask).sum()),
        nan_samples=int(bad.sum()), nan_runs=nan_start.size, frozen_samples=nf,
        frozen_runs=len(frozen), longest=longest, fraction=float((~mask).mean()))


def frame_holds(channels):
    """Mask samples where every continuous measured channel repeats its previous value at once.

    An acquisition that freezes (a frame re-sent, a held bus) repeats all channels together,
    for runs of any length, also shorter than a single channel's hold test can tell from
    chance. Independent noisy channels repeat together by chance with probability
    ``prod p_c``, ``p_c`` a channel's own repeat rate at the other samples; the coincidences
    are a fault when the expected number of chance coincidences ``n prod p_c`` is below
    ``FALSE_RUNS``. ``channels``: name -> array (two or more: force, displacement, velocity).
    Returns ``(mask, finding or None)``; the held copies are masked, not the sample they copy.
    """
    if len(channels) < 2:
        return None, None
    eqs = [np.r_[False, repeats(y)] for y in map(np.asarray, channels.values())]
    held = np.logical_and.reduce(eqs)
    nh = int(held.sum())
    if nh == 0:
        return None, None
    rest = max(int((~held).sum()), 1)
    chance = held.size * math.prod(float((eq & ~held).sum()) / rest for eq in eqs)
    if chance > FALSE_RUNS:
        return None, None
    start, length = runs(held)
    names = ', '.join(channels)
    return ~held, finding(
        'dropout', names, 'excluded',
        f'{nh} sample(s) in {start.size} run(s) (longest {int(length.max())}) where {names} '
        f'all repeat their previous value at once: a frozen acquisition frame (chance '
        f'coincidences expected: {chance:.1e}); masked', samples=nh, frozen_samples=nh,
        frame_runs=int(start.size), longest=int(length.max()), fraction=nh / held.size)


def spikes(name, x, limit=None):
    """Mask non-physical values (``|x| > limit``) and isolated samples far from the median.

    ``x`` must be finite (fill dropouts first). An outlier leaves the 5-sample running median
    by more than ``SPIKE_SIGMAS`` robust sigmas and lies outside the channel's envelope
    (0.5-99.5 % range widened by ``SPIKE_SPREAD`` of it on each side): a glitch, not a fast
    but genuine excursion. Returns ``(mask, finding or None)``.
    """
    x = np.asarray(x, dtype=float)
    if limit is None:
        limit = LIMITS.get(name, math.inf)
    wild = np.abs(x) > limit
    xs = fill(x, ~wild) if wild.any() and not wild.all() else x
    r = xs - ndimage.median_filter(xs, size=5, mode='nearest')
    sigma = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    lo, hi = np.percentile(xs, [0.5, 99.5])
    thr = max(SPIKE_SIGMAS * sigma, _resolution(xs))
    wide = SPIKE_SPREAD * (hi - lo)
    outl = (np.abs(r) > thr) & ((xs > hi + wide) | (xs < lo - wide)) & ~wild
    mask = ~(wild | outl)
    if mask.all():
        return mask, None
    nw, no = int(wild.sum()), int(outl.sum())
    parts = []
    if nw:
        parts.append(f'{nw} non-physical value(s) (|{name}| > {limit:.3g}, up to '
                     f'{float(np.max(np.abs(x[wild]))):.3g})')
    if no:
        parts.append(f'{no} isolated outlier(s) beyond {thr:.3g} from the running median')
    return mask, finding('spike', name, 'excluded', f'{name}: ' + ' and '.join(parts)
                         + '; masked', samples=nw + no, nonphysical=nw, outliers=no,
                         threshold=thr, fraction=(nw + no) / x.size)


LOWPASS_MAX = 0.45   # a cut-off at or above this fraction of the sampling rate: no low-pass


def lowpass(y, dt, cutoff, order=2):
    """Zero-phase Butterworth low-pass (``order``, ``cutoff`` Hz; None or >= 0.45 fs: none)."""
    fs = 1.0 / dt
    if cutoff is None or cutoff >= LOWPASS_MAX * fs or y.size <= 30:
        return y
    sos = signal.butter(order, cutoff / (0.5 * fs), output='sos')
    return signal.sosfiltfilt(sos, y, padlen=_padlen(y.size, fs, cutoff, order))


def _padlen(n, fs, cutoff, order):
    """Odd-extension length of a zero-phase filter: three periods of the cut-off."""
    if order == 2:  # the historical derived velocity (filtfilt's own default)
        return min(9, n - 1)
    return int(min(n - 1, max(15, 3.0 * fs / cutoff)))


def derive_velocity(x, dt, cutoff=25.0, order=2):
    """Velocity from displacement: zero-phase Butterworth (``order``, ``cutoff`` Hz) + gradient."""
    return np.gradient(lowpass(x, dt, cutoff, order), dt)


BAND_SNR = 10.0      # spectrum above this many times the white-noise level: motion
BAND_FACTOR = 1.6    # cut-off = this x the motion band's edge (4th-order zero-phase: < 1.2 %)
BAND_MIN = 5.0       # [Hz] lowest automatic cut-off
BAND_RANGE = 1e-10   # noise level at least this fraction of the spectrum's peak (100 dB)


def motion_cutoff(y, dt):
    """Cut-off [Hz] of ``motion_band`` (None: no low-pass)."""
    return motion_band(y, dt)[0]


def motion_band(y, dt):
    """Low-pass cut-off [Hz] that keeps the motion of ``y`` and drops its white sensor noise.

    ``y`` is a signal whose sensor noise is white (a measured displacement or velocity).
    Welch spectrum (about 2 s segments); the noise level is the median spectrum above 0.3 of
    the sampling rate (robust to tones there, e.g. from rounded time stamps), at least
    ``BAND_RANGE`` times the spectrum's peak; the motion band
    ends at the highest frequency below 0.25 of the sampling rate whose spectrum is above
    ``BAND_SNR`` times it. Returns ``(cut-off, white-noise RMS above it)``: the cut-off is
    ``BAND_FACTOR`` times that edge, within ``BAND_MIN`` and 0.4 of the sampling rate, or None
    when nothing stands above the noise (with the white RMS of the whole band) or the record is
    too short to tell (no filtering; 0).
    """
    fs = 1.0 / dt
    spec = _spectrum(y, dt)
    if spec is None:
        return None, 0.0
    f, p, white = spec
    # Never more than BAND_RANGE below the peak: a deterministic residue (stamps rounded in a
    # repeating pattern, quantisation) leaves a near-zero median that window leakage beats.
    noise = max(white, BAND_RANGE * float(p.max()))
    if not noise > 0.0:
        return None, 0.0
    band = (f > 0) & (f < 0.25 * fs)
    above = np.nonzero(band & (p > BAND_SNR * noise))[0]
    if not above.size:
        return None, math.sqrt(white * 0.5 * fs)
    cut = float(min(max(BAND_FACTOR * f[above[-1]], BAND_MIN), 0.4 * fs))
    return cut, math.sqrt(white * (0.5 * fs - cut))


def _spectrum(y, dt):
    """Welch spectrum of ``y`` (about 2 s segments) and its white level ``(f, p, white)``.

    ``white`` [unit^2/Hz, one-sided] is the median spectrum above 0.3 of the sampling rate
    (robust to tones there); None when ``y`` is too short or not finite.
    """
    y = np.asarray(y, dtype=float)
    fs = 1.0 / dt
    if y.size < 256 or not np.all(np.isfinite(y)):
        return None
    nper = int(min(y.size // 4, 2 ** round(math.log2(max(64.0, 2.0 * fs)))))
    f, p = signal.welch(y, fs, nperseg=nper, detrend='linear')
    top = f >= 0.3 * fs
    return f, p, float(np.median(p[top])) if top.any() else 0.0


FUSE_MIN = 1.0       # [Hz] below this crossover the displacement adds nothing worth a filter


def fuse_velocity(x, v, dt):
    """Measured velocity fused with the derivative of the measured displacement.

    Two measurements of one rate with white noise: ``v`` (level ``S_v``) and ``dx/dt``
    (central differences, level about ``w^2 S_x``, which grows with frequency). Their
    minimum-variance (Wiener) combination weighs the derivative by
    ``W = S_v / (S_v + w^2 S_x) = 1 / (1 + (f/f_c)^2)``, ``f_c = sqrt(S_v / S_x) / 2 pi``,
    and ``W`` is exactly the gain of a first-order Butterworth run forwards and backwards, so
    ``v_f = v + filtfilt_1(dx/dt - v)``: the difference holds no motion, only the two noises,
    and the filter has no phase lag. The white levels are the spectra's medians above 0.3 of
    the sampling rate (``_spectrum``). Returns ``(v_f, f_c)``; ``(v, None)`` when either
    level is not measurable or ``f_c`` is below ``FUSE_MIN``. With ``f_c`` above 0.45 of the
    sampling rate the derivative wins at every frequency and is returned.
    """
    sx, sv = _spectrum(x, dt), _spectrum(v, dt)
    if sx is None or sv is None or not (sx[2] > 0.0 and sv[2] > 0.0):
        return v, None
    fc = math.sqrt(sv[2] / sx[2]) / (2.0 * math.pi)
    if fc < FUSE_MIN:
        return v, None
    # Central differences (not a higher-order stencil): a velocity that the rig itself took
    # as the central difference of this displacement is left exactly as it is.
    d = np.gradient(np.asarray(x, dtype=float), dt) - v
    if not np.max(np.abs(d)) > 1e-9 * np.max(np.abs(v)):
        return v, None
    return _fuse(x, v, dt, fc), fc


def _fuse(x, v, dt, fc):
    """``v + filtfilt_1(dx/dt - v)`` at the crossover ``fc`` (``fuse_velocity``'s chain)."""
    d = np.gradient(np.asarray(x, dtype=float), dt) - v
    if fc >= 0.45 / dt:
        return v + d
    sos = signal.butter(1, fc * 2.0 * dt, output='sos')
    # Even (mirror) padding: the difference is noise about zero, and an odd extension would
    # shift the padding by twice its first, noisy sample.
    pad = int(min(d.size - 1, max(15, 3.0 / (fc * dt))))
    return v + signal.sosfiltfilt(sos, d, padtype='even', padlen=pad)


def white_noise(y, dt):
    """Tell whether the noise of ``y`` is white (flat over the upper half of the band).

    The median Welch spectrum over 0.15-0.22 of the sampling rate against that over 0.3-0.45
    (``_spectrum``'s white level): white noise gives 1, the noise of a central-difference
    derivative of a noisy signal (``sin^2(2 pi f dt)``-shaped, a velocity the rig took as
    such a derivative) about 1.8. True below ``WHITE_TOL``.
    """
    spec = _spectrum(y, dt)
    if spec is None or not spec[2] > 0.0:
        return False
    f, p, white = spec
    mid = (f >= 0.15 / dt) & (f < 0.22 / dt)
    return bool(mid.any() and np.median(p[mid]) < WHITE_TOL * white)


WHITE_TOL = 1.45      # ``white_noise``: mid-band / top-band spectrum below this is white
ICI_GAMMA = 2.0       # half-width of each confidence interval, in noise standard deviations
ICI_STEP = 1.5        # ratio of neighbouring cut-offs of the ladder
ICI_NOISE = 1 << 15   # samples of the noise realisation that sets each rung's deviation


def velocity_noise(x, v, dt, fc=None, seed=0):
    """Draw the noise of a velocity estimate: white at the levels ``_spectrum`` finds.

    With a measured velocity ``v``: ``fuse_velocity``'s output at the crossover ``fc`` the
    record's fusion used (None: no fusion, ``v``'s noise alone); without (``v`` None): the
    central difference of the displacement ``x``'s noise. At most ``ICI_NOISE`` samples;
    seeded, so a record always gives the same estimate.
    """
    n = int(min(np.asarray(x).size, ICI_NOISE))
    rng = np.random.default_rng(seed)
    sx = _spectrum(x, dt)
    ex = (0.0 if sx is None else math.sqrt(sx[2] * 0.5 / dt)) * rng.standard_normal(n)
    if v is None:
        return np.gradient(ex, dt)
    sv = _spectrum(v, dt)
    ev = (0.0 if sv is None else math.sqrt(sv[2] * 0.5 / dt)) * rng.standard_normal(n)
    return ev if fc is None else _fuse(ex, ev, dt, fc)


def measured_velocity_noise(x, v, dt, fc=None):
    """Draw the noise of a measured velocity ``v`` after fusion at ``fc``, or None if unknown.

    White noise (``white_noise``): ``velocity_noise(x, v, dt, fc)``. Otherwise the velocity
    may be the rig's own derivative of the noisy displacement (over its stamps, so not
    exactly ``np.gradient(x, dt)`` and fused all the same): its noise is then that of the
    displacement's central difference, ``velocity_noise(x, None, dt)``, whose white level
    (median spectrum above 0.3 fs) must match ``v``'s within ``DERIV_TOL``; other coloured
    noise is not modelled (None).
    """
    if white_noise(v, dt):
        return velocity_noise(x, v, dt, fc)
    e = velocity_noise(x, None, dt)
    se, sv = _spectrum(e, dt), _spectrum(v, dt)
    if se is None or sv is None or not (se[2] > 0.0 and sv[2] > 0.0):
        return None
    return e if abs(math.log(sv[2] / se[2])) < math.log(DERIV_TOL) else None


DERIV_TOL = 1.5       # ``measured_velocity_noise``: white levels of ``v`` and dx/dt this close


def ici_lowpass(y, dt, cut, noise, gamma=ICI_GAMMA, with_sd=False):
    """Zero-phase low-pass of ``y`` at ``cut`` or, per sample, as far below as the data allow.

    A ladder of 4th-order zero-phase Butterworth low-passes ``y_j`` from ``cut`` [Hz] down to
    ``BAND_MIN`` in steps of ``ICI_STEP``; ``sigma_j`` is the deviation of ``noise`` (``y``'s
    noise, ``velocity_noise``) through the same filter. From ``cut`` down, the intervals
    ``y_j +- gamma sigma_j`` are intersected, and each sample keeps the last rung whose
    interval still meets every wider one (intersection of confidence intervals: Goldenshluger
    & Nemirovski 1997, Katkovnik 1999). Slow motion is smoothed below ``cut``, a fast reversal
    keeps ``cut``; never wider than ``cut``, so never noisier than its one low-pass. Within
    half a period of a rung's cut-off from either end (one-sided there) that rung is not taken.
    Returns ``(estimate, cut-off per sample [Hz])``; ``with_sd``: also the chosen rung's noise
    deviation per sample.
    """
    y = np.asarray(y, dtype=float)
    k = max(0, int(math.floor(math.log(cut / BAND_MIN) / math.log(ICI_STEP))))
    cuts = cut / ICI_STEP ** np.arange(k + 1)
    edge = min(noise.size // 4, int(3.0 / (cuts[-1] * dt)))
    lo = np.full(y.size, -np.inf)
    hi = np.full(y.size, np.inf)
    alive = np.ones(y.size, dtype=bool)
    out = np.empty_like(y)
    chosen = np.empty_like(y)
    chosen_sd = np.empty_like(y)
    ends = np.minimum(np.arange(y.size), np.arange(y.size)[::-1])
    for c in cuts:
        est = lowpass(y, dt, c, order=4)
        sig = float(np.std(lowpass(noise, dt, c, order=4)[edge:noise.size - edge]))
        lo = np.maximum(lo, est - gamma * sig)
        hi = np.minimum(hi, est + gamma * sig)
        # within half a period of either end the filter is one-sided (``data.velocity_edge``)
        if c < cuts[0]:
            alive &= (lo <= hi) & (ends >= math.ceil(0.5 / (c * dt)))
        out[alive] = est[alive]
        chosen[alive] = c
        chosen_sd[alive] = sig
    return (out, chosen, chosen_sd) if with_sd else (out, chosen)


LPA_ORDER = 2        # ``lpa_ici``: local polynomial degree (a turn of the motion is quadratic)
LPA_MIN = 2          # ``lpa_ici``: shortest half-window [samples]


def _correlate(y, first, c):
    """Return ``sum_j c_j y[n + first + j]`` for every ``n`` (zero beyond the ends; FFT)."""
    last = first + c.size - 1
    return signal.oaconvolve(y, c[::-1], mode='full')[last:last + y.size]


def lpa_ici(y, dt, noise, mask=None, gamma=ICI_GAMMA, order=LPA_ORDER):
    """Per-sample local polynomial smoothing of ``y`` over past, centred and future windows.

    For each direction (past, centred, future) a ladder of half-windows ``h`` from
    ``LPA_MIN`` samples up by ``ICI_STEP`` to half a period of ``BAND_MIN``: the
    least-squares polynomial of degree ``order`` over the window, valued at the sample
    (local polynomial approximation, LPA). ``sigma_h`` is the deviation of ``noise`` (``y``'s
    noise, ``velocity_noise``) through the same weights. Each sample keeps, per direction,
    the longest window whose interval ``y_h +- gamma sigma_h`` still meets every shorter one
    (intersection of confidence intervals), and the three directions are fused by inverse
    variance (Katkovnik, Egiazarian & Astola 2006, Local Approximation Techniques in Signal
    and Image Processing, ch. 6). A one-sided window keeps a kink of the motion (a reversal
    against a yield force) that every symmetric one blurs; slow motion gets long windows.
    Windows never reach past either end nor hold a sample ``mask`` refuses. Returns
    ``(estimate, its noise deviation per sample)``: NaN and inf where no window fits.
    """
    y = np.asarray(y, dtype=float)
    n = y.size
    noise = np.asarray(noise, dtype=float)
    h_max = max(LPA_MIN, int(0.5 / (BAND_MIN * dt)))
    hs = np.unique(np.round(LPA_MIN * ICI_STEP ** np.arange(
        1 + math.log(h_max / LPA_MIN) / math.log(ICI_STEP))).astype(int))
    hs = hs[hs <= h_max]
    idx = np.arange(n)
    # windows holding an unusable (filled) sample count as beyond an end
    bad = np.zeros(n + 1, dtype=np.int64)
    if mask is not None:
        bad[1:] = np.cumsum(~np.asarray(mask, dtype=bool))
    edge = noise.size // 4
    num = np.zeros(n)
    den = np.zeros(n)
    for side in (-1, 0, 1):
        lo = np.full(n, -np.inf)
        hi = np.full(n, np.inf)
        alive = np.ones(n, dtype=bool)
        est = np.zeros(n)
        var = np.full(n, np.inf)
        for h in hs:
            # the window's first sample, behind (-2h), around (-h) or at (0) the estimate's;
            # Savitzky-Golay weights of the polynomial's value at the estimate's sample
            first = {-1: -2 * h, 0: -h, 1: 0}[side]
            c = signal.savgol_coeffs(2 * h + 1, order, pos=-first, use='dot')
            a, b = idx + first, idx + first + 2 * h
            valid = (a >= 0) & (b < n)
            valid[valid] = bad[b[valid] + 1] == bad[a[valid]]
            if not valid.any():
                break
            e = _correlate(y, first, c)
            e_noise = _correlate(noise, first, c)[max(edge, first + 2 * h):
                                                  noise.size - max(edge, -first)]
            sig = float(np.std(e_noise)) if e_noise.size > 10 else \
                float(np.std(noise) * math.sqrt(np.dot(c, c)))
            lo = np.maximum(lo, e - gamma * sig)
            hi = np.minimum(hi, e + gamma * sig)
            alive &= valid & (lo <= hi)
            est[alive] = e[alive]
            var[alive] = sig * sig
        ok = np.isfinite(var) & (var > 0)
        num[ok] += est[ok] / var[ok]
        den[ok] += 1.0 / var[ok]
    with np.errstate(divide='ignore', invalid='ignore'):
        return num / den, 1.0 / np.sqrt(den)


def directional_velocity(y, dt, cut, noise, mask=None):
    """Prediction velocity: the low-pass ladder and the directional local fits, fused.

    Four estimates of the rate ``y`` per sample, each with its noise deviation: the
    zero-phase Butterworth ladder (``ici_lowpass``, from ``cut`` down; it carries a smooth
    stretch on the longest filters) and the past, centred and future local quadratic fits
    (``lpa_ici``; a one-sided window keeps the kink of a reversal against a yield force).
    Fused by inverse variance: ``v = sum(v_k / s_k^2) / sum(1 / s_k^2)`` (the ``s_k`` count
    noise only, as if the four were independent: weights, not an error bar). Returns ``(v,
    the local fits' share of the weight per sample)``; where every local window holds a
    masked sample, or with a noise of zero deviation, the ladder (share 0).
    """
    lad, _, lad_sd = ici_lowpass(y, dt, cut, noise, with_sd=True)
    if not np.all(lad_sd > 0):  # no noise to weigh by: nothing to fuse
        return lad, np.zeros(lad.size)
    loc, loc_sd = lpa_ici(y, dt, noise, mask)
    fit = np.isfinite(loc_sd)
    w_lad = 1.0 / lad_sd ** 2
    w_loc = np.where(fit, 1.0 / np.where(fit, loc_sd, 1.0) ** 2, 0.0)
    v = (w_lad * lad + w_loc * np.where(fit, loc, 0.0)) / (w_lad + w_loc)
    return v, w_loc / (w_lad + w_loc)


def smooth_velocity(v, dt, cutoff):
    """Zero-phase 4th-order Butterworth low-pass of a measured velocity (no phase lag)."""
    return lowpass(np.asarray(v, dtype=float), dt, cutoff, order=4)


def _ncc_shift(a, b, w, lmax, m):
    """Return the lag of ``a`` behind ``b`` [samples] and the peak correlation.

    Normalised cross-correlation over the samples ``w`` at integer lags, parabolic
    interpolation of its peak.
    """
    n = a.size
    ww = w[m:n - m]
    bb = np.where(ww, b[m:n - m], 0.0)
    nb = np.dot(bb, bb)
    r = np.empty(2 * lmax + 1)
    for j, lag in enumerate(range(-lmax, lmax + 1)):
        aa = np.where(ww, a[m + lag:n - m + lag], 0.0)
        r[j] = np.dot(aa, bb) / math.sqrt(np.dot(aa, aa) * nb)
    j = int(np.clip(np.argmax(r), 1, 2 * lmax - 1))
    y0, y1, y2 = r[j - 1:j + 2]
    den = y0 - 2 * y1 + y2
    frac = 0.5 * (y0 - y2) / den if den < 0 else 0.0
    return float(j - lmax + np.clip(frac, -1.0, 1.0)), float(r[j])


def velocity_check(x, v, dt, cutoff=25.0, mask=None, order=2):
    """Compare a measured velocity with the zero-phase derivative of displacement.

    Both are compared after the same zero-phase low-pass. Raises ``DataError`` when the gain
    is off by more than ``UNIT_TOL`` (units or sign) or the two do not correlate. A gain off
    by more than ``GAIN_TOL``, a time shift of ``SHIFT_TOL`` sample or more, or high-frequency
    noise above ``NOISE_TOL`` of the velocity RMS gives ``velocity_inconsistent`` and the
    derived velocity replaces it.
    Returns ``(velocity to use, finding or None)``.
    """
    x = np.asarray(x, dtype=float)
    v = np.asarray(v, dtype=float)
    n = x.size
    vd = derive_velocity(x, dt, cutoff, order)
    vf = lowpass(v, dt, cutoff, order)
    edge = min(n // 10, int(3.0 / (cutoff * dt)) if cutoff else 10)
    lmax = int(min(50, max(3, round(0.02 / dt)), max(1, n // 20)))
    m = edge + lmax
    w = np.ones(n, dtype=bool) if mask is None else np.array(mask, dtype=bool)
    if not w.all():
        w = ndimage.binary_erosion(w, np.ones(2 * lmax + 1, dtype=bool), border_value=1)
    w[:m] = False
    w[n - m:] = False
    nb = float(np.dot(vd[w], vd[w]))
    if nb <= 0 or w.sum() < 10:
        return v, None
    sign = 1.0 if np.dot(vf[w], vd[w]) >= 0 else -1.0
    shift, corr = _ncc_shift(sign * vf, vd, w, lmax, m)
    if corr < 0.5:
        raise DataError(f'velocity does not follow d(displacement)/dt (correlation {corr:.2f})'
                        '; check the column mapping, or pass --derive-velocity')
    k = int(round(shift))
    gain = float(np.dot(np.roll(vf, -k)[w], vd[w]) / nb)
    rms_d = math.sqrt(nb / max(int(w.sum()), 1))
    if abs(gain - 1.0) > UNIT_TOL:
        what = 'has the opposite sign of' if gain < 0 else 'disagrees with'
        raise DataError(f'velocity {what} d(displacement)/dt (gain {gain:.4g}, RMS '
                        f'{abs(gain) * rms_d:.3g} vs {rms_d:.3g} m/s); check --units '
                        'velocity=... / displacement=... and the sign convention, or pass '
                        '--derive-velocity')
    e = (v - vf)[w]
    noise = 1.4826 * float(np.median(np.abs(e - np.median(e)))) if e.size else 0.0
    ed = (vd - lowpass(vd, dt, cutoff, order))[w]
    noise_d = 1.4826 * float(np.median(np.abs(ed - np.median(ed)))) if ed.size else 0.0
    ratio = noise / rms_d if rms_d > 0 else 0.0
    skewed = abs(shift) >= SHIFT_TOL
    noisy = ratio > NOISE_TOL and noise > 3 * noise_d
    scaled = abs(gain - 1.0) > GAIN_TOL
    nums = {'gain': gain, 'shift_samples': shift, 'shift_s': shift * dt, 'noise_ratio': ratio,
            'noise_ratio_derived': noise_d / rms_d if rms_d > 0 else 0.0}
    if not (skewed or noisy or scaled):
        return v, None
    parts = []
    if scaled:
        parts.append(f'is {gain:.3f} times d(displacement)/dt')
    if skewed:
        parts.append(f'{"lags" if shift > 0 else "leads"} d(displacement)/dt by '
                     f'{abs(shift):.2f} sample(s) ({1e3 * abs(shift) * dt:.3g} ms)')
    if noisy:
        parts.append(f'carries {100 * ratio:.1f} % high-frequency noise (the derived one '
                     f'{100 * nums["noise_ratio_derived"]:.2f} %)')
    return vd, finding('velocity_inconsistent', 'velocity', 'corrected',
                       'measured velocity ' + ' and '.join(parts) + f' (gain {gain:.4f}); '
                       'replaced by the zero-phase derivative of displacement '
                       f'({"no low-pass" if cutoff is None else f"{cutoff:.3g} Hz"})', **nums)
