"""Rig records: loaders (CSV/text, MATLAB .mat, rosbag2), column/unit mapping and input checks.

A record holds SI arrays on a uniform time base: ``time`` [s], ``displacement`` [m] (+ =
extension), ``velocity`` [m/s], ``force`` [N] (+ resists extension), the input current ``i_in``
[A] the force model sees before current dynamics (the measured coil ``current`` when present,
else the command through the driver's static map: a ``current_command`` is taken as the coil
current, a ``voltage_command`` goes through ``core.driver.static_current``), and optionally
``temperature``. When no velocity is given it is derived from displacement by a zero-phase
Butterworth low-pass and central differences; the cut-off is ``velocity_cutoff`` (2nd order)
or, by default, 1.6x the edge of the data's motion band (4th order, ``sensors.motion_band``),
which also cleans a measured velocity's white noise above that band. The filter has no phase
lag, so it cannot fake a delay or a hysteresis.

The vrths rig files (``<amp>mm<freq>Hz<current>A.txt``, headerless time/displacement mm/
velocity mm/s/force N) and ``validacion.mat`` (``data``: displacement mm, then force at 0.2..1.0
A) are recognised by name and load through the same path (``preset='vrths'``).
"""

from dataclasses import dataclass, field, replace
import math
from pathlib import Path
import re
import warnings

import numpy as np
from scipy import io as sio

from mr_suspension.identification import sensors
from mr_suspension.identification.errors import DataError
from mr_suspension.identification.sensors import derive_velocity


CANONICAL = ('time', 'displacement', 'velocity', 'force', 'current_command', 'voltage_command',
             'current', 'temperature')
UNITS = {
    'time': {'s': 1.0, 'ms': 1e-3},
    'displacement': {'m': 1.0, 'mm': 1e-3, 'cm': 1e-2},
    'velocity': {'m/s': 1.0, 'mm/s': 1e-3, 'cm/s': 1e-2},
    'force': {'n': 1.0, 'kn': 1e3},
    'current_command': {'a': 1.0, 'ma': 1e-3},
    'current': {'a': 1.0, 'ma': 1e-3},
    'voltage_command': {'v': 1.0, 'mv': 1e-3},
    'temperature': {'c': 1.0, 'degc': 1.0, 'k': 1.0},
}
MIN_SAMPLES = 200
MIN_DURATION = 1.0
SET_CHANNELS = ('current_command', 'voltage_command', 'current', 'temperature')
NO_MOTION = 1e-4         # [m] 1-99 % displacement span below which nothing moved
NO_MOTION_V = 1e-4       # [m/s] velocity RMS below which nothing moved
VRTHS_TXT = re.compile(r'(\d+(?:x\d+)?)mm(\d+(?:x\d+)?)Hz(\d+(?:x\d+)?)A', re.IGNORECASE)
VRTHS_MAT_CURRENTS = (0.2, 0.4, 0.6, 0.8, 1.0)


@dataclass(frozen=True)
class Record:
    """One rig record in SI units on a uniform time base (see the module docstring).

    ``mask`` marks usable samples (False: dropout, clipping, spike, and the
    ``velocity_edge`` samples at each end whose low-passed velocity is one-sided; those are
    linearly filled so that model states can run through them, never scored). ``findings`` are the
    sensor findings (``sensors``). ``stamps`` are the input rows' own times relative to the
    first and ``stamp_index`` their grid samples (None when the rows were resampled).
    ``velocity_pred``: the velocity a prediction takes when it is not ``velocity`` (a noisy
    measured or derived velocity, ``for_prediction``),
    else None.
    """

    name: str
    time: np.ndarray
    displacement: np.ndarray
    velocity: np.ndarray
    force: np.ndarray
    i_in: np.ndarray
    input_kind: str
    dt: float
    command: np.ndarray = None
    temperature: np.ndarray = None
    velocity_source: str = 'measured'
    meta: dict = field(default_factory=dict)
    mask: np.ndarray = None
    findings: tuple = ()
    stamps: np.ndarray = None
    stamp_index: np.ndarray = None
    velocity_edge: int = 0
    velocity_pred: np.ndarray = None

    def __post_init__(self):
        """Fill the defaults: ``mask`` all True, ``stamps`` = ``time`` (one row per sample)."""
        if self.mask is None:
            object.__setattr__(self, 'mask', np.ones(self.time.shape[0], dtype=bool))
        if self.stamps is None:
            object.__setattr__(self, 'stamps', self.time)
            object.__setattr__(self, 'stamp_index', np.arange(self.time.shape[0]))

    @property
    def n(self):
        """Number of samples."""
        return int(self.time.shape[0])

    @property
    def duration(self):
        """Record length [s]."""
        return float(self.n * self.dt)


@dataclass(frozen=True)
class LoadOptions:
    """How to read files: column names (canonical -> file column), units, preset, filter.

    ``need_force=False`` (``predict``) ignores any force column and skips the force checks.
    """

    columns: dict = field(default_factory=dict)
    units: dict = field(default_factory=dict)
    preset: str = 'auto'
    velocity_cutoff: float = None  # [Hz]; None: from the motion band (sensors.motion_cutoff)
    derive_velocity: bool = False
    use_measured_current: bool = True
    need_force: bool = True


