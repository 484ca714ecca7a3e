"""Realistic rig sensors: noise, channel delay or anti-alias filter, faults, dropouts.

Measured force (in this order)::

    F_ref  = clean force delayed by ``force_delay`` (cubic interpolation, signed, fractional)
             or through a causal 2nd-order Butterworth low-pass (``force_filter_hz``)
    F_meas = F_ref + white + AR(1) (time constant ``force_ar_tau``) + random-walk drift
             + offset, then clipped at +-rail (``clip_fraction`` x peak |F_meas|)

Displacement gets white noise [m]; velocity is ``measured`` (clean + white noise),
``derived`` (``np.gradient`` of the noisy displacement over the recorded stamps) or
``absent``; the coil current is ``measured`` (+ white noise [A]) or ``absent``. Time stamps may
be rounded to a quantum; dropouts are short runs of NaN, of the repeated last value, or of
missing rows, in every measured channel (the command is the rig computer's own and is kept).

``info['noise_rms']`` is the RMS about its mean of ``F_meas - F_ref`` over the valid samples
(not clipped, not dropped): the floor a perfect model reaches (a constant offset is absorbed
by the model's ``f0``); ``floor_nrmse = noise_rms / std(F_meas)`` over the same samples.
"""

from dataclasses import asdict, dataclass

import numpy as np
from scipy import signal
from scipy.interpolate import CubicSpline

FAULTS = ('channel_delay', 'anti_alias', 'derived_velocity', 'no_velocity', 'drift',
          'clipping', 'time_rounding', 'dropout_nan', 'dropout_hold', 'dropout_missing')
EXCLUSIVE = ({'derived_velocity', 'no_velocity'}, {'channel_delay', 'anti_alias'},
             {'dropout_nan', 'dropout_hold', 'dropout_missing'})
VELOCITY_MODES = ('measured', 'derived', 'absent')
DROPOUTS = ('none', 'nan', 'hold', 'missing')


@dataclass(frozen=True)
class SensorSpec:
    """Measurement chain of one rig (see the module docstring).

    Force noise levels are fractions of ``std(clean force)``: ``force_white``, ``force_ar``
    (AR(1), time constant ``force_ar_tau`` [s]), ``force_drift`` (RMS of a random walk that
    starts at 0), ``force_offset``. ``force_delay`` [s] (+ = the force lags the motion),
    ``force_filter_hz`` (0 = no filter). ``displacement_noise`` [m]; ``velocity`` mode and
    ``velocity_noise`` (fraction of ``std(v)``); ``current`` ('measured'/'absent') and
    ``current_noise`` [A]; ``clip_fraction`` (0 = no clipping); ``time_quantum`` [s] (0 =
    exact stamps); ``dropout`` kind, ``dropout_fraction`` of the samples, runs of 1 to
    ``dropout_run`` samples. ``faults`` names the faults drawn.
    """

    force_white: float = 0.005
    force_ar: float = 0.01
    force_ar_tau: float = 0.005
    force_drift: float = 0.0
    force_offset: float = 0.0
    force_delay: float = 0.0
    force_filter_hz: float = 0.0
    displacement_noise: float = 0.0
    velocity: str = 'measured'
    velocity_noise: float = 0.0
    current: str = 'measured'
    current_noise: float = 0.0
    clip_fraction: float = 0.0
    time_quantum: float = 0.0
    dropout: str = 'none'
    dropout_fraction: float = 0.0
    dropout_run: int = 10
    faults: tuple = ()

    def __post_init__(self):
        for k, v in asdict(self).items():
            if isinstance(v, float) and not np.isfinite(v):
                raise ValueError(f'SensorSpec: {k} must be finite, got {v}')
        for k in ('force_white', 'force_ar', 'force_drift', 'force_filter_hz',
                  'displacement_noise', 'velocity_noise', 'current_noise', 'time_quantum',
                  'dropout_fraction'):
            if getattr(self, k) < 0:
                raise ValueError(f'SensorSpec: {k} must be >= 0, got {getattr(self, k)}')
        if not self.force_ar_tau > 0:
            raise ValueError('SensorSpec: force_ar_tau must be > 0')
        if self.velocity not in VELOCITY_MODES:
            raise ValueError(f'SensorSpec: velocity must be one of {VELOCITY_MODES}')
        if self.current not in ('measured', 'absent'):
            raise ValueError("SensorSpec: current must be 'measured' or 'absent'")
        if self.dropout not in DROPOUTS:
            raise ValueError(f'SensorSpec: dropout must be one of {DROPOUTS}')
        if not 0.0 <= self.clip_fraction < 1.0:
            raise ValueError('SensorSpec: clip_fraction must be in [0, 1)')
        if self.dropout_fraction > 0.2 or self.dropout_run < 1:
            raise ValueError('SensorSpec: dropout_fraction <= 0.2 and dropout_run >= 1')
        if self.force_delay != 0.0 and self.force_filter_hz > 0.0:
            raise ValueError('SensorSpec: give force_delay or force_filter_hz, not both')

    def to_dict(self):
        """Return the spec as a plain dict."""
        d = asdict(self)
        d['faults'] = list(self.faults)
        return d


