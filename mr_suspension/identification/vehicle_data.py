"""Vehicle records for ``diagnose-vehicle``: CSV or rosbag2 of the topic contract, checked.

A record is one corner on a uniform time base (the body IMU's): ``body_acc`` and
``wheel_acc`` with gravity removed (the IMUs report the specific force, +9.81 m/s^2 at rest,
z up), ``stroke`` [m] (+ = extension), its rate from a zero-phase differentiator,
``current_command`` [A], optional ``coil_current`` [A] and ``road`` [m] (a rig's shaker).
Pure numerics apart from reading bags through rosbags; no ROS client library.
"""

from dataclasses import dataclass, field, fields, replace
import math
from pathlib import Path
import warnings

from numba import njit
import numpy as np

from mr_suspension.identification import sensors
from mr_suspension.identification.data import check_time, DataError

G = 9.81
REQUIRED = ('time', 'body_acc', 'wheel_acc', 'stroke', 'current_command')
OPTIONAL = ('coil_current', 'road')
ALIASES = {'t': 'time', 'timestamp': 'time', 'a_body': 'body_acc', 'body_accel': 'body_acc',
           'a_wheel': 'wheel_acc', 'wheel_accel': 'wheel_acc', 'x': 'stroke',
           'i_cmd': 'current_command', 'command': 'current_command', 'current': 'coil_current',
           'i_coil': 'coil_current', 'z_r': 'road'}
MIN_SAMPLES = 2000
MIN_DURATION = 5.0       # [s] 24 blocks of held-out judgement need some length
NAN_MAX = 0.01           # share of NaN/inf per channel above which the record is refused
STROKE_MAX = 0.5         # [m] beyond: millimetres read as metres
CURRENT_MAX = 10.0       # [A] beyond: milliamperes read as amperes
NO_MOTION = 1e-4         # [m] 1-99 % stroke span below which nothing moved
DIFF_CUTOFF_MIN = 20.0   # [Hz] lowest cut-off of the stroke differentiator
CROSS_MIN, CROSS_MAX = 0.3, 20.0  # [Hz] range of the stroke/IMU crossover
LAG_MIN = 1.5e-3         # [s] stroke lag worth a finding
# Topics of the contract (msg_defs/topics.yaml), relative to the corner's namespace.
TOPICS = {'imu/body': 'body_acc', 'imu/wheel': 'wheel_acc', 'stroke': 'stroke',
          'current_command': 'current_command', 'coil_current': 'coil_current'}


@dataclass
class VehicleRecord:
    """One corner's measured record on a uniform grid (SI, gravity removed)."""

    name: str
    time: np.ndarray
    dt: float
    body_acc: np.ndarray
    wheel_acc: np.ndarray
    stroke: np.ndarray
    stroke_rate: np.ndarray
    current_command: np.ndarray
    coil_current: np.ndarray = None
    road: np.ndarray = None
    cutoff: float = None
    mask: np.ndarray = None
    findings: list = field(default_factory=list)
    stroke_fused: np.ndarray = None
    crossover: float = None
    stroke_tau: float = 0.0
    start: float = 0.0  # [s] the first sample's time in the source (``time`` starts at 0)

    def __post_init__(self):
        """Set the default mask: every sample usable."""
        if self.mask is None:
            self.mask = np.ones(self.time.size, dtype=bool)

    @property
    def n(self):
        """Number of samples."""
        return int(self.time.size)

    @property
    def duration(self):
        """Record length [s]."""
        return self.n * self.dt

    def trimmed(self, n):
        """Return the record's first ``n`` samples."""
        arrays = {f.name: getattr(self, f.name)[:n] for f in fields(self)
                  if isinstance(getattr(self, f.name), np.ndarray)}
        return replace(self, **arrays)


def _norm(name):
    h = name.strip().strip('"').lower()
    for sep in ('[', '('):
        if sep in h:
            h = h.split(sep)[0]
    h = h.strip().replace(' ', '_')
    return ALIASES.get(h, h)