def parse_mapping(items, what):
    """Parse ``['force=F_kN', 'time=t']`` (or one comma-separated string) into a dict."""
    out = {}
    if not items:
        return out
    if isinstance(items, str):
        items = [items]
    for item in items:
        for part in str(item).split(','):
            part = part.strip()
            if not part:
                continue
            if '=' not in part:
                raise DataError(f'{what}: expected NAME=VALUE, got {part!r}')
            key, value = (s.strip() for s in part.split('=', 1))
            if key not in CANONICAL:
                raise DataError(f'{what}: unknown quantity {key!r}; known: {", ".join(CANONICAL)}')
            out[key] = value
    return out


def _grid_mask(base, row_mask, gap_mask, n):
    """Usable samples of the uniform grid from the ``n`` input rows' ``row_mask``."""
    row_mask = np.broadcast_to(np.asarray(row_mask, dtype=bool), (n,))
    if base.resampled:
        bad_rows = np.flatnonzero(~row_mask)
        mask = np.ones(base.time.size, dtype=bool)
        if bad_rows.size:
            j = np.searchsorted(base.stamps, base.time)
            bad = np.zeros(n + 1, dtype=bool)
            bad[bad_rows] = True
            mask = ~(bad[np.clip(j, 0, n - 1)] | bad[np.clip(j - 1, 0, n - 1)])
        return mask
    mask = gap_mask.copy()
    mask[base.index] = row_mask
    return mask


def _pred_text(share, mask):
    """Describe ``sensors.directional_velocity``'s estimate by the local fits' weight."""
    most = 100.0 * float(np.mean(share[mask] > 0.5))
    return ('the ladder of zero-phase low-passes and local quadratic fits over past, centred '
            'and future windows, each as long as the data allow (intersection of confidence '
            f'intervals), fused by inverse variance (the local fits weigh most on {most:.3g} % '
            'of samples)')


def _derived_pred(x, dt, cut, opts, vsrc, mask):
    """Prediction velocity of a derived one (``Record.velocity_pred``) and its description.

    The central difference of ``x`` through ``sensors.directional_velocity`` (the low-pass
    ladder from the motion band's ``cut`` down, fused with past, centred and future local
    quadratic fits); None with the user's cut-off or none.
    """
    if opts.velocity_cutoff or cut is None:
        return None, vsrc
    noise = sensors.velocity_noise(x, None, dt)
    if not np.std(noise) > 0:
        return None, vsrc
    v_pred, share = sensors.directional_velocity(np.gradient(x, dt), dt, cut, noise, mask)
    return v_pred, vsrc + '; for predictions ' + _pred_text(share, mask)


def velocity_edge(cutoff, dt, n):
    """Count the one-sided samples at each end of a velocity low-passed at ``cutoff`` [Hz].

    Half a period of the cut-off, ``ceil(0.5 / (cutoff dt))``; 0 without a low-pass or for a
    record shorter than 40 times that.
    """
    if cutoff is None or not cutoff < sensors.LOWPASS_MAX / dt:
        return 0
    k = int(math.ceil(0.5 / (cutoff * dt)))
    return k if n >= 40 * k else 0


def velocity_band(x, dt, opts):
    """Cut-off [Hz] and filter order for velocities: the user's, else the motion band's."""
    if opts.velocity_cutoff:
        return opts.velocity_cutoff, 2
    return sensors.motion_cutoff(x, dt), 4


def _unit_factor(name, unit):
    table = UNITS[name]
    key = unit.strip().lower().replace(' ', '')
    if key not in table:
        raise DataError(f'unit {unit!r} not known for {name}; use one of {sorted(table)}')
    return table[key]


def _check_nan_budget(name, label, fnd, n):
    """Raise ``DataError`` when a channel's NaN/inf values are too many or too scattered."""
    if fnd is None or not fnd.get('nan_samples'):
        return
    bad, nruns = fnd['nan_samples'], fnd['nan_runs']
    if bad >= n or bad > 0.25 * n or (bad > 0.01 * n and nruns > max(10, 0.001 * n)):
        raise DataError(f'{label}: {bad} of {n} {name} values are NaN/inf ({100 * bad / n:.1f} '
                        f'%, {nruns} runs); clean the record (scattered NaN above 1 % or any '
                        'above 25 % cannot be masked)')


def _time_units(name, t, opts):
    """Median step of ``t`` in s: a step >= 0.05 s is ms read as s (converted) or an error."""
    step = float(np.median(np.diff(t)))
    if step < 0.05:
        return t
    if 'time' in opts.units or step > 50.0:
        raise DataError(f'{name}: median time step {step:.3g} s ({1 / step:.3g} Hz) is too slow '
                        'for a damper rig record; if time is in ms pass --units time=ms')
    warnings.warn(f'{name}: median time step {step:.3g} would mean {1 / step:.3g} Hz sampling, '
                  f'too slow for a damper rig; time taken as ms ({1e3 / step:.4g} Hz). Pass '
                  '--units time=ms to confirm, or --units time=s to refuse')
    return t * 1e-3


def _on_grid(base, y):
    """Input rows ``y`` placed on the time base (gaps/resampling filled linearly)."""
    if base.index is None:
        return None
    if base.index.size == base.time.size:
        return y
    out = np.interp(np.arange(base.time.size), base.index, y)
    out[base.index] = y
    return out


