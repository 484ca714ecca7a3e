"""The domain a damper model was fitted on, and the stretches of a record outside it.

``fit_domain`` summarises the usable samples of the training records (``data.Record``):
stroke, stroke rate, input and frequency ranges, the force at rest, the per-record force
offsets and the largest force against the motion. ``check`` flags every stretch of another
record that leaves that domain or that no damper can produce, one ``Stretch`` per run of
flagged samples, and the mask of what is left (``DomainCheck``). A prediction there
extrapolates (a sigmoid's tail, a gas spring or a loop are not identifiable outside the
fitted range), or the force there is not a damper's (an end stop, a clipped load cell, a
removed offset): its error there says nothing about the model.

Rules, one a kind (the numbers are the module constants):

* ``displacement`` / ``velocity`` / ``input``: a sample beyond the fitted range by more than
  5 % of its width (at least 0.1 mm, 0.1 mm/s, 20 mA), since a stroke, stroke rate or current
  the fit never saw is extrapolation; the velocity range is the signed extremes, each capped at
  1.5x the 99.9th percentile of ``|v|`` so that a lone spike does not widen it.
* ``frequency``: a window of 4 periods of the fitted band edge (the frequency below which
  99 % of a training record's velocity power lies, the largest over the records) holding more
  than 50 % of its velocity power above 1.25x that edge, with that power's RMS above 5 % of
  the fitted 99.9 % ``|v|``: rate and fluid dynamics were never excited there.
* ``half_cycle``: a half-cycle (stroke between two reversals, a reversal being a turn back by
  0.2 % of the fitted stroke range, at least 0.1 mm) shorter than half the 1st percentile of
  the fitted records' whole half-cycles and than the shortest of them (a record is never
  flagged against its own domain): a loop's or a series spring's behaviour in small
  reversals was never excited (a loop fitted on sine tests of 4 mm strokes or more holds its
  yield force through the sub-millimetre reversals of a broadband record).
* ``clipping``: force samples held at a rail (``sensors.clipping``): the true force is unknown.
* ``reversal``: a force against the motion (``-sign(v) F``) above 1.5x the training's 99.9th
  percentile plus 5 % of the force span (at least 3 rest-noise deviations), at speeds the
  training covers (``|v|`` above 10 % of its range): beyond what the fitted loop produced,
  a damper does not push along its motion (the loop's tail reached 1.4x that percentile
  in the DoE truth records).
* ``rest_noise``: a rest chunk (``|v|`` below 2 % of the fitted range for 50 ms or more, the
  stroke within 0.2 % of its range, at most 0.5 s) whose force deviates about a quadratic in
  time and a line in velocity by more than 3x the training's 99th percentile (its white
  force noise when it had no rest) and 0.5 % of the force span: a still damper holds its
  force.
* ``offset``: the record's force offset (``_offset``) further from the training offsets'
  median than their spread plus 3 % of the force span (at least 3 rest-noise deviations):
  a shifted load cell zero, or a gas spring at another mean stroke. The whole record is
  flagged, but no sample is excluded: the estimate is model-free, and a damper's own
  structure moves it with the programme (an unseen programme of a truth damper with a soft
  series spring moved it by 90 N, 3.4 % of its span).

Flags grow by 20 ms (``GUARD``) on each side: a stretch covers its edges, and runs closer than
40 ms merge. Samples the record already masks are never flagged, and the returned mask is ANDed
with the record's: it holds the usable samples inside the domain.
"""

from dataclasses import dataclass, fields
import math

from numba import njit
import numpy as np
from scipy import ndimage

from mr_suspension.identification import sensors

KINDS = ('displacement', 'velocity', 'input', 'frequency', 'half_cycle', 'clipping',
         'reversal', 'rest_noise', 'offset')