def read_csv(path):
    """Columns ``{name: array}`` of a CSV file with a header (names as in the module doc)."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f'{path}: no such file')
    with open(path, encoding='utf-8', errors='replace') as fh:
        header = fh.readline()
    if not header.strip():
        raise DataError(f'{path}: empty file; expected a header line with {", ".join(REQUIRED)}')
    delim = ',' if ',' in header else (';' if ';' in header else None)
    names = [_norm(h) for h in (header.split(delim) if delim else header.split())]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            table = np.genfromtxt(path, delimiter=delim, skip_header=1, dtype=float,
                                  invalid_raise=True)
    except ValueError as exc:
        raise DataError(f'{path}: cannot parse the numbers ({" ".join(str(exc).split())[:120]})'
                        ) from None
    table = np.atleast_2d(table)
    if table.size == 0:
        raise DataError(f'{path}: no data rows under the header')
    if table.shape[1] != len(names):
        raise DataError(f'{path}: {len(names)} header names but {table.shape[1]} columns')
    cols = {}
    for k, n in enumerate(names):
        if n in cols:
            raise DataError(f'{path}: two columns for {n!r}')
        cols[n] = table[:, k]
    return cols


def _ns_topics(topics, namespace):
    """Map contract topics to quantities for one corner (``namespace`` or the only one)."""
    bodies = sorted(t for t in topics if t.rstrip('/').endswith('imu/body'))
    if namespace is not None:
        ns = '/' + namespace.strip('/') if namespace.strip('/') else ''
    else:
        spaces = sorted({t[:-len('/imu/body')] for t in bodies})
        if not spaces:
            raise DataError(f'no imu/body topic in the bag; topics: {sorted(topics)}')
        if len(spaces) > 1:
            raise DataError(f'the bag holds several corners {spaces}; pick one with '
                            '--namespace NAME, or diagnose a full car with --car NAME')
        ns = spaces[0]
    out = {}
    for rel, q in TOPICS.items():
        name = f'{ns}/{rel}'
        if name in topics:
            out[name] = q
    return out, ns


def read_bag(path, namespace=None, road_topic=None):
    """Columns of a rosbag2 bag of the contract topics, aligned on the body IMU stamps.

    ``Imu.linear_acceleration.z``, ``JointState.position[0]`` of ``stroke``, ``Float64.data``
    of the currents (commands held between their stamps, the others interpolated); header
    stamps when present, else bag stamps. ``road_topic``: a Float64 or JointState (its
    ``road`` joint, e.g. ``truth/state``) with the known road/shaker displacement.
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import get_typestore, Stores

    series = {}
    try:
        with AnyReader([Path(path)], default_typestore=get_typestore(Stores.LATEST)) as reader:
            topics = {c.topic for c in reader.connections}
            wanted, ns = _ns_topics(topics, namespace)
            if road_topic:
                rt = road_topic if road_topic.startswith('/') else f'{ns}/{road_topic}'
                if rt not in topics:
                    raise DataError(f'{path}: no road topic {rt}; topics: {sorted(topics)}')
                wanted[rt] = 'road'
            conns = [c for c in reader.connections if c.topic in wanted]
            for conn, stamp, raw in reader.messages(connections=conns):
                q = wanted[conn.topic]
                msg = reader.deserialize(raw, conn.msgtype)
                val = _value(msg, q)
                if val is None:
                    continue
                hdr = getattr(msg, 'header', None)
                ts = stamp * 1e-9
                if hdr is not None and (hdr.stamp.sec or hdr.stamp.nanosec):
                    ts = hdr.stamp.sec + hdr.stamp.nanosec * 1e-9
                series.setdefault(q, ([], []))
                series[q][0].append(ts)
                series[q][1].append(val)
    except DataError:
        raise
    except Exception as exc:  # rosbags raises many types for damaged bags
        msg = ' '.join(str(exc).split())[:160] or type(exc).__name__
        raise DataError(f'{path}: cannot read the bag ({type(exc).__name__}: {msg}); run '
                        f'`mr-suspension bag repair {path}` and load the repaired bag') from None
    missing = [q for q in REQUIRED[1:] if q not in series]
    if missing:
        raise DataError(f'{path}: corner {ns or "/"} has no messages for {missing} (topics '
                        f'{", ".join(f"{ns}/{r}" for r, q in TOPICS.items() if q in missing)})')
    tb = np.array(series['body_acc'][0])
    order = np.argsort(tb, kind='stable')
    keep = np.concatenate(([True], np.diff(tb[order]) > 0))
    t = tb[order][keep]
    cols = {'time': t, 'body_acc': np.array(series['body_acc'][1])[order][keep]}
    for q, (ts, vs) in series.items():
        if q == 'body_acc':
            continue
        ts, vs = np.asarray(ts), np.asarray(vs)
        o = np.argsort(ts, kind='stable')
        ts, vs = ts[o], vs[o]
        if q == 'current_command':
            idx = np.searchsorted(ts, t + 1e-9, side='right') - 1
            cols[q] = np.where(idx >= 0, vs[np.clip(idx, 0, None)], vs[0])
        else:
            cols[q] = np.interp(t, ts, vs)
    return cols