def _consistent_holds(cols, t, opts):
    """Mark samples where a held displacement or velocity agrees with the other sensor.

    A displacement hold is genuine where the measured velocity is ~0; a velocity hold where
    the velocity derived from displacement has the held value (constant-speed ramps).
    """
    x, v = cols['displacement'], cols['velocity']
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(v))):
        return {}
    dt = float(np.median(np.diff(t)))
    vg = np.gradient(x, dt)
    scale = float(np.sqrt(np.mean(derive_velocity(x, dt, opts.velocity_cutoff or 25.0) ** 2)))
    return {'displacement': np.abs(v) <= 0.05 * scale,
            'velocity': np.abs(vg - v) <= 0.1 * scale}


def check_time(name, t):
    """Return ``t`` if finite and strictly increasing, else raise a ``DataError`` (row named)."""
    if not np.all(np.isfinite(t)):
        raise DataError(f'{name}: time contains NaN/inf')
    dts = np.diff(t)
    if np.any(dts <= 0):
        k = int(np.argmax(dts <= 0))
        raise DataError(f'{name}: time is not strictly increasing (row {k + 1}: {t[k]} -> '
                        f'{t[k + 1]}); sort or split the record')
    return t


def build_record(name, cols, opts=None, meta=None):
    """Check raw SI columns (dict canonical -> array) and return a ``Record``.

    Raises ``DataError`` for missing columns, non-monotonic or too slow time, too short records,
    too many NaN/spikes, no motion and implausible units; warns for every sensor finding (see
    ``sensors``), time read as ms and suspicious scales. Masked samples are linearly filled.
    """
    opts = opts or LoadOptions()
    cols = dict(cols)
    if not opts.need_force:
        cols.pop('force', None)
        if 'time' in cols:
            cols['force'] = np.zeros(np.asarray(cols['time']).size)
    missing = [c for c in ('time', 'displacement', 'force') if c not in cols]
    if missing:
        raise DataError(f'{name}: missing column(s) {missing}; found {sorted(cols)}. Map names '
                        f'with --columns force=MyForce,... (quantities: {", ".join(CANONICAL)})')
    if not any(c in cols for c in ('current_command', 'voltage_command', 'current')):
        raise DataError(f'{name}: no current_command, voltage_command or current column; found '
                        f'{sorted(cols)}. Map one with --columns current_command=NAME')
    cols = {k: np.asarray(v, dtype=float).ravel() for k, v in cols.items()}
    n = cols['time'].size
    for k, v in cols.items():
        if v.size != n:
            raise DataError(f'{name}: column {k} has {v.size} samples, time has {n}')
    if n < MIN_SAMPLES:
        raise DataError(f'{name}: too short ({n} samples); need at least {MIN_SAMPLES}')
    t = check_time(name, cols['time'])
    t = _time_units(name, t, opts)
    if t[-1] - t[0] < MIN_DURATION:
        raise DataError(f'{name}: too short ({t[-1] - t[0]:.3f} s); need >= {MIN_DURATION} s')
    findings = []
    row_mask = np.ones(n, dtype=bool)
    measured_v = 'velocity' in cols and not opts.derive_velocity
    checked = [k for k in ('force', 'displacement', 'velocity', 'current', 'current_command',
                           'voltage_command', 'temperature') if k in cols]
    if not opts.need_force:
        checked.remove('force')
    still = _consistent_holds(cols, t, opts) if measured_v else {}
    own = {}  # each channel's own unusable samples (its motion is bridged over them)
    for k in checked:
        y = cols[k]
        ok = np.isfinite(y)
        if not ok.any():
            raise DataError(f'{name}: every {k} value is NaN/inf')
        good = ok
        fnd = fs = fc = None
        if k in SET_CHANNELS:
            # set values (and a coil current following them) legitimately hold: NaN runs only
            _, fnd = sensors.dropouts(k, y, frozen=False)
        else:
            ms, fs = sensors.spikes(k, sensors.fill(y, ok))
            ms |= ~ok
            if fs is not None and fs['fraction'] > 0.01:
                raise DataError(f'{name}: {fs["detail"].replace("; masked", "")}: '
                                f'{100 * fs["fraction"]:.1f} % of the samples; check the sensor '
                                'and its units (at most 1 % can be excluded)')
            good, fnd = sensors.dropouts(k, y, still.get(k), exclude=~ms)
            mc, fc = sensors.clipping(k, np.where(ms, y, np.nan), still.get(k))
            good &= ms & mc
        _check_nan_budget(k, name, fnd, n)
        if not good.all():
            cols[k] = sensors.fill(np.where(good, y, 0.0), good)
            row_mask &= good
            own[k] = good
        findings.extend(f for f in (fnd, fs, fc) if f is not None)
    mf, ff = sensors.frame_holds({k: cols[k] for k in ('force', 'displacement', 'velocity')
                                  if k in checked})
    if ff is not None:
        findings.append(ff)
        row_mask &= mf
    base, ft = sensors.uniform_time(t)
    gap_mask, fg = sensors.missing_rows(base)
    findings.extend(f for f in (ft, fg) if f is not None)
    if base.resampled:
        for k in list(cols):
            if k != 'time':
                cols[k] = np.interp(base.time, base.stamps, cols[k])
    else:
        for k in list(cols):
            if k != 'time':
                cols[k] = _on_grid(base, cols[k])
    mask = _grid_mask(base, row_mask, gap_mask, n)
    held = True if mf is None else mf  # a frozen frame holds every motion channel
    for k in ('displacement', 'velocity'):
        if k not in cols:
            continue
        # A gap or a frozen frame in the motion: bridged smoothly (a line leaves kinks that
        # the velocity's derivative and low-pass spread over the usable samples around it).
        motion_ok = _grid_mask(base, own.get(k, True) & held, gap_mask, n)
        if not motion_ok.all():
            cols[k] = sensors.fill_motion(cols[k], motion_ok)
    for fnd in findings:
        warnings.warn(f'{name}: {fnd["finding"]}: {fnd["detail"]}')
    if mask.mean() < 0.5:
        raise DataError(f'{name}: only {100 * mask.mean():.1f} % of the samples are usable after '
                        'masking dropouts, clipping and spikes; fix the record')
    dt = base.dt
    x = cols['displacement']
    f = cols['force']
    xm = x[mask]
    if np.max(np.abs(xm)) > 0.5:
        raise DataError(f'{name}: displacement reaches {np.max(np.abs(xm)):.3g} m, implausible '
                        'for a damper; if it is in mm pass --units displacement=mm')
    lo, hi = np.percentile(xm, [1, 99])
    if hi - lo < NO_MOTION:
        raise DataError(f'{name}: no motion: displacement spans {1e3 * (hi - lo):.3g} mm (1-99 % '
                        f'range, need >= {1e3 * NO_MOTION:g} mm); a damper force needs stroke '
                        'velocity: check the displacement column and its units')
    if opts.need_force:
        if np.std(f[mask]) < 1e-9:
            raise DataError(f'{name}: force is constant; nothing to identify')
        if np.max(np.abs(f[mask])) < 20.0:
            warnings.warn(f'{name}: peak force only {np.max(np.abs(f[mask])):.3g} N; if the file '
                          'is in kN pass --units force=kN (parameters would be 1000x too small)')
    vsrc = 'measured'
    v_pred = None  # the velocity predictions use, when not ``v`` (``Record.velocity_pred``)
    top = None  # the cut-off of a low-pass the velocity went through
    cut, order = velocity_band(x, dt, opts)
    band = 'no low-pass' if cut is None else f'zero-phase Butterworth order {order} {cut:.3g} Hz'
    derived = f'derived ({band})'
    if measured_v:
        try:
            v, fv = sensors.velocity_check(x, cols['velocity'], dt, cut, mask, order)
        except DataError as exc:
            raise DataError(f'{name}: {exc}') from None
        if fv is not None:
            findings.append(fv)
            warnings.warn(f'{name}: {fv["finding"]}: {fv["detail"]}')
            top = cut
            vsrc = derived + '; measured velocity replaced'
            v_pred, vsrc = _derived_pred(x, dt, cut, opts, vsrc, mask)
        elif not opts.velocity_cutoff:
            # White sensor noise above the motion band only scatters the yield branch.
            vrms = float(np.sqrt(np.mean(v[mask] ** 2)))
            vcut, removed = sensors.motion_band(v, dt)
            if vcut is not None and removed > 1e-3 * vrms:
                # (clean data are left exactly as they are) The displacement's derivative is
                # the better rate below the crossover f_c; what noise is left above the
                # motion band is then cut.
                v_raw = v
                v, fc = sensors.fuse_velocity(x, v, dt)
                parts = [] if fc is None else \
                    [f'fused with d(displacement)/dt below {fc:.3g} Hz (Wiener weights)']
                vcut, removed = sensors.motion_band(v, dt)
                if vcut is not None and removed > 1e-3 * vrms:
                    noise = sensors.measured_velocity_noise(x, v_raw, dt, fc)
                    if noise is not None:
                        v_pred, share = sensors.directional_velocity(v, dt, vcut, noise, mask)
                    v = sensors.smooth_velocity(v, dt, vcut)
                    top = vcut
                    parts.append(f'zero-phase Butterworth order 4 {vcut:.3g} Hz: noise '
                                 f'above the motion band removed, {removed:.3g} m/s RMS')
                    if v_pred is not None:
                        parts.append('for predictions ' + _pred_text(share, mask))
                vsrc = f'measured ({"; ".join(parts)})' if parts else vsrc
    else:
        v = derive_velocity(x, dt, cut, order)
        vsrc = derived
        top = cut
        v_pred, vsrc = _derived_pred(x, dt, cut, opts, vsrc, mask)
    edge = velocity_edge(top, dt, mask.size)
    if edge:
        # Within half a period of the cut-off from either end the zero-phase filter has
        # one side only: that velocity is an extrapolation (errors of several mm/s, where a
        # yield force turns within a few), so those samples are neither fitted nor scored.
        mask = mask.copy()
        mask[:edge] = False
        mask[-edge:] = False
        vsrc += f'; its first and last {edge} samples (one-sided filter) excluded'

    vrms = float(np.sqrt(np.mean(v[mask] ** 2)))
    if vrms < NO_MOTION_V:
        raise DataError(f'{name}: no motion: velocity RMS {1e3 * vrms:.3g} mm/s (need >= '
                        f'{1e3 * NO_MOTION_V:g} mm/s); nothing to identify')
    command = None
    if 'current_command' in cols:
        command = cols['current_command']
        kind = 'current_command'
    elif 'voltage_command' in cols:
        from mr_suspension.core.driver import DriverParams, static_current  # numba: lazily

        volt = cols['voltage_command']
        dp = DriverParams().to_array()
        command = np.array([static_current(dp, float(u)) for u in volt])
        kind = 'voltage_command'
    if 'current' in cols and (opts.use_measured_current or command is None):
        i_in = cols['current']
        kind = 'current'
    else:
        i_in = command
    if np.max(np.abs(i_in)) > 10.0:
        warnings.warn(f'{name}: current reaches {np.max(np.abs(i_in)):.3g} A; if it is in mA '
                      'pass --units current_command=mA')
    if np.min(i_in) < -0.05 * max(float(np.max(np.abs(i_in))), 1e-3):
        warnings.warn(f'{name}: current goes negative (down to {np.min(i_in):.3g} A); an MR '
                      'coil is driven with a current >= 0 and the force law uses the signed '
                      'value: check the sign convention of the current column')
    return Record(name=name, time=base.time, displacement=x, velocity=v, force=f, i_in=i_in,
                  input_kind=kind, dt=dt, command=command, temperature=cols.get('temperature'),
                  velocity_source=vsrc, meta=dict(meta or {}), mask=mask,
                  findings=tuple(findings), stamps=base.stamps, stamp_index=base.index,
                  velocity_edge=edge, velocity_pred=v_pred)