SLACK = 0.05            # range rules: tolerance, fraction of the fitted range's width
DISP_FLOOR = 1e-4       # [m] least stroke tolerance (data.NO_MOTION: no motion below it)
VEL_FLOOR = 1e-4        # [m/s] least stroke-rate tolerance (data.NO_MOTION_V)
INPUT_FLOOR = 0.02      # [A] least input tolerance (2 % of a 1 A coil; a measured current's noise)
FORCE_FLOOR = 1.0       # [N] least force span (a constant force channel has none)
VEL_PCT = 99.9          # percentile of |v| ...
VEL_CAP = 1.5           # ... this x which caps the velocity range (a spike does not widen it)
FORCE_PCT = 0.05        # force span: the FORCE_PCT .. 100 - FORCE_PCT percentiles
BAND_SHARE = 0.99       # the band edge has this share of a record's velocity power below it
FREQ_FACTOR = 1.25      # power above this x the band edge counts as above the band
FREQ_SHARE = 0.5        # a window with a larger share of its velocity power above is flagged
FREQ_FLOOR = 0.05       # ... when that power's RMS also exceeds this x the 99.9 % |v|
FREQ_PERIODS = 4.0      # window length, in periods of the band edge
REST_SPEED = 0.02       # rest: |v| below this fraction of the fitted velocity range ...
REST_MIN = 0.05         # [s] ... for at least this long ...
REST_STROKE = 0.002     # ... moving less than this fraction of the fitted stroke range
STROKE_FLOOR = 1e-5     # [m] least rest stroke (a displacement sensor's resolution)
REST_CHUNK = 0.5        # [s] longer rests are judged in chunks of about this length
REST_PCT = 99.0         # the training's rest deviation: this percentile over its chunks
REST_FACTOR = 3.0       # a rest chunk deviating by more than this x the training's ...
REST_FLOOR = 0.005      # ... and by more than this fraction of the force span is flagged
REVERSAL_SPEED = 0.1    # reversal judged at |v| above this fraction of the velocity range
REVERSAL_PCT = 99.9     # the training's force against the motion: this percentile ...
REVERSAL_FACTOR = 1.5   # ... times this (a hysteresis tail reached 1.4x it in DoE records)
REVERSAL_MARGIN = 0.05  # margin above it: this fraction of the force span (or 3 noise sigmas)
OFFSET_MIN = 0.1        # offset: each direction of motion holds at least this share
OFFSET_MARGIN = 0.03    # offset margin beyond the training spread: fraction of the force span
NOISE_SIGMAS = 3.0      # the reversal and offset margins are at least this x the rest noise
HALF_PCT = 1.0          # half_cycle: the fitted stroke between reversals, this percentile
HALF_FACTOR = 0.5       # ... times this is the shortest accepted (1 % of a process is below p1)
HALF_MIN = 10           # ... of at least this many whole half-cycles (else no rule)
TURN = 0.002            # a reversal: the stroke turns back by this fraction of its range
GUARD = 0.02            # [s] a flag covers this much more on each side
SHOW_RANGES = 3         # ``DomainCheck.lines`` lists this many time ranges per kind