def _value(msg, q):
    if q in ('body_acc', 'wheel_acc'):
        return float(msg.linear_acceleration.z)
    if hasattr(msg, 'data'):
        return float(msg.data)
    names = list(getattr(msg, 'name', []))
    pos = list(getattr(msg, 'position', []))
    if q == 'road' and 'road' in names:
        return float(pos[names.index('road')])
    if q == 'stroke' and names and 'suspension' in names and 'suspension_stroke' not in names:
        return float(pos[names.index('suspension')])
    return float(pos[0]) if pos else None


def _finite_fill(name, label, x):
    """Linearly fill NaN/inf (few, else error); return ``(x, usable mask)``."""
    ok = np.isfinite(x)
    if ok.all():
        return x, ok
    bad = 1.0 - ok.mean()
    if bad > NAN_MAX or ok.sum() < 2:
        raise DataError(f'{name}: {label} has {100 * bad:.1f} % NaN/inf samples (limit '
                        f'{100 * NAN_MAX:g} %); clean or cut the record')
    idx = np.arange(x.size)
    return np.interp(idx, idx[ok], x[ok]), ok


def _gravity(name, label, a):
    """Remove gravity from an IMU's z specific force; refuse other conventions."""
    med = float(np.mean(a))  # the mean over a drive is g (the body does not drift away)
    if 0.8 * G < med < 1.2 * G:
        return a - G
    if -1.2 * G < med < -0.8 * G:
        raise DataError(f'{name}: {label} reads {med:.2f} m/s^2 on average: z points down; '
                        'the contract is z up (+9.81 at rest), flip the sign')
    if abs(med) < 0.1 * G:
        raise DataError(f'{name}: {label} has mean {med:.2f} m/s^2: gravity already removed?'
                        ' The contract is the IMU specific force (gravity included, +9.81 '
                        'm/s^2 at rest, z up); add 9.81')
    raise DataError(f'{name}: {label} has mean {med:.3g}: not m/s^2 with gravity '
                    '(in g? multiply by 9.81)')