def _apply_units(cols, units, defaults=None):
    units = dict(defaults or {}, **(units or {}))
    out = {}
    for k, v in cols.items():
        out[k] = np.asarray(v, dtype=float)
        if k in units:
            out[k] = out[k] * _unit_factor(k, units[k])
    return out


def _vrths_value(token):
    return float(token.replace('x', '.'))


ALIASES = {'time': ('t', 'timestamp'), 'displacement': ('disp', 'stroke', 'position'),
           'velocity': ('vel', 'stroke_rate', 'speed'), 'force': ('load', 'damper_force'),
           'current_command': ('current_cmd', 'i_cmd', 'command'),
           'voltage_command': ('voltage_cmd', 'u_cmd', 'voltage'),
           'current': ('coil_current', 'i_coil', 'measured_current'),
           'temperature': ('temp',)}
_BRACKET = re.compile(r'^(.*?)\s*[\[(]\s*([^\])]*?)\s*[\])]\s*$')


def _norm_unit(unit):
    return unit.strip().lower().replace(' ', '').replace('\u00b0', 'deg').replace('degc', 'c')


def _header_name(h):
    """``(name, unit or None)`` of a header cell: ``Time [s]``, ``Force_N``, ``force (kN)``."""
    h = h.strip().strip('"\'').strip()
    m = _BRACKET.match(h)
    if m:
        return m.group(1).strip().lower().replace(' ', '_').replace('-', '_'), m.group(2)
    return h.lower().replace(' ', '_').replace('-', '_'), None