def draw_sensor(rng, faults=(), clean=False, rate=1000.0, measured_current=None):
    """Draw a ``SensorSpec`` with the named ``faults`` (``FAULTS``; None = 0-3 random ones).

    ``clean=True`` draws no fault (``faults`` must then be empty or None).

    Always: white (0.2-1 %) and AR(1) (0.5-2.5 %, 2-20 ms) force noise. Unless ``clean``:
    displacement noise 1-10 um, velocity noise 0.5-2 %, current noise 2-10 mA. Faults:
    ``channel_delay`` +-0.3-5 ms, ``anti_alias`` cut-off 0.1-0.35 ``rate``, ``drift``
    (random walk 1-5 %, offset +-10 %), ``clipping`` at 0.7-0.95 of the peak,
    ``time_rounding`` to 0.2-0.45 of the period, dropouts 0.1-0.8 % in runs of <= 20.
    ``measured_current`` None draws it (p = 0.5).
    """
    if faults is None and clean:
        faults = ()
    if faults is None:
        k = int(rng.integers(0, 4))
        pool = list(FAULTS)
        faults = []
        while len(faults) < k and pool:
            f = pool.pop(int(rng.integers(len(pool))))
            if all(not (f in ex and set(faults) & ex) for ex in EXCLUSIVE):
                faults.append(f)
    faults = tuple(faults)
    for f in faults:
        if f not in FAULTS:
            raise ValueError(f'draw_sensor: unknown fault {f!r}; known: {", ".join(FAULTS)}')
    for ex in EXCLUSIVE:
        if len(set(faults) & ex) > 1:
            raise ValueError(f'draw_sensor: faults {sorted(set(faults) & ex)} exclude each other')
    if clean and faults:
        raise ValueError('draw_sensor: clean=True draws no fault')
    if not (np.isfinite(rate) and rate > 0):
        raise ValueError('draw_sensor: rate must be > 0')
    if measured_current is None:
        measured_current = bool(rng.uniform() < 0.5)
    d = {'force_white': rng.uniform(0.002, 0.01), 'force_ar': rng.uniform(0.005, 0.025),
         'force_ar_tau': rng.uniform(0.002, 0.02),
         'current': 'measured' if measured_current else 'absent', 'faults': faults}
    if not clean:
        d['displacement_noise'] = rng.uniform(1e-6, 1e-5)
        d['velocity_noise'] = rng.uniform(0.005, 0.02)
        d['current_noise'] = rng.uniform(0.002, 0.01)
    if 'channel_delay' in faults:
        d['force_delay'] = rng.uniform(0.3e-3, 5e-3) * rng.choice([-1.0, 1.0])
    if 'anti_alias' in faults:
        d['force_filter_hz'] = rng.uniform(0.1, 0.35) * rate
    if 'derived_velocity' in faults:
        d['velocity'] = 'derived'
    if 'no_velocity' in faults:
        d['velocity'] = 'absent'
    if 'drift' in faults:
        d['force_drift'] = rng.uniform(0.01, 0.05)
        d['force_offset'] = rng.uniform(-0.1, 0.1)
    if 'clipping' in faults:
        d['clip_fraction'] = rng.uniform(0.7, 0.95)
    if 'time_rounding' in faults:
        d['time_quantum'] = rng.uniform(0.2, 0.45) / rate
    for kind in ('nan', 'hold', 'missing'):
        if 'dropout_' + kind in faults:
            d['dropout'] = kind
            d['dropout_fraction'] = rng.uniform(0.001, 0.008)
            d['dropout_run'] = int(rng.integers(5, 21))
    return SensorSpec(**{k: (float(v) if isinstance(v, (float, np.floating)) else v)
                         for k, v in d.items()})


def ar1(rng, n, dt, tau, rms):
    """AR(1) noise ``e_k = a e_(k-1) + w_k``, ``a = exp(-dt/tau)``, stationary, RMS ``rms``."""
    if n == 0 or rms <= 0:
        return np.zeros(n)
    a = float(np.exp(-dt / tau))
    w = rng.standard_normal(n) * np.sqrt(1.0 - a * a)
    zi = np.array([a * rng.standard_normal()])
    e, _ = signal.lfilter([1.0], [1.0, -a], w, zi=zi)
    return rms * e


def delayed(t, y, delay):
    """``y(t - delay)`` by a cubic spline through the samples (held beyond the ends)."""
    if delay == 0.0:
        return y.copy()
    cs = CubicSpline(t, y)
    tq = np.clip(t - delay, t[0], t[-1])
    return cs(tq)


def butter_causal(y, fc, rate):
    """Causal 2nd-order Butterworth low-pass from a steady state at ``y[0]``."""
    wn = min(fc / (0.5 * rate), 0.99)
    b, a = signal.butter(2, wn)
    zi = signal.lfilter_zi(b, a) * y[0]
    out, _ = signal.lfilter(b, a, y, zi=zi)
    return out