def build(name, cols):
    """Check the columns and return a :class:`VehicleRecord` (gravity removed, rate derived)."""
    missing = [c for c in REQUIRED if c not in cols]
    if missing:
        raise DataError(f'{name}: missing column(s) {missing}; found {sorted(cols)}; expected '
                        f'{", ".join(REQUIRED)} (+ optional {", ".join(OPTIONAL)})')
    t = np.asarray(cols['time'], dtype=float)
    if t.size < MIN_SAMPLES:
        raise DataError(f'{name}: {t.size} samples, need at least {MIN_SAMPLES}')
    check_time(name, t)
    steps = np.diff(t)
    dt = float(np.median(steps))
    if t[-1] - t[0] < MIN_DURATION:
        raise DataError(f'{name}: {t[-1] - t[0]:.2f} s of data, need at least '
                        f'{MIN_DURATION:g} s (time in ms? convert to s)')
    findings = []
    mask = np.ones(t.size, dtype=bool)
    data = {}
    for q in REQUIRED[1:] + OPTIONAL:
        if q not in cols:
            continue
        x, ok = _finite_fill(name, q, np.asarray(cols[q], dtype=float))
        mask &= ok
        data[q] = x
    irregular = np.max(np.abs(steps - dt)) > 0.1 * dt
    grid = t[0] + dt * np.arange(int(round((t[-1] - t[0]) / dt)) + 1)
    if irregular:
        findings.append({'finding': 'irregular_sampling', 'location': 'sensor', 'channel': 'time',
                         'action': 'corrected', 'detail': 'resampled to the median step '
                         f'{dt * 1e3:.3g} ms'})
        for q, x in data.items():
            kind = 'previous' if q == 'current_command' else 'linear'
            if kind == 'linear':
                data[q] = np.interp(grid, t, x)
            else:
                data[q] = x[np.clip(np.searchsorted(t, grid + 1e-12, side='right') - 1, 0, None)]
        mask = np.interp(grid, t, mask.astype(float)) > 0.999
        t = grid
    body = _gravity(name, 'body_acc', data['body_acc'])
    wheel = _gravity(name, 'wheel_acc', data['wheel_acc'])
    x = data['stroke']
    span = np.percentile(x, 99) - np.percentile(x, 1)
    if np.max(np.abs(x)) > STROKE_MAX:
        raise DataError(f'{name}: stroke reaches {np.max(np.abs(x)):.3g} m (> {STROKE_MAX} m): '
                        'millimetres? give metres')
    if span < NO_MOTION:
        raise DataError(f'{name}: the stroke hardly moves (1-99 % span {span * 1e3:.3g} mm): '
                        'nothing to identify')
    for q in ('current_command', 'coil_current'):
        if q in data and np.max(np.abs(data[q])) > CURRENT_MAX:
            raise DataError(f'{name}: {q} reaches {np.max(np.abs(data[q])):.3g} A (> '
                            f'{CURRENT_MAX:g} A): milliamperes? give amperes')
    for q, sig in (('body_acc', body), ('wheel_acc', wheel), ('stroke', x)):
        m, f = sensors.clipping(q, sig)
        if f is None:
            m, f = rail_pileup(q, sig)
        if f is not None:
            mask &= m
            findings.append(dict(f))
    if mask.mean() < 0.5:
        raise DataError(f'{name}: less than half of the samples are usable')
    cut = sensors.motion_cutoff(x, dt)
    cut = max(DIFF_CUTOFF_MIN, cut or 0.25 / dt)
    cut = min(cut, 0.4 / dt)
    a_rel = body - wheel
    lag, f_lag = stroke_lag(x, a_rel, dt)
    if f_lag is not None:
        findings.append(f_lag)
    x_used = x
    fc = crossover(x_used, a_rel, dt)
    # Above the crossover the rate comes from the IMUs, which resolve the yield switching's
    # fast content: no band limit (a low-pass at the stroke's motion band cost 8x the error).
    cut = 0.45 / dt
    xf, rate = fuse(x_used, a_rel, dt, fc, cut, lag)
    return VehicleRecord(name=name, time=t - t[0], start=float(t[0]), dt=dt, body_acc=body,
                         wheel_acc=wheel, stroke=x, stroke_rate=rate,
                         current_command=data['current_command'],
                         coil_current=data.get('coil_current'), road=data.get('road'),
                         cutoff=cut, mask=mask, findings=findings, stroke_fused=xf,
                         crossover=fc, stroke_tau=lag)


def rail_pileup(name, x, n_min=5, ratio=5.0):
    """Clipping seen as samples piling up on the extreme value: ``(mask, finding or None)``.

    A continuous (or finely quantised) channel holds its extreme value a few times at most,
    about as often as the next level; a rail holds it far more often (>= ``n_min`` samples
    and >= ``ratio`` times the next level's count). Complements the held-run test, which
    misses a rail touched in many short runs (a vibrating wheel).
    """
    mask = np.ones(x.size, dtype=bool)
    rails = []
    x = sensors.snap_rails(x, float(np.max(x)), float(np.min(x)))
    for side in (1.0, -1.0):
        v = side * x
        top = float(np.max(v))
        at = v == top
        c_top = int(at.sum())
        below = v[~at]
        c_next = int(np.sum(below == np.max(below))) if below.size else 0
        if c_top >= n_min and c_top >= ratio * max(c_next, 1):
            mask &= ~at
            rails.append(('max' if side > 0 else 'min', side * top, c_top))
    if not rails:
        return mask, None
    nbad = int((~mask).sum())
    where = ' and '.join(f'{w} {val:.6g} ({c} samples)' for w, val, c in rails)
    return mask, sensors.finding(
        'clipping', name, 'excluded', f'{name} piles up at its {where}: clipped; '
        f'{nbad} samples ({100 * nbad / x.size:.2f} %) masked', samples=nbad,
        fraction=nbad / x.size)