def map_header(header, opts, label):
    """Map header cells to quantities: ``({quantity: column index}, {quantity: unit})``.

    ``--columns`` names match exactly, then case-insensitively; other cells match a quantity
    (or a common alias) case-insensitively, with a unit in brackets or as a ``_unit`` suffix
    (``Time [s]``, ``Force_N``, ``velocity_mm_s``). Header units apply unless ``--units``
    gives one.
    """
    cols, units, prio = {}, {}, {}
    lower = [h.strip().strip('"\'').strip().lower() for h in header]
    for canon, src in opts.columns.items():
        if src in header:
            cols[canon] = header.index(src)
        elif src.lower() in lower:
            cols[canon] = lower.index(src.lower())
        else:
            raise DataError(f'{label}: mapped column {src!r} for {canon} not in header {header}')
    taken = set(cols.values())
    for j, h in enumerate(header):
        if j in taken:
            continue
        name, unit = _header_name(h)
        for canon in CANONICAL:
            if canon in opts.columns:
                continue
            for rank, alias in enumerate((canon,) + ALIASES[canon]):
                u = unit
                rank *= 2
                if name != alias:
                    rank += 1
                    if not name.startswith(alias + '_') or unit is not None:
                        continue
                    u = name[len(alias) + 1:]
                    if _norm_unit(u.replace('_', '/')) in UNITS[canon]:
                        u = u.replace('_', '/')
                    elif _norm_unit(u) not in UNITS[canon]:
                        continue
                if u is not None and _norm_unit(u) not in UNITS[canon]:
                    raise DataError(f'{label}: header {h!r} gives unit {u!r}, not known for '
                                    f'{canon} ({sorted(UNITS[canon])}); pass --units '
                                    f'{canon}=UNIT')
                if canon in cols and prio[canon] == rank:
                    raise DataError(f'{label}: columns {header[cols[canon]]!r} and {h!r} both '
                                    f'look like {canon}; choose with --columns {canon}=NAME')
                if canon not in cols or rank < prio[canon]:
                    cols[canon], prio[canon] = j, rank
                    if u is not None:
                        units[canon] = _norm_unit(u)
                    else:
                        units.pop(canon, None)
                break
    return cols, {k: u for k, u in units.items() if k not in opts.units}


def _split(line, delim):
    return [c.strip().strip('"') for c in (line.split(delim) if delim else line.split())]