@dataclass(frozen=True)
class Domain:
    """What the training records covered (SI units; ranges are ``(low, high)``).

    ``displacement`` [m], ``velocity`` [m/s] (capped at 1.5x ``abs_velocity_p999``), ``i_in`` [A],
    ``force`` [N] (0.05..99.95 %); ``band`` [Hz] the velocity's band edge (None: no motion);
    ``rest_velocity`` [m/s] and ``rest_stroke`` [m] what counts as rest; ``rest_noise`` [N]
    the force deviation at rest (None: no rest); ``force_noise`` [N] the white force noise;
    ``reversal`` [N] the force against the motion at ``|v| >= reversal_speed`` (None: no
    such speed); ``offsets`` ``((name, N), ...)`` per record (``offset``); ``half_stroke``
    [m] the shortest fitted half-cycle (``half_cycle``; None: too few half-cycles).
    """

    displacement: tuple
    velocity: tuple
    abs_velocity_p999: float
    i_in: tuple
    force: tuple
    band: float
    rest_velocity: float
    rest_stroke: float
    rest_noise: float
    force_noise: float
    reversal_speed: float
    reversal: float
    offsets: tuple
    records: int
    samples: int
    half_stroke: float = None

    @property
    def force_span(self):
        """Width of the force range [N] (at least ``FORCE_FLOOR``)."""
        return max(self.force[1] - self.force[0], FORCE_FLOOR)

    @property
    def noise(self):
        """Force deviation at rest [N] the rules compare with (else the white noise)."""
        return self.rest_noise if self.rest_noise is not None else self.force_noise

    def to_dict(self):
        """Return a plain JSON-ready dictionary (``from_dict`` reads it back)."""
        d = {a.name: getattr(self, a.name) for a in fields(self)}
        for k in ('displacement', 'velocity', 'i_in', 'force'):
            d[k] = list(d[k])
        d['offsets'] = [[name, value] for name, value in self.offsets]
        return d

    @classmethod
    def from_dict(cls, d):
        """Read ``to_dict``'s output; a missing or non-finite entry raises ValueError."""
        if not isinstance(d, dict):
            raise ValueError(f'domain: expected a mapping, got {type(d).__name__}')
        try:
            kw = {k: _pair(d[k], k) for k in ('displacement', 'velocity', 'i_in', 'force')}
            for k in ('abs_velocity_p999', 'rest_velocity', 'rest_stroke', 'force_noise',
                      'reversal_speed'):
                kw[k] = _number(d[k], k)
            for k in ('band', 'rest_noise', 'reversal'):
                kw[k] = None if d[k] is None else _number(d[k], k)
            h = d.get('half_stroke')  # absent in models written before the rule
            kw['half_stroke'] = None if h is None else _number(h, 'half_stroke')
            kw['offsets'] = tuple((str(k), _number(v, 'offsets')) for k, v in d['offsets'])
            kw['records'], kw['samples'] = int(d['records']), int(d['samples'])
        except KeyError as exc:
            raise ValueError(f'domain: missing key {exc.args[0]!r}') from None
        except (TypeError, ValueError) as exc:
            raise ValueError(f'domain: {exc}') from None
        return cls(**kw)


def _number(x, key):
    """Return ``x`` as a finite float (ValueError naming ``key`` otherwise)."""
    x = float(x)
    if not math.isfinite(x):
        raise ValueError(f'{key} must be finite, got {x}')
    return x


def _pair(x, key):
    """Return ``x`` as a ``(low, high)`` pair of finite floats."""
    lo, hi = (_number(a, key) for a in x)
    if lo > hi:
        raise ValueError(f'{key} must be [low, high], got [{lo}, {hi}]')
    return lo, hi


@dataclass(frozen=True)
class Stretch:
    """A run of a record outside the domain: ``kind`` (``KINDS``), ``[t0, t1)`` [s], ``detail``.

    ``value`` is the worst value (SI: m, m/s, A, the peak's Hz, N) and ``excess`` how far it
    lies beyond the limit in the same unit (frequency: the share above ``FREQ_SHARE``;
    clipping: the samples at the rail); it ranks the stretches of a kind.
    """

    kind: str
    t0: float
    t1: float
    detail: str
    value: float = math.nan
    excess: float = 0.0

    @property
    def duration(self):
        """Length [s]."""
        return self.t1 - self.t0


@dataclass(frozen=True)
class DomainCheck:
    """The stretches of a record outside a domain, and the mask of what is left.

    ``mask``: True where a sample is usable (the record's own mask) and inside the domain;
    ``usable``: the record's own usable samples; ``dt`` [s] its sample period.
    """

    name: str
    stretches: tuple
    mask: np.ndarray
    usable: np.ndarray
    dt: float

    @property
    def excluded_share(self):
        """Share of the usable samples the check excludes (0 when nothing is usable)."""
        n = int(np.count_nonzero(self.usable))
        return float(np.count_nonzero(self.usable & ~self.mask) / n) if n else 0.0

    def kinds(self):
        """Return the kinds flagged, in ``KINDS`` order."""
        found = {s.kind for s in self.stretches}
        return [k for k in KINDS if k in found]

    def lines(self):
        """Return one line per kind: count, seconds, share, the worst one, the first ranges."""
        out = []
        n = max(int(np.count_nonzero(self.usable)), 1)
        for kind in self.kinds():
            st = [s for s in self.stretches if s.kind == kind]
            total = sum(s.duration for s in st)
            share = min(total / self.dt / n, 1.0)
            worst = max(st, key=lambda s: s.excess)
            where = ', '.join(f'{s.t0:.2f}-{s.t1:.2f}' for s in st[:SHOW_RANGES])
            more = ', ...' if len(st) > SHOW_RANGES else ''
            out.append(f'{kind}: {len(st)} stretch{"es" if len(st) > 1 else ""}, {total:.3g} s '
                       f'({100 * share:.1f} % of the usable record); worst: {worst.detail}; '
                       f'at {where}{more} s')
        return out