def _white(y, dt):
    """White-noise PSD [unit^2/Hz] of ``y``: median Welch level above 0.3 fs."""
    from scipy import signal
    fs = 1.0 / dt
    f, p = signal.welch(y, fs, nperseg=min(y.size // 4, int(2 * fs)))
    return float(np.median(p[f >= 0.3 * fs]))


def crossover(x, a_rel, dt):
    """Frequency [Hz] where the stroke's differentiated noise meets the IMUs' integrated noise.

    ``(2 pi f)^2 S_x = S_a / (2 pi f)^2``, i.e. ``f = (S_a / S_x)^(1/4) / (2 pi)``, within
    ``CROSS_MIN``..``CROSS_MAX``.
    """
    sx, sa = _white(x, dt), _white(a_rel, dt)
    if not sx > 0 or not sa > 0:
        return CROSS_MAX
    return float(np.clip((sa / sx) ** 0.25 / (2 * math.pi), CROSS_MIN, CROSS_MAX))


def fuse(x, a_rel, dt, fc, cut, tau=0.0):
    """Stroke and stroke rate fused from the stroke sensor (below ``fc``) and the IMUs (above).

    The Wiener smoother of the double integrator ``x'' = a_rel`` (relative acceleration body -
    wheel, mean removed) with the stroke as measurement: in the interior its weights are the
    complementary ``W = 1 / (1 + (f/fc)^4)`` on the stroke and ``1 - W`` on the IMUs
    (``V = W j w X + (1 - W) A / (j w)``), because the acceleration-noise to stroke-noise ratio
    is set to ``q / r = (2 pi fc)^4`` (``fc`` from :func:`crossover`). It runs as a Kalman
    filter and Rauch-Tung-Striebel smoother (:func:`_rts`), so the record's ends need no
    periodic extension (a reflected record put a velocity jump at the end: errors of 10x the
    interior over the last seconds). Then the zero-phase low-pass at ``cut``. ``tau``: the
    stroke sensor's lag, inverted as ``x + tau x'``.
    """
    xs = np.asarray(x, dtype=float)
    if tau > 0.0:
        xs = xs + tau * np.gradient(xs, dt)
    a = np.asarray(a_rel, dtype=float)
    s = _rts(np.ascontiguousarray(xs), np.ascontiguousarray(a - a.mean()), float(dt),
             (2.0 * math.pi * fc) ** 4)
    return s[:, 0].copy(), sensors.lowpass(s[:, 1].copy(), dt, cut, order=4)


@njit(cache=True, nogil=True)
def _rts(z, a, dt, q):
    """Kalman filter + RTS smoother of ``[x, v]``; returns the smoothed ``(n, 2)``.

    ``x_k+1 = x_k + dt v_k + dt^2/2 a``, ``v_k+1 = v_k + dt a`` (``a`` the trapezoidal mean),
    acceleration noise ``q``, measurement ``z`` of ``x`` with unit noise (Rauch, Tung and
    Striebel 1965).
    """
    n = z.size
    xf = np.empty((n, 2))
    pf = np.empty((n, 3))
    xp = np.empty((n, 2))
    pp = np.empty((n, 3))
    x0, x1 = z[0], 0.0
    p00, p01, p11 = 1.0, 0.0, 1e12  # the first stroke sample, no knowledge of the rate
    b0, b1 = 0.5 * dt * dt, dt
    for k in range(n):
        if k > 0:
            am = 0.5 * (a[k - 1] + a[k])
            x0 = x0 + dt * x1 + b0 * am
            x1 = x1 + b1 * am
            n00 = p00 + 2.0 * dt * p01 + dt * dt * p11 + q * b0 * b0
            n01 = p01 + dt * p11 + q * b0 * b1
            p11 = p11 + q * b1 * b1
            p00, p01 = n00, n01
        xp[k, 0], xp[k, 1] = x0, x1
        pp[k, 0], pp[k, 1], pp[k, 2] = p00, p01, p11
        s = p00 + 1.0
        k0, k1 = p00 / s, p01 / s
        r = z[k] - x0
        x0 += k0 * r
        x1 += k1 * r
        p00, p01, p11 = p00 - k0 * p00, p01 - k0 * p01, p11 - k1 * p01
        xf[k, 0], xf[k, 1] = x0, x1
        pf[k, 0], pf[k, 1], pf[k, 2] = p00, p01, p11
    out = xf.copy()
    for k in range(n - 2, -1, -1):
        # C = P_f F^T P_p(k+1)^-1
        m00 = pf[k, 0] + dt * pf[k, 1]
        m01 = pf[k, 1]
        m10 = pf[k, 1] + dt * pf[k, 2]
        m11 = pf[k, 2]
        q00, q01, q11 = pp[k + 1, 0], pp[k + 1, 1], pp[k + 1, 2]
        det = q00 * q11 - q01 * q01
        i00, i01, i11 = q11 / det, -q01 / det, q00 / det
        d0 = out[k + 1, 0] - xp[k + 1, 0]
        d1 = out[k + 1, 1] - xp[k + 1, 1]
        out[k, 0] = xf[k, 0] + (m00 * i00 + m01 * i01) * d0 + (m00 * i01 + m01 * i11) * d1
        out[k, 1] = xf[k, 1] + (m10 * i00 + m11 * i01) * d0 + (m10 * i01 + m11 * i11) * d1
    return out


def stroke_lag(x, a_rel, dt, band=(1.0, 8.0)):
    """First-order lag of the stroke sensor against the IMUs: ``(tau [s], finding or None)``.

    In ``band`` the stroke must equal the double integral of the relative acceleration
    ``X_a = -A / w^2``; a sensor lag gives ``X = X_a / (1 + j w tau)``. ``tau`` minimises
    ``sum |X (1 + j w tau) - X_a|^2`` over a grid (0-60 ms; no model involved). A lag beyond
    ``LAG_MIN`` that removes at least 30 % of the mismatch is a finding; :func:`fuse` inverts
    it (below the crossover, where the stroke is used).
    """
    n = x.size
    f = np.fft.rfftfreq(n, dt)
    m = (f >= band[0]) & (f <= band[1])
    X = np.fft.rfft(x - x.mean())[m]
    w = 2 * math.pi * f[m]
    Xa = -np.fft.rfft(a_rel - a_rel.mean())[m] / w ** 2
    taus = np.arange(0.0, 0.0605, 0.0005)
    err = np.array([np.sum(np.abs(X * (1 + 1j * w * t) - Xa) ** 2) for t in taus])
    j = int(np.argmin(err))
    tau = float(taus[j])
    if tau < LAG_MIN or err[j] > 0.7 * err[0]:
        return 0.0, None
    return tau, {'finding': 'stroke_lag', 'location': 'sensor', 'channel': 'stroke',
                 'action': 'corrected',
                 'detail': f'the stroke lags the double-integrated relative acceleration '
                           f'(IMUs) like a first-order lag of {tau * 1e3:.1f} ms in '
                           f'{band[0]:g}-{band[1]:g} Hz (mismatch {err[j] / err[0]:.0%} of '
                           'the unlagged one); inverted below the crossover',
                 'tau_s': tau}


def is_bag(path):
    """Return True for a rosbag2 directory (``metadata.yaml``) or a ``.mcap``/``.db3`` file."""
    p = Path(path)
    return (p.is_dir() and (p / 'metadata.yaml').is_file()) or p.suffix in ('.mcap', '.db3')


def load(paths, namespace=None, road_topic=None):
    """Load CSV files and bags (directories of them too) as :class:`VehicleRecord` s."""
    out = []
    for p in paths:
        p = Path(p)
        if not p.exists():
            raise DataError(f'{p}: no such file or directory')
        if is_bag(p):
            out.append(build(p.name, read_bag(p, namespace, road_topic)))
        elif p.is_dir():
            inner = sorted(q for q in p.iterdir() if q.suffix.lower() in ('.csv', '.txt')
                           or is_bag(q))
            if not inner:
                raise DataError(f'{p}: no CSV files or bags inside')
            out.extend(load(inner, namespace, road_topic))
        else:
            out.append(build(p.name, read_csv(p)))
    if not out:
        raise DataError('no records given')
    dts = {round(r.dt, 9) for r in out}
    if len(dts) > 1:
        raise DataError(f'records with different sample steps {sorted(dts)}; resample them')
    return out


def nan_safe(x):
    """Float or None for JSON."""
    return None if x is None or not math.isfinite(x) else float(x)