def _read_table_slow(path, header, delim, skip):
    """Line-by-line parser: empty fields are NaN, a bad line is named in the error."""
    with open(path, encoding='utf-8-sig', errors='replace') as fh:
        lines = fh.read().splitlines()[skip:]
    rows = []
    for k, ln in enumerate(lines):
        if not ln.strip() or ln.lstrip().startswith('#'):
            continue
        try:
            rows.append([float(c) if c not in ('', 'nan', 'NaN') else math.nan
                         for c in _split(ln, delim)])
        except ValueError:
            raise DataError(f'{path}: non-numeric value on data line {k + 1}: {ln[:60]!r}')
    if not rows:
        raise DataError(f'{path}: no data rows')
    width = len(header) if header else len(rows[0])
    if any(len(r) != width for r in rows):
        raise DataError(f'{path}: rows have different numbers of columns')
    return np.array(rows, dtype=float).reshape(-1, width)


def _read_table(path):
    """``(header or None, 2-D table)`` of a CSV/whitespace text file (``np.loadtxt`` fast path)."""
    first, skip = None, 0
    with open(path, encoding='utf-8-sig', errors='replace') as fh:
        for line in fh:
            skip += 1
            if line.strip() and not line.lstrip().startswith('#'):
                first = line.strip()
                break
    if first is None:
        raise DataError(f'{path}: empty file')
    delim = ',' if ',' in first else (';' if ';' in first else ('\t' if '\t' in first else None))
    cells = _split(first, delim)
    try:
        [float(c) for c in cells]
        header = None
        skip -= 1
    except ValueError:
        header = cells
    try:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            table = np.loadtxt(path, delimiter=delim, skiprows=skip, comments='#', ndmin=2,
                               dtype=float, encoding='utf-8-sig')
        if header and table.shape[1] != len(header) or table.shape[0] == 0:
            raise ValueError('shape')
    except ValueError:
        table = _read_table_slow(path, header, delim, skip)
    return header, table


def load_text(path, opts=None):
    """Load a CSV/whitespace table with a header (or a vrths sine file) as one ``Record``."""
    opts = opts or LoadOptions()
    path = Path(path)
    header, table = _read_table(path)
    m = VRTHS_TXT.search(path.name)
    if header is None:
        if opts.preset in ('auto', 'vrths') and m and table.shape[1] == 4:
            cols = dict(zip(('time', 'displacement', 'velocity', 'force'), table.T))
            cols['current_command'] = np.full(table.shape[0], _vrths_value(m.group(3)))
            cols = _apply_units(cols, opts.units, {'displacement': 'mm', 'velocity': 'mm/s'})
            meta = {'amplitude_mm': _vrths_value(m.group(1)),
                    'frequency_hz': _vrths_value(m.group(2)), 'preset': 'vrths'}
            return build_record(path.name, cols, opts, meta)
        raise DataError(f'{path}: no header row; the CSV needs a header naming the columns '
                        f'({", ".join(CANONICAL)})')
    index, units = map_header(header, opts, path)
    if units:
        opts = replace(opts, units={**units, **opts.units})
    cols = {}
    for canon, j in index.items():
        cols[canon] = np.array(table[:, j])          # contiguous copy; the table is freed
        if canon in opts.units:
            cols[canon] *= _unit_factor(canon, opts.units[canon])
    del table
    return build_record(path.name, cols, opts)


def load_mat(path, opts=None):
    """Load a MATLAB file: vrths ``validacion.mat`` (5 records) or named 1-D variables."""
    opts = opts or LoadOptions()
    path = Path(path)
    try:
        mat = sio.loadmat(str(path))
    except Exception as exc:  # scipy raises several types for unreadable files
        raise DataError(f'{path}: cannot read MATLAB file ({exc})')
    keys = [k for k in mat if not k.startswith('__')]
    data = mat.get('data')
    if (opts.preset == 'vrths' or (opts.preset == 'auto' and keys == ['data']
                                   and data is not None and data.ndim == 2
                                   and data.shape[1] == 6)):
        n = data.shape[0]
        t = np.arange(n) * 1e-3
        recs = []
        for j, cur in enumerate(VRTHS_MAT_CURRENTS):
            cols = {'time': t, 'displacement': data[:, 0] * 1e-3, 'force': data[:, j + 1],
                    'current_command': np.full(n, cur)}
            cols = _apply_units(cols, {k: u for k, u in opts.units.items() if k == 'force'})
            recs.append(build_record(f'{path.name}[{cur:g}A]', cols, opts,
                                     {'preset': 'vrths-validation'}))
        return recs
    cols = {}
    for canon in CANONICAL:
        src = opts.columns.get(canon, canon)
        if src in mat:
            try:
                cols[canon] = np.asarray(mat[src], dtype=float).ravel()
            except (TypeError, ValueError):
                raise DataError(f'{path}: variable {src!r} ({canon}) is not numeric '
                                f'({np.asarray(mat[src]).dtype}); store it as a numeric vector')
    return [build_record(path.name, _apply_units(cols, opts.units), opts)]