def _usable(rec):
    """Return the usable samples: the record's mask and finite motion, force and input."""
    n = int(np.asarray(rec.time).shape[0])
    mask = np.ones(n, dtype=bool) if rec.mask is None else np.asarray(rec.mask, dtype=bool)
    if mask.shape != (n,):
        raise ValueError(f'{rec.name}: mask has shape {mask.shape}, time {n} samples')
    for name in ('displacement', 'velocity', 'force', 'i_in'):
        y = np.asarray(getattr(rec, name), dtype=float)
        if y.shape != (n,):
            raise ValueError(f'{rec.name}: {name} has shape {y.shape}, time {n} samples')
        mask = mask & np.isfinite(y)
    return mask


def _dt(rec):
    """Return the sample period: ``rec.dt``, else the median time step (ValueError: neither)."""
    try:
        dt = float(rec.dt)
    except (TypeError, ValueError):
        dt = math.nan
    if math.isfinite(dt) and dt > 0:
        return dt
    t = np.asarray(rec.time, dtype=float)
    d = np.diff(t[np.isfinite(t)])
    dt = float(np.median(d)) if d.size else math.nan
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f'{rec.name}: no sample period (dt {rec.dt!r}, no increasing time)')
    return dt


def _filled(y, usable):
    """Return ``y`` with its unusable samples linearly bridged (zeros when none is usable)."""
    y = np.asarray(y, dtype=float)
    if not usable.any():
        return np.zeros(y.size)
    return sensors.fill(np.where(usable, y, 0.0), usable)


def _band(v, dt):
    """Frequency [Hz] below which ``BAND_SHARE`` of ``v``'s power lies (Hann periodogram).

    None for fewer than 16 samples or a constant velocity.
    """
    if v.size < 16:
        return None
    p = np.abs(np.fft.rfft((v - v.mean()) * np.hanning(v.size))) ** 2
    c = np.cumsum(p)
    if not c[-1] > 0:
        return None
    f = np.fft.rfftfreq(v.size, dt)
    return float(f[min(int(np.searchsorted(c, BAND_SHARE * c[-1])), f.size - 1)])