def _dropout_mask(rng, n, frac, run):
    mask = np.zeros(n, dtype=bool)
    target = int(round(frac * n))
    guard = 0
    while mask.sum() < target and guard < 10 * n:
        length = int(rng.integers(1, run + 1))
        start = int(rng.integers(1, max(2, n - length - 1)))
        mask[start:start + length] = True
        guard += 1
    mask[0] = False
    return mask


def apply(rng, t, clean, spec):
    """Measure a clean record; return ``(columns, info)``.

    ``clean`` holds ``force``, ``displacement``, ``velocity``, ``current_command`` and
    ``coil_current`` at the uniform times ``t``. ``columns`` uses the package's names (``time``,
    ``displacement``, ``velocity`` if present, ``force``, ``current_command``, ``current`` if
    present). ``info``: what was applied, ``rows`` (indices of the kept rows), ``valid``
    (per kept row), ``reference_force`` (delayed/filtered clean force per kept row), noise
    RMS of each component [N], ``noise_rms`` and ``floor_nrmse`` (module docstring).
    """
    t = np.asarray(t, dtype=float)
    n = t.size
    for k in ('force', 'displacement', 'velocity', 'current_command', 'coil_current'):
        if k not in clean or np.asarray(clean[k]).size != n:
            raise ValueError(f'sensors.apply: clean[{k!r}] missing or not {n} samples long')
    if n < 4:
        raise ValueError('sensors.apply: need at least 4 samples')
    dt = float((t[-1] - t[0]) / (n - 1))
    rate = 1.0 / dt
    f = np.asarray(clean['force'], dtype=float)
    sf = float(np.std(f)) or 1.0
    if spec.force_filter_hz > 0:
        ref = butter_causal(f, spec.force_filter_hz, rate)
    else:
        ref = delayed(t, f, spec.force_delay)
    white = rng.standard_normal(n) * spec.force_white * sf
    col = ar1(rng, n, dt, spec.force_ar_tau, spec.force_ar * sf)
    drift = np.zeros(n)
    if spec.force_drift > 0:
        walk = np.cumsum(rng.standard_normal(n))
        walk -= walk[0]
        drift = walk * spec.force_drift * sf / max(np.sqrt(np.mean(walk ** 2)), 1e-12)
    noise = white + col + drift + spec.force_offset * sf
    meas = ref + noise
    clipped = np.zeros(n, dtype=bool)
    rail = None
    if spec.clip_fraction > 0:
        rail = spec.clip_fraction * float(np.max(np.abs(meas)))
        clipped = np.abs(meas) > rail
        meas = np.clip(meas, -rail, rail)
    x = np.asarray(clean['displacement'], dtype=float)
    xm = x + rng.standard_normal(n) * spec.displacement_noise
    stamps = t.copy()
    if spec.time_quantum > 0:
        stamps = np.round(t / spec.time_quantum) * spec.time_quantum
    cols = {'time': stamps, 'displacement': xm}
    if spec.velocity == 'measured':
        v = np.asarray(clean['velocity'], dtype=float)
        cols['velocity'] = v + rng.standard_normal(n) * spec.velocity_noise * np.std(v)
    elif spec.velocity == 'derived':
        cols['velocity'] = np.gradient(xm, stamps)
    cols['force'] = meas
    cols['current_command'] = np.asarray(clean['current_command'], dtype=float).copy()
    if spec.current == 'measured':
        cols['current'] = (np.asarray(clean['coil_current'], dtype=float)
                           + rng.standard_normal(n) * spec.current_noise)
    drop = np.zeros(n, dtype=bool)
    if spec.dropout != 'none' and spec.dropout_fraction > 0:
        drop = _dropout_mask(rng, n, spec.dropout_fraction, spec.dropout_run)
    measured = [k for k in ('displacement', 'velocity', 'force', 'current') if k in cols]
    rows = np.arange(n)
    if spec.dropout == 'nan':
        for k in measured:
            cols[k][drop] = np.nan
    elif spec.dropout == 'hold':
        idx = np.where(drop, 0, rows)
        idx = np.maximum.accumulate(idx)
        for k in measured:
            cols[k] = cols[k][idx]
    elif spec.dropout == 'missing':
        rows = rows[~drop]
        cols = {k: v[rows] for k, v in cols.items()}
    valid_all = ~clipped & ~drop
    valid = valid_all[rows]
    err = (meas - ref)[valid_all]
    noise_rms = float(np.std(err)) if err.size > 1 else 0.0
    meas_std = float(np.std(meas[valid_all])) if err.size > 1 else 0.0
    info = {'spec': spec.to_dict(), 'faults': list(spec.faults), 'rows': rows, 'valid': valid,
            'reference_force': ref[rows], 'force_scale': sf,
            'white_rms': float(np.std(white)), 'ar_rms': float(np.std(col)),
            'drift_rms': float(np.std(drift)), 'offset': float(spec.force_offset * sf),
            'rail': rail, 'clipped': int(clipped.sum()), 'dropped': int(drop.sum()),
            'noise_rms': noise_rms,
            'floor_nrmse': noise_rms / meas_std if meas_std > 0 else float('nan')}
    return cols, info