def _msg_values(msg, quantity):
    """Quantities carried by one message: a Float64 ``data`` field or a ``JointState``."""
    if hasattr(msg, 'data'):
        return {quantity: float(np.asarray(msg.data, dtype=float).ravel()[0])}
    if hasattr(msg, 'effort') or hasattr(msg, 'position'):
        pos = list(getattr(msg, 'position', []))
        vel = list(getattr(msg, 'velocity', []))
        eff = list(getattr(msg, 'effort', []))
        out = {}
        if quantity == 'force':
            if eff:
                out['force'] = float(eff[0])
            if pos:
                out['displacement_alt'] = float(pos[0])
            if vel:
                out['velocity_alt'] = float(vel[0])
        else:
            if pos:
                out[quantity] = float(pos[0])
            if vel and quantity == 'displacement':
                out['velocity_alt'] = float(vel[0])
        return out
    for name in getattr(msg, '__dataclass_fields__', {}):
        val = getattr(msg, name)
        if isinstance(val, (int, float)):
            return {quantity: float(val)}
    raise DataError(f'cannot read a number from message type {type(msg).__name__}')


def _topic_quantity(topic, opts):
    for canon, src in opts.columns.items():
        if topic == src:
            return canon
    t = topic.lower()
    if any(k in t for k in ('tyre', 'tire', 'truth', 'imu', 'clock')):
        return None
    if 'command' in t or 'cmd' in t:
        return 'voltage_command' if 'volt' in t else 'current_command'
    for key, canon in (('force', 'force'), ('stroke_rate', 'velocity'), ('velocity', 'velocity'),
                       ('stroke', 'displacement'), ('displacement', 'displacement'),
                       ('temperature', 'temperature'), ('current', 'current')):
        if key in t:
            return canon
    return None


def _stamp(msg, bag_ns):
    header = getattr(msg, 'header', None)
    if header is not None:
        ns = header.stamp.sec * 1_000_000_000 + header.stamp.nanosec
        if ns > 0:
            return ns * 1e-9
    return bag_ns * 1e-9


def load_bag(path, opts=None):
    """Load a rosbag2 (sqlite3 or mcap) recorded by the node set as one ``Record``.

    Topics are matched by name (``stroke``/``displacement``, ``damper/force``, ``command``,
    ``coil_current``, ``velocity``/``stroke_rate``, ``temperature``; truth, tyre, IMU and clock
    topics are ignored; or ``--columns force=/my/topic``). Values are ``msg.data``
    (Float64) or, for ``JointState``, ``position[0]``/``velocity[0]`` and ``effort[0]`` on
    the force topic (the actuator also reports stroke and rate there). Times are header
    stamps when present, else bag stamps (sim time in lockstep). The force messages are the
    rows; the other signals are interpolated at their stamps (commands held); the rows then
    go through the same time-base checks as a file. An unreadable bag is a ``DataError``
    that says to run ``mr-suspension bag repair BAG``.
    """
    opts = opts or LoadOptions()
    try:
        series = _read_bag(path, opts)
    except DataError:
        raise
    except Exception as exc:  # rosbags/mcap/yaml/sqlite raise many types for damaged bags
        msg = ' '.join(str(exc).split())[:160] or type(exc).__name__
        raise DataError(f'{path}: cannot read the bag ({type(exc).__name__}: {msg}); run '
                        f'`mr-suspension bag repair {path}` and load the repaired bag') from None
    for alt in ('displacement', 'velocity'):
        if alt + '_alt' in series:
            if alt not in series:
                series[alt] = series[alt + '_alt']
            del series[alt + '_alt']
    if 'force' not in series:
        raise DataError(f'{path}: no force topic; found quantities {sorted(series)}')
    t = np.unique(np.array(series['force'][0]))
    if t.size < 2:
        raise DataError(f'{path}: too few force messages')
    dt = float(np.median(np.diff(t)))
    cols = {'time': t}
    for q, (ts, vs) in series.items():
        ts = np.array(ts)
        vs = np.array(vs)
        order = np.argsort(ts, kind='stable')
        ts, vs = ts[order], vs[order]
        if q in ('current_command', 'voltage_command'):
            idx = np.clip(np.searchsorted(ts, t + 0.01 * dt, side='right') - 1, 0, ts.size - 1)
            cols[q] = vs[idx]
        elif q == 'force':
            keep = np.concatenate((np.diff(ts) > 0, [True]))
            cols[q] = vs[keep]
        else:
            cols[q] = np.interp(t, ts, vs)
    return build_record(Path(path).name, _apply_units(cols, opts.units), opts)