def _rest_chunks(x, v, usable, rest_v, rest_x, dt):
    """Rest chunks ``[(a, b), ...]``: ``|v| < rest_v`` for ``REST_MIN``, ``x`` within ``rest_x``.

    Runs longer than ``REST_CHUNK`` are cut into chunks of about that length, each kept when
    its stroke spans at most ``rest_x``: a slow turning point (the force passing from one
    yield level to the other over a millimetre) is motion, not rest.
    """
    shortest = max(int(math.ceil(REST_MIN / dt)), 5)
    chunk = max(int(round(REST_CHUNK / dt)), shortest)
    out = []
    slow = usable & (np.abs(np.where(usable, v, np.inf)) < rest_v)
    for a, ln in zip(*sensors.runs(slow)):
        if ln < shortest:
            continue
        edges = np.linspace(a, a + ln, max(int(ln // chunk), 1) + 1).round().astype(int)
        out.extend((int(p), int(q)) for p, q in zip(edges[:-1], edges[1:])
                   if np.ptp(x[p:q]) <= rest_x)
    return out


def _rest_sd(f, v):
    """Force deviation at rest about a quadratic in time and a line in velocity [N].

    The quadratic takes a slow drift or a ramp of the pre-yield force at a turning point, the
    line a slow passage through zero on a damper's steep low-speed slope.
    """
    t = np.linspace(-1.0, 1.0, f.size)
    s = float(np.std(v))
    a = np.column_stack([np.ones(f.size), t, t * t,
                         (v - v.mean()) / s if s > 0 else np.zeros(f.size)])
    r = f - a @ np.linalg.lstsq(a, f, rcond=None)[0]
    return float(math.sqrt(np.dot(r, r) / max(f.size - 4, 1)))


def _white_noise(f, usable):
    """White force noise [N]: robust deviation of the second differences / sqrt(6)."""
    ok = usable[2:] & usable[1:-1] & usable[:-2]
    d2 = np.diff(np.where(usable, f, 0.0), 2)[ok]
    return 1.4826 * float(np.median(np.abs(d2))) / math.sqrt(6.0) if d2.size else 0.0


def _offset(v, f, usable):
    """Force offset [N]: the constant of the least-squares ``F ~ c + a sign(v) + b v``.

    A symmetric damper's force is odd in the motion, so its yield, viscous and hysteresis
    parts leave the constant alone. Over the 30 vrths sine records (0-1 A, 0.1-5 Hz) it
    scattered by -7..13 N; the median force while slow by -437..381 N (the midpoint of a
    force that jumps between yield levels at the turning points), and adding ``|v|`` or a
    stiffness about the mid-stroke by -59..17 and -3..106 N. None unless each direction of
    motion holds ``OFFSET_MIN`` of the samples (a one-way motion has no such constant).
    """
    vu = v[usable]
    if vu.size < 10 or min(np.mean(vu > 0), np.mean(vu < 0)) < OFFSET_MIN:
        return None
    scale = max(float(np.max(np.abs(vu))), 1e-300)
    a = np.column_stack([np.ones(vu.size), np.sign(vu), vu / scale])
    return float(np.linalg.lstsq(a, f[usable], rcond=None)[0][0])


def _against(v, f):
    """Force against the motion [N]: ``max(0, -sign(v) F)`` (F + resists extension, v + out)."""
    return np.maximum(-np.sign(v) * f, 0.0)


@njit(cache=True)
def _turns(x, h):
    """Reversal samples of ``x``: extremes after which it turns back by more than ``h``.

    Returns the indices of the turning points with 0 and ``n - 1`` added (a zig-zag
    filter: a turn counts once the stroke has come back ``h`` from the running extreme).
    """
    n = x.size
    out = np.empty(n + 2, dtype=np.int64)
    m = 0
    out[m] = 0
    m += 1
    hi = 0
    lo = 0
    d = 0
    for k in range(1, n):
        if x[k] > x[hi]:
            hi = k
        if x[k] < x[lo]:
            lo = k
        if d >= 0 and x[hi] - x[k] > h:
            if hi > out[m - 1]:
                out[m] = hi
                m += 1
            d = -1
            lo = k
            hi = k
        elif d <= 0 and x[k] - x[lo] > h:
            if lo > out[m - 1]:
                out[m] = lo
                m += 1
            d = 1
            hi = k
            lo = k
    if out[m - 1] != n - 1:
        out[m] = n - 1
        m += 1
    return out[:m]


def _turn_step(disp):
    """Return the turn-back a reversal needs [m]: ``TURN`` of the stroke range, >= 0.1 mm."""
    return max(TURN * (disp[1] - disp[0]), DISP_FLOOR)


def _half_cycles(x, usable, h):
    """Return ``(starts, stops, strokes)`` of the whole half-cycles of ``x``.

    The first and last, cut by the record's ends, are left out.
    """
    xf = _filled(x, usable)
    t = _turns(xf, h)
    a, b = t[1:-2], t[2:-1]
    return a, b, np.abs(xf[b] - xf[a])


def fit_domain(records):
    """Fit the ``Domain`` of the usable samples of ``records`` (Records or one Record).

    Raises ValueError when no record holds a usable sample.
    """
    if hasattr(records, 'time'):
        records = [records]
    parts = []
    for r in records:
        u = _usable(r)
        if u.any():
            parts.append((r, u, _dt(r)))
    if not parts:
        raise ValueError('fit_domain: no usable samples in the training records')

    def cat(name):
        return np.concatenate([np.asarray(getattr(r, name), dtype=float)[u] for r, u, _ in parts])

    x, v, f, i = cat('displacement'), cat('velocity'), cat('force'), cat('i_in')
    p999 = float(np.percentile(np.abs(v), VEL_PCT))
    vel = (max(float(v.min()), -VEL_CAP * p999), min(float(v.max()), VEL_CAP * p999))
    disp = (float(x.min()), float(x.max()))
    vrange = vel[1] - vel[0]
    rest_v = max(REST_SPEED * vrange, VEL_FLOOR)
    rest_x = max(REST_STROKE * (disp[1] - disp[0]), STROKE_FLOOR)
    bands, offsets, rest, noise, halves = [], [], [], [], []
    for r, u, dt in parts:
        xr, vr, fr = (np.asarray(getattr(r, k), dtype=float)
                      for k in ('displacement', 'velocity', 'force'))
        b = _band(_filled(vr, u), dt)
        if b is not None and b > 0:
            bands.append(b)
        o = _offset(vr, fr, u)
        if o is not None:
            offsets.append((str(r.name), o))
        rest.extend(_rest_sd(fr[a:e], vr[a:e])
                    for a, e in _rest_chunks(xr, vr, u, rest_v, rest_x, dt))
        noise.append(_white_noise(fr, u))
        halves.append(_half_cycles(xr, u, _turn_step(disp))[2])
    halves = np.concatenate(halves)
    fast = np.abs(v) >= REVERSAL_SPEED * vrange
    moved = vrange > VEL_FLOOR and fast.any()
    return Domain(
        displacement=disp, velocity=vel, abs_velocity_p999=p999,
        i_in=(float(i.min()), float(i.max())),
        force=tuple(float(a) for a in np.percentile(f, [FORCE_PCT, 100 - FORCE_PCT])),
        band=max(bands) if bands and vrange > VEL_FLOOR else None, rest_velocity=rest_v,
        rest_stroke=rest_x, rest_noise=float(np.percentile(rest, REST_PCT)) if rest else None,
        force_noise=float(np.median(noise)), reversal_speed=REVERSAL_SPEED * vrange,
        reversal=float(np.percentile(_against(v[fast], f[fast]), REVERSAL_PCT)) if moved else None,
        offsets=tuple(offsets), records=len(parts), samples=int(x.size),
        half_stroke=(min(HALF_FACTOR * float(np.percentile(halves, HALF_PCT)),
                         float(np.min(halves))) if halves.size >= HALF_MIN else None))


def _grow(flags, g):
    """Return ``flags`` grown by ``g`` samples on each side."""
    if g <= 0 or not flags.any():
        return flags
    return ndimage.binary_dilation(flags, np.ones(2 * g + 1, dtype=bool))


def _beyond(y, usable, lo, hi, floor):
    """Return how far each usable sample lies beyond ``[lo, hi]`` widened by ``SLACK``."""
    tol = max(SLACK * (hi - lo), floor)
    with np.errstate(invalid='ignore'):
        return np.where(usable, np.maximum(y - hi, lo - y) - tol, -np.inf)


def _above_band(v, usable, dt, dom):
    """Return the share of the local velocity power above the band, its RMS, the high band.

    None when the domain has no band or the record cannot resolve above it.
    """
    n = v.size
    if dom.band is None or n <= 30 or FREQ_FACTOR * dom.band >= sensors.LOWPASS_MAX / dt:
        return None
    vf = _filled(v, usable)
    hi = vf - sensors.lowpass(vf, dt, FREQ_FACTOR * dom.band, order=4)
    w = int(min(max(round(FREQ_PERIODS / dom.band / dt), 5), n))
    p_all = ndimage.uniform_filter1d(vf * vf, w, mode='nearest')
    p_hi = np.maximum(ndimage.uniform_filter1d(hi * hi, w, mode='nearest'), 0.0)
    with np.errstate(divide='ignore', invalid='ignore'):
        share = np.where(p_all > 0, p_hi / p_all, 0.0)
    return share, np.sqrt(p_hi), hi


def _peak(y, dt):
    """Frequency [Hz] of the largest periodogram line of ``y`` (nan when too short)."""
    if y.size < 8:
        return math.nan
    p = np.abs(np.fft.rfft((y - y.mean()) * np.hanning(y.size))) ** 2
    p[0] = 0.0
    return float(np.fft.rfftfreq(y.size, dt)[int(np.argmax(p))])


class _Flagger:
    """Collect the stretches of a record: flags grown by the guard, described per run."""

    def __init__(self, time, dt, usable):
        self.time, self.dt, self.usable = time, dt, usable
        self.guard = max(int(round(GUARD / dt)), 1)
        self.out = np.zeros(usable.size, dtype=bool)
        self.stretches = []

    def add(self, kind, flags, describe):
        """Flag ``flags`` (usable ones only); ``describe(a, b)`` -> (value, excess, detail)."""
        flags = flags & self.usable
        if not flags.any():
            return
        grown = _grow(flags, self.guard)
        self.out |= grown
        for a, ln in zip(*sensors.runs(grown)):
            value, excess, detail = describe(a, a + ln)
            self.stretches.append(Stretch(kind, float(self.time[a]),
                                          float(self.time[a + ln - 1] + self.dt), detail,
                                          float(value), float(excess)))


def _range_rules(fl, x, v, i, dom):
    """Flag samples beyond the fitted stroke, stroke rate and input ranges (``SLACK``)."""
    for kind, y, (lo, hi), floor, word, unit, scale in (
            ('displacement', x, dom.displacement, DISP_FLOOR, 'stroke', 'mm', 1e3),
            ('velocity', v, dom.velocity, VEL_FLOOR, 'stroke rate', 'm/s', 1.0),
            ('input', i, dom.i_in, INPUT_FLOOR, 'input', 'A', 1.0)):
        excess = _beyond(y, fl.usable, lo, hi, floor)

        def describe(a, b, y=y, excess=excess, lo=lo, hi=hi, word=word, unit=unit, s=scale):
            k = a + int(np.argmax(excess[a:b]))
            return y[k], excess[k], (f'{word} {s * y[k]:.3g} {unit} beyond the fitted '
                                     f'{s * lo:.3g}..{s * hi:.3g} {unit}')
        fl.add(kind, excess > 0, describe)


def _frequency_rule(fl, v, dom):
    """Flag windows with most of their velocity power above the fitted band."""
    res = _above_band(v, fl.usable, fl.dt, dom)
    if res is None:
        return
    share, rms, hi = res
    flags = (share > FREQ_SHARE) & (rms > FREQ_FLOOR * dom.abs_velocity_p999)

    def describe(a, b):
        k = a + int(np.argmax(share[a:b]))
        peak = _peak(hi[a:b], fl.dt)
        return peak, share[k] - FREQ_SHARE, (
            f'{100 * share[k]:.0f} % of the velocity power above '
            f'{FREQ_FACTOR * dom.band:.3g} Hz (fitted band 0..{dom.band:.3g} Hz), '
            f'peak near {peak:.3g} Hz')
    fl.add('frequency', flags, describe)


def _half_cycle_rule(fl, x, dom):
    """Flag the half-cycles shorter than the fitted records' shortest (``half_stroke``)."""
    if dom.half_stroke is None:
        return
    a, b, stroke = _half_cycles(x, fl.usable, _turn_step(dom.displacement))
    small = stroke < dom.half_stroke
    if not small.any():
        return
    flags = np.zeros(x.size, dtype=bool)
    for i, j in zip(a[small], b[small]):
        flags[i:j + 1] = True

    def describe(i, j):
        inside = (a >= i) & (b < j) & small
        worst = float(stroke[inside].min()) if inside.any() else float(stroke[small].min())
        return worst, dom.half_stroke - worst, (
            f'half-cycles down to {1e3 * worst:.2f} mm of stroke, below the fitted '
            f'{1e3 * dom.half_stroke:.2f} mm')
    fl.add('half_cycle', flags, describe)


def _clipping_rule(fl, f):
    """Flag force samples held at a rail (``sensors.clipping`` on the usable samples)."""
    clip, fnd = sensors.clipping('force', np.where(fl.usable, f, np.nan))
    if fnd is None:
        return

    def describe(a, b):
        held = ~clip[a:b]
        val = float(f[a + int(np.argmax(held))])
        return val, int(np.count_nonzero(held)), (
            f'force held at its rail {val:.6g} N for {int(np.count_nonzero(held))} samples')
    fl.add('clipping', ~clip, describe)


def _reversal_rule(fl, v, f, dom):
    """Flag a force against the motion beyond the training's, at speeds the training covers."""
    if dom.reversal is None:
        return
    tol = max(SLACK * (dom.velocity[1] - dom.velocity[0]), VEL_FLOOR)
    limit = REVERSAL_FACTOR * dom.reversal + max(REVERSAL_MARGIN * dom.force_span,
                                                 NOISE_SIGMAS * dom.noise)
    vv = np.where(fl.usable, v, 0.0)
    covered = (np.abs(vv) >= dom.reversal_speed) & (vv >= dom.velocity[0] - tol)
    covered &= vv <= dom.velocity[1] + tol
    against = np.where(covered, _against(vv, np.where(fl.usable, f, 0.0)), 0.0)

    def describe(a, b):
        k = a + int(np.argmax(against[a:b]))
        return against[k], against[k] - limit, (
            f'force {against[k]:.4g} N against the motion at {v[k]:.3g} m/s (training up to '
            f'{dom.reversal:.4g} N, limit {limit:.4g} N)')
    fl.add('reversal', against > limit, describe)


def _rest_rule(fl, x, v, f, dom):
    """Flag rest chunks whose force deviates more than the training's (``REST_FACTOR``)."""
    limit = max(REST_FACTOR * dom.noise, REST_FLOOR * dom.force_span)
    sds = np.zeros(v.size)
    for a, b in _rest_chunks(x, v, fl.usable, dom.rest_velocity, dom.rest_stroke, fl.dt):
        sds[a:b] = _rest_sd(f[a:b], v[a:b])

    def describe(a, b):
        s = float(np.max(sds[a:b]))
        return s, s - limit, (f'force deviation {s:.4g} N at rest (training {dom.noise:.3g} N,'
                              f' limit {limit:.3g} N)')
    fl.add('rest_noise', sds > limit, describe)


def _offset_rule(fl, v, f, dom):
    """Flag the whole record when its offset lies outside the training offsets and a margin.

    The offset is estimated from the samples no other rule flagged.
    """
    if not dom.offsets:
        return
    o = _offset(v, f, fl.usable & ~fl.out)
    if o is None:
        return
    vals = np.array([val for _, val in dom.offsets])
    centre = float(np.median(vals))
    spread = float(np.max(np.abs(vals - centre)))
    margin = max(OFFSET_MARGIN * dom.force_span, NOISE_SIGMAS * dom.noise)
    if abs(o - centre) <= spread + margin:
        return
    detail = (f'force offset {o:.4g} N against the training {centre - spread:.4g}..'
              f'{centre + spread:.4g} N (margin {margin:.3g} N)')
    fl.stretches.append(Stretch('offset', float(fl.time[0]), float(fl.time[-1] + fl.dt),
                                detail, o, abs(o - centre) - spread - margin))


def check(record, domain):
    """Flag the stretches of ``record`` outside ``domain`` (a Domain or its dict).

    Returns a ``DomainCheck``; the rules are the module's. Bad data (constant channels, NaN,
    nothing usable, no rest, another sample period) gives fewer flags, never an exception;
    only arrays of different lengths or no sample period at all raise ValueError.
    """
    dom = domain if isinstance(domain, Domain) else Domain.from_dict(domain)
    usable = _usable(record)
    n = usable.size
    if not usable.any():
        try:
            dt = _dt(record)
        except ValueError:
            dt = 1.0
        return DomainCheck(str(record.name), (), usable.copy(), usable, dt)
    dt = _dt(record)
    t = np.asarray(record.time, dtype=float)
    if not np.all(np.isfinite(t)):
        t = (t[0] if math.isfinite(t[0]) else 0.0) + dt * np.arange(n)
    x, v, f, i = (np.asarray(getattr(record, k), dtype=float)
                  for k in ('displacement', 'velocity', 'force', 'i_in'))
    fl = _Flagger(t, dt, usable)
    _range_rules(fl, x, v, i, dom)
    _frequency_rule(fl, v, dom)
    _half_cycle_rule(fl, x, dom)
    _clipping_rule(fl, f)
    _reversal_rule(fl, v, f, dom)
    _rest_rule(fl, x, v, f, dom)
    _offset_rule(fl, v, f, dom)
    found = sorted(fl.stretches, key=lambda s: (KINDS.index(s.kind), s.t0))
    return DomainCheck(str(record.name), tuple(found), usable & ~fl.out, usable, dt)
