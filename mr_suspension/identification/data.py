"""Rig records: loaders (CSV/text, MATLAB .mat, rosbag2), column/unit mapping and input checks.

A record holds SI arrays on a uniform time base: ``time`` [s], ``displacement`` [m] (+ =
extension), ``velocity`` [m/s], ``force`` [N] (+ resists extension), the input current ``i_in``
[A] the force model sees before current dynamics (the measured coil ``current`` when present,
else the command through the driver's static map: a ``current_command`` is taken as the coil
current, a ``voltage_command`` goes through ``core.driver.static_current``), and optionally
``temperature``. When no velocity is given it is derived from displacement by a zero-phase
2nd-order Butterworth low-pass (``filtfilt``, cut-off ``velocity_cutoff``, default 25 Hz) and
central differences; the filter has no phase lag, so it cannot fake a delay or a hysteresis.

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
from scipy import signal

from mr_suspension.core.driver import DriverParams, static_current

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
VRTHS_TXT = re.compile(r'(\d+(?:x\d+)?)mm(\d+(?:x\d+)?)Hz(\d+(?:x\d+)?)A', re.IGNORECASE)
VRTHS_MAT_CURRENTS = (0.2, 0.4, 0.6, 0.8, 1.0)


class DataError(ValueError):
    """Raised for unusable input data, with a message saying what to fix."""


@dataclass(frozen=True)
class Record:
    """One rig record in SI units on a uniform time base (see the module docstring)."""

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
    """How to read files: column names (canonical -> file column), units, preset, filter."""

    columns: dict = field(default_factory=dict)
    units: dict = field(default_factory=dict)
    preset: str = 'auto'
    velocity_cutoff: float = 25.0
    derive_velocity: bool = False
    use_measured_current: bool = True


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


def derive_velocity(x, dt, cutoff=25.0):
    """Velocity from displacement: zero-phase Butterworth (order 2, ``cutoff`` Hz) + gradient."""
    fs = 1.0 / dt
    xs = x
    if cutoff is not None and cutoff < 0.45 * fs and x.size > 30:
        b, a = signal.butter(2, cutoff / (0.5 * fs))
        xs = signal.filtfilt(b, a, x, padlen=min(3 * max(len(a), len(b)), x.size - 1))
    return np.gradient(xs, dt)


def _unit_factor(name, unit):
    table = UNITS[name]
    key = unit.strip().lower().replace(' ', '')
    if key not in table:
        raise DataError(f'unit {unit!r} not known for {name}; use one of {sorted(table)}')
    return table[key]


def _fix_nan(name, arr, label):
    bad = ~np.isfinite(arr)
    if not bad.any():
        return arr
    frac = bad.mean()
    if frac > 0.01 or bad.all():
        raise DataError(f'{label}: {bad.sum()} of {arr.size} {name} values are NaN/inf '
                        f'({100 * frac:.1f} %); clean the record (at most 1 % can be patched)')
    idx = np.arange(arr.size)
    warnings.warn(f'{label}: {bad.sum()} NaN/inf {name} value(s) linearly interpolated')
    out = arr.copy()
    out[bad] = np.interp(idx[bad], idx[~bad], arr[~bad])
    return out


def build_record(name, cols, opts=None, meta=None):
    """Check raw SI columns (dict canonical -> array) and return a ``Record``.

    Raises ``DataError`` for missing columns, non-monotonic time, too short records, too many
    NaN and implausible units; warns for patched NaN, resampling and suspicious scales.
    """
    opts = opts or LoadOptions()
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
    t = cols['time']
    if not np.all(np.isfinite(t)):
        raise DataError(f'{name}: time contains NaN/inf')
    dts = np.diff(t)
    if np.any(dts <= 0):
        k = int(np.argmax(dts <= 0))
        raise DataError(f'{name}: time is not strictly increasing (row {k + 1}: {t[k]} -> '
                        f'{t[k + 1]}); sort or split the record')
    dt = float(np.median(dts))
    if t[-1] - t[0] < MIN_DURATION:
        raise DataError(f'{name}: too short ({t[-1] - t[0]:.3f} s); need >= {MIN_DURATION} s')
    for k in list(cols):
        if k != 'time':
            cols[k] = _fix_nan(k, cols[k], name)
    if np.max(np.abs(dts - dt)) > 0.1 * dt:
        warnings.warn(f'{name}: irregular sampling (dt {dts.min():.3g}..{dts.max():.3g} s); '
                      f'resampled to a uniform {dt:.3g} s grid')
        tu = t[0] + dt * np.arange(int((t[-1] - t[0]) / dt) + 1)
        for k in list(cols):
            if k != 'time':
                cols[k] = np.interp(tu, t, cols[k])
        t = tu
    x = cols['displacement']
    f = cols['force']
    if np.max(np.abs(x)) > 0.5:
        raise DataError(f'{name}: displacement reaches {np.max(np.abs(x)):.3g} m, implausible '
                        'for a damper; if it is in mm pass --units displacement=mm')
    if np.std(f) < 1e-9:
        raise DataError(f'{name}: force is constant; nothing to identify')
    if np.max(np.abs(f)) < 20.0:
        warnings.warn(f'{name}: peak force only {np.max(np.abs(f)):.3g} N; if the file is in '
                      'kN pass --units force=kN (parameters would be 1000x too small)')
    vsrc = 'measured'
    if 'velocity' in cols and not opts.derive_velocity:
        v = cols['velocity']
        vd = derive_velocity(x, dt, opts.velocity_cutoff)
        rv, rd = np.sqrt(np.mean(v ** 2)), np.sqrt(np.mean(vd ** 2))
        if rd > 0 and rv > 0 and not 0.2 < rv / rd < 5.0:
            raise DataError(f'{name}: velocity RMS {rv:.3g} m/s disagrees with d(displacement)/dt '
                            f'RMS {rd:.3g} m/s (ratio {rv / rd:.3g}); check --units '
                            'velocity=... / displacement=...')
    else:
        v = derive_velocity(x, dt, opts.velocity_cutoff)
        vsrc = f'derived (zero-phase Butterworth 2nd order {opts.velocity_cutoff:g} Hz)'
    command = None
    if 'current_command' in cols:
        command = cols['current_command']
        kind = 'current_command'
    elif 'voltage_command' in cols:
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
    return Record(name=name, time=t - t[0], displacement=x, velocity=v, force=f, i_in=i_in,
                  input_kind=kind, dt=dt, command=command, temperature=cols.get('temperature'),
                  velocity_source=vsrc, meta=dict(meta or {}))


def _apply_units(cols, units, defaults=None):
    units = dict(defaults or {}, **(units or {}))
    out = {}
    for k, v in cols.items():
        fac = _unit_factor(k, units[k]) if k in units else 1.0
        out[k] = np.asarray(v, dtype=float) * fac
    return out


def _vrths_value(token):
    return float(token.replace('x', '.'))


def _read_table(path):
    text = Path(path).read_text(errors='replace').splitlines()
    lines = [ln for ln in text if ln.strip() and not ln.lstrip().startswith('#')]
    if not lines:
        raise DataError(f'{path}: empty file')
    delim = ',' if ',' in lines[0] else (';' if ';' in lines[0] else None)
    first = [s.strip().strip('"') for s in (lines[0].split(delim) if delim else lines[0].split())]
    try:
        [float(s) for s in first]
        header = None
        body = lines
    except ValueError:
        header = first
        body = lines[1:]
    rows = []
    for k, ln in enumerate(body):
        parts = ln.split(delim) if delim else ln.split()
        try:
            rows.append([float(s) if s.strip() not in ('', 'nan', 'NaN') else math.nan
                         for s in parts])
        except ValueError:
            raise DataError(f'{path}: non-numeric value on data line {k + 1}: {ln[:60]!r}')
    width = len(header) if header else len(rows[0])
    if any(len(r) != width for r in rows):
        raise DataError(f'{path}: rows have different numbers of columns')
    return header, np.array(rows, dtype=float).reshape(-1, width)


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
    names = {h: j for j, h in enumerate(header)}
    cols = {}
    for canon in CANONICAL:
        src = opts.columns.get(canon, canon)
        if src in names:
            cols[canon] = table[:, names[src]]
        elif canon in opts.columns:
            raise DataError(f'{path}: mapped column {src!r} for {canon} not in header {header}')
    return build_record(path.name, _apply_units(cols, opts.units), opts)


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
            cols[canon] = np.asarray(mat[src], dtype=float).ravel()
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
    stamps when present, else bag stamps (sim time in lockstep). All signals are
    interpolated onto a uniform grid at the force topic's median period (commands held).
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import get_typestore, Stores

    opts = opts or LoadOptions()
    series = {}
    with AnyReader([Path(path)], default_typestore=get_typestore(Stores.LATEST)) as reader:
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
    for alt in ('displacement', 'velocity'):
        if alt + '_alt' in series:
            if alt not in series:
                series[alt] = series[alt + '_alt']
            del series[alt + '_alt']
    if 'force' not in series:
        raise DataError(f'{path}: no force topic; found quantities {sorted(series)}')
    tf = np.unique(np.array(series['force'][0]))
    if tf.size < 2:
        raise DataError(f'{path}: too few force messages')
    dt = float(np.median(np.diff(tf)))
    t = tf[0] + dt * np.arange(int(round((tf[-1] - tf[0]) / dt)) + 1)
    cols = {'time': t}
    for q, (ts, vs) in series.items():
        ts = np.array(ts)
        vs = np.array(vs)
        order = np.argsort(ts, kind='stable')
        ts, vs = ts[order], vs[order]
        if q in ('current_command', 'voltage_command'):
            idx = np.clip(np.searchsorted(ts, t + 0.01 * dt, side='right') - 1, 0, ts.size - 1)
            cols[q] = vs[idx]
        else:
            cols[q] = np.interp(t, ts, vs)
    return build_record(Path(path).name, _apply_units(cols, opts.units), opts)


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
        if p.is_dir() and not (p / 'metadata.yaml').exists():
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
    """Every ``q``-th sample of a record (signals are smooth at the rig rates; no filter)."""
    if q <= 1:
        return rec
    sl = slice(None, None, q)

    def cut(a):
        return None if a is None else a[sl]

    return replace(rec, time=rec.time[sl], displacement=rec.displacement[sl],
                   velocity=rec.velocity[sl], force=rec.force[sl], i_in=rec.i_in[sl],
                   command=cut(rec.command), temperature=cut(rec.temperature), dt=rec.dt * q)


def with_force(rec, force):
    """Return a copy of ``rec`` with another force array (used by the generator and tests)."""
    return replace(rec, force=np.asarray(force, dtype=float))