def _read_bag(path, opts):
    """Time series ``{quantity: ([t], [value])}`` of the recognised topics of a bag."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import get_typestore, Stores

    series = {}
    with AnyReader([Path(path)], default_typestore=get_typestore(Stores.LATEST)) as reader:
        if not reader.connections or not reader.message_count:
            raise DataError(f'{path}: no messages in the bag')
        conns = [c for c in reader.connections if _topic_quantity(c.topic, opts)]
        if not conns:
            topics = [c.topic for c in reader.connections]
            raise DataError(f'{path}: no recognised topics in {topics}')
        for conn, stamp, raw in reader.messages(connections=conns):
            q = _topic_quantity(conn.topic, opts)
            msg = reader.deserialize(raw, conn.msgtype)
            ts = _stamp(msg, stamp)
            for key, val in _msg_values(msg, q).items():
                series.setdefault(key, ([], []))
                series[key][0].append(ts)
                series[key][1].append(val)
    return series


def load_path(path, opts=None):
    """Load one path (file or bag directory) into a list of ``Record``."""
    path = Path(path)
    if not path.exists():
        raise DataError(f'{path}: no such file or directory')
    suffix = path.suffix.lower()
    if path.is_dir() or suffix in ('.mcap', '.db3'):
        return [load_bag(path, opts)]
    if suffix == '.mat':
        return load_mat(path, opts)
    return [load_text(path, opts)]


def load_records(paths, opts=None):
    """Load every path (directories of text files are expanded unless they are bags)."""
    recs = []
    for p in paths:
        p = Path(p)
        storage = p.is_dir() and any(q.suffix.lower() in ('.mcap', '.db3') for q in p.iterdir())
        if p.is_dir() and not (p / 'metadata.yaml').exists() and not storage:
            files = sorted(q for q in p.iterdir() if q.suffix.lower() in ('.csv', '.txt', '.mat'))
            if not files:
                raise DataError(f'{p}: directory without .csv/.txt/.mat files or bag metadata')
            for q in files:
                recs.extend(load_path(q, opts))
        else:
            recs.extend(load_path(p, opts))
    if not recs:
        raise DataError('no records loaded')
    return recs


def decimate(rec, q):
    """Every ``q``-th sample of a record (signals are smooth at the rig rates; no filter).

    The mask keeps the kept samples' own validity; only the input rows that land on a kept
    sample stay in ``stamps`` (all of them when the record was resampled).
    """
    if q <= 1:
        return rec
    sl = slice(None, None, q)

    def cut(a):
        return None if a is None else a[sl]

    stamps, index = rec.stamps, rec.stamp_index
    if index is not None:
        keep = index % q == 0
        stamps, index = stamps[keep], index[keep] // q
    return replace(rec, time=rec.time[sl], displacement=rec.displacement[sl],
                   velocity=rec.velocity[sl], force=rec.force[sl], i_in=rec.i_in[sl],
                   command=cut(rec.command), temperature=cut(rec.temperature), dt=rec.dt * q,
                   mask=cut(rec.mask), stamps=stamps, stamp_index=index,
                   velocity_pred=cut(rec.velocity_pred))


def window(rec, start, stop, name=None):
    """Return samples ``start:stop`` of a record as a record of its own (time from 0)."""
    sl = slice(int(start), int(stop))

    def cut(a):
        return None if a is None else a[sl]

    stamps, index = rec.stamps, rec.stamp_index
    if index is not None:
        keep = (index >= sl.start) & (index < sl.stop)
        stamps, index = stamps[keep] - rec.time[sl.start], index[keep] - sl.start
    else:
        stamps = rec.time[sl] - rec.time[sl.start]
    return replace(rec, name=name or f'{rec.name}[{sl.start}:{sl.stop}]',
                   time=rec.time[sl] - rec.time[sl.start], displacement=rec.displacement[sl],
                   velocity=rec.velocity[sl], force=rec.force[sl], i_in=rec.i_in[sl],
                   command=cut(rec.command), temperature=cut(rec.temperature),
                   mask=cut(rec.mask), stamps=stamps, stamp_index=index,
                   velocity_pred=cut(rec.velocity_pred))


def for_prediction(rec):
    """Return ``rec`` with the velocity a prediction takes (``Record.velocity_pred``, if any).

    Identification and prediction ask different things of a noisy velocity. A fit wants it
    free of bias, or a series spring's stiffness and a loop's width absorb the bias at the
    reversals: the motion band's one low-pass. A prediction wants the least error per
    sample: a cut-off per sample at or below the band's, far quieter in slow motion, where a
    steep yield turns on a few mm/s, fused with one-sided local fits that keep the kink of a
    reversal (``sensors.directional_velocity``).
    """
    if rec.velocity_pred is None:
        return rec
    return replace(rec, velocity=rec.velocity_pred, velocity_pred=None)


def limit_duration(records, max_seconds, piece=20.0):
    """Limit records to ``max_seconds`` in total by evenly spread ``piece``-second windows.

    Long records (a 2-million-row file) are judged on windows spread over their whole length,
    at the full rate, instead of on every sample: the selection and the fits scale with the
    samples used. Returns ``(records, note or None)``.
    """
    total = sum(r.duration for r in records)
    if total <= max_seconds:
        return list(records), None
    out = []
    share = max_seconds / total
    for r in records:
        want = r.duration * share
        k = max(1, int(round(want / piece)))
        n_piece = int(min(piece, r.duration / k) / r.dt)
        starts = np.linspace(0, r.n - n_piece, k).astype(int)
        out += [window(r, a, a + n_piece) for a in starts]
    used = sum(r.duration for r in out)
    return out, (f'{total:.0f} s of records: judged on {len(out)} windows of {piece:g} s '
                 f'spread over them ({used:.0f} s, {100 * used / total:.0f} %)')


def at_stamps(rec, y):
    """``(stamps, y at the stamps)``: a signal on the record's grid at the input's own rows."""
    y = np.asarray(y, dtype=float)
    if rec.stamp_index is not None:
        return rec.stamps, y[rec.stamp_index]
    return rec.stamps, np.interp(rec.stamps, rec.time, y)


def with_force(rec, force):
    """Return a copy of ``rec`` with another force array (used by the generator and tests)."""
    return replace(rec, force=np.asarray(force, dtype=float))
