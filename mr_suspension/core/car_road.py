"""Roads for a four-wheel car: one profile per corner, rear wheels on the front tracks.

A :class:`CarRoad` holds the road height and rate under the four wheels in :data:`CORNERS`
order, sampled at ``dt`` with ``n + 1`` samples like :class:`road.Road`. At constant ``speed``
the rear wheels run in the front tracks delayed by ``tau = wheelbase / speed``. The left and
right tracks are ``track`` apart; random ISO 8608 tracks are correlated by the isotropic-road
coherence of Dodds & Robson (1973).
"""

from dataclasses import dataclass
import math

import numpy as np
from scipy import special

from mr_suspension.core import road as rd
from mr_suspension.core.validation import check_range

CORNERS = ('front_left', 'front_right', 'rear_left', 'rear_right')
SIDES = ('left', 'right', 'both')
COHERENCE_MODELS = ('isotropic', None)

TRACK_MIN, TRACK_MAX = 0.5, 3.0  # [m] left-right wheel distance
WHEELBASE_MIN, WHEELBASE_MAX = 0.5, 10.0  # [m] front-rear axle distance
RIG_SPEED = 10.0  # [m/s] speed that turns a rig-like single-track road into a car road
WHOLE_TOL = 1.0e-9  # [samples] a delay this close to a whole number of samples is whole


def _check_speed(owner, speed):
    return check_range(owner, 'speed', speed, 0.01, rd.SPEED_MAX, 'm/s', 'vehicle speed')


def _check_track(owner, track):
    return check_range(owner, 'track', track, TRACK_MIN, TRACK_MAX, 'm',
                       'left-right wheel distance')


def _check_wheelbase(owner, wheelbase):
    return check_range(owner, 'wheelbase', wheelbase, WHEELBASE_MIN, WHEELBASE_MAX, 'm',
                       'front-rear axle distance')


@dataclass(frozen=True)
class CarRoad:
    """Road under the four wheels: ``z``, ``zdot`` of shape (4, n + 1) in :data:`CORNERS` order.

    ``speed`` [m/s] and ``wheelbase`` [m] give the front-to-rear delay ``tau``.
    """

    name: str
    dt: float
    z: np.ndarray
    zdot: np.ndarray
    speed: float
    wheelbase: float

    def __post_init__(self):
        """Check the step, the geometry and the shapes; store ``z``, ``zdot`` as float arrays."""
        if not isinstance(self.name, str):
            raise ValueError(f'CarRoad: name must be a string, got {self.name!r}')
        check_range('CarRoad', 'dt', self.dt, 1.0e-6, 0.1, 's', 'time step')
        _check_speed('CarRoad', self.speed)
        _check_wheelbase('CarRoad', self.wheelbase)
        for key in ('z', 'zdot'):
            try:
                value = np.asarray(getattr(self, key), dtype=float)
            except (TypeError, ValueError):
                raise ValueError(f'CarRoad: {key} must be a numeric array') from None
            if value.ndim != 2 or value.shape[0] != len(CORNERS) or value.shape[1] < 3:
                raise ValueError(f'CarRoad: {key} must have shape (4, n + 1) with one row per '
                                 f'corner {CORNERS} and n >= 2, got {value.shape}')
            if not np.all(np.isfinite(value)):
                raise ValueError(f'CarRoad: {key} must be finite (no NaN or inf)')
            object.__setattr__(self, key, value)
        if self.zdot.shape != self.z.shape:
            raise ValueError(f'CarRoad: zdot shape {self.zdot.shape} differs from z shape '
                             f'{self.z.shape}')

    @property
    def t(self):
        """Sample times [s]."""
        return np.arange(self.z.shape[1]) * self.dt

    @property
    def n_steps(self):
        """Number of simulation steps the road covers."""
        return self.z.shape[1] - 1

    @property
    def duration(self):
        """Covered duration [s]."""
        return self.n_steps * self.dt

    @property
    def tau(self):
        """Front-to-rear delay ``wheelbase / speed`` [s]."""
        return self.wheelbase / self.speed

    def corner(self, i):
        """Road under one wheel: ``i`` is an index 0..3 or a name of :data:`CORNERS`."""
        if isinstance(i, str) and i in CORNERS:
            i = CORNERS.index(i)
        if isinstance(i, (bool, np.bool_)) or not isinstance(i, (int, np.integer)) \
                or not 0 <= i < len(CORNERS):
            raise ValueError(f'CarRoad: corner must be 0..3 or one of {CORNERS}, got {i!r}')
        return rd.Road(f'{self.name}_{CORNERS[i]}', self.dt, self.z[i].copy(),
                       self.zdot[i].copy())


def _split_delay(tau, dt):
    """Delay ``tau`` in samples as ``(shift, whole)``; within WHOLE_TOL of an integer is whole."""
    shift = tau / dt
    m = round(shift)
    if abs(shift - m) <= WHOLE_TOL:
        return m, True
    return shift, False


def _delay_samples(z, zdot, tau, dt):
    """Return ``z(t - tau)``, ``zdot(t - tau)``; at rest (``z[0]``, rate 0) before ``tau``.

    A whole-sample delay shifts the samples exactly; otherwise z and zdot are interpolated
    linearly between the two neighbouring samples (error <= dt^2 max|z''| / 8).
    """
    size = z.size
    shift, whole = _split_delay(tau, dt)
    zd = np.full(size, z[0])
    zdd = np.zeros(size)
    if whole:
        if shift < size:
            zd[shift:] = z[:size - shift]
            zdd[shift:] = zdot[:size - shift]
        return zd, zdd
    s = np.arange(size) - shift
    after = s >= 0.0
    i = np.floor(s[after]).astype(int)
    w = s[after] - i
    j = np.minimum(i + 1, size - 1)
    zd[after] = (1.0 - w) * z[i] + w * z[j]
    zdd[after] = (1.0 - w) * zdot[i] + w * zdot[j]
    return zd, zdd


def from_track(road, wheelbase, speed, right=None):
    """Car road from single-track roads: left track ``road``, right track ``right`` (or ``road``).

    The rear wheels see the front tracks delayed by ``tau = wheelbase / speed``. The profile
    between samples is unknown, so ``z(t - tau)`` and ``zdot(t - tau)`` are interpolated
    linearly (exact when ``tau`` is a whole number of samples); before ``t = tau`` the rear
    wheels stand on the road at rest: the track's first height ``z[0]``, rate 0 (a road that
    does not start at rest, e.g. a harmonic, gives the rear a rate jump at ``tau``).
    """
    for key, value in (('road', road), ('right', right)):
        if value is not None and not isinstance(value, rd.Road):
            raise ValueError(f'from_track: {key} must be a road.Road, got '
                             f'{type(value).__name__}')
    if road is None:
        raise ValueError('from_track: road must be a road.Road, got None')
    wheelbase = _check_wheelbase('from_track', wheelbase)
    speed = _check_speed('from_track', speed)
    left = road
    right = left if right is None else right
    if right.dt != left.dt or right.z.size != left.z.size:
        raise ValueError(f'from_track: left and right tracks must share dt and length, got '
                         f'dt {left.dt:g}/{right.dt:g} s and {left.z.size}/{right.z.size} '
                         'samples')
    tau = wheelbase / speed
    rear = [_delay_samples(np.asarray(trk.z, dtype=float), np.asarray(trk.zdot, dtype=float),
                           tau, left.dt) for trk in (left, right)]
    z = np.stack([left.z, right.z, rear[0][0], rear[1][0]])
    zdot = np.stack([left.zdot, right.zdot, rear[0][1], rear[1][1]])
    name = left.name if right is left else f'{left.name}+{right.name}'
    return CarRoad(name, left.dt, z, zdot, speed, wheelbase)


def isotropic_coherence(n, track=1.4, waviness=2.0):
    """Coherence of two parallel tracks ``track`` [m] apart on an isotropic road.

    For an isotropic surface whose profile PSD is ``Gd(n) ~ n^(-w)`` the cross-spectral density
    of parallel tracks ``B`` apart is ``gamma(n) Gd(n)`` with
    ``gamma(n) = 2^(1 - nu) / Gamma(nu) u^nu K_nu(u)``, ``u = 2 pi n B``, ``nu = w / 2`` and
    ``K_nu`` the modified Bessel function of the second kind; for the ISO 8608 ``w = 2``,
    ``gamma = u K_1(u)``. Isotropic road model of Dodds & Robson (1973, J. Sound Vib. 31(2)
    175-183) and Kamash & Robson (1978, J. Sound Vib. 57(1) 89-100); no fitted constants, the
    track width B and the waviness w set it. ``gamma`` is real, 1 at n = 0, falling to 0.5 near
    ``n B = 0.2`` (w = 2); the magnitude-squared coherence is ``gamma^2``. n in cycle/m.
    """
    track = _check_track('isotropic_coherence', track)
    waviness = check_range('isotropic_coherence', 'waviness', waviness, 0.1, 5.0, '',
                           'PSD slope')
    nu = 0.5 * waviness
    u = 2.0 * np.pi * np.abs(np.asarray(n, dtype=float)) * track
    safe = np.where(u > 0.0, u, 1.0)
    with np.errstate(under='ignore'):
        gamma = 2.0 ** (1.0 - nu) / math.gamma(nu) * safe ** nu * special.kv(nu, safe)
    return np.clip(np.where(u > 0.0, gamma, 1.0), 0.0, 1.0)


def _fade(u, udot, s):
    """Fade ``u`` in over 1 s from local time ``s = 0``: height and exact rate.

    Height ``u(s) r(s)`` with ramp ``r = clip(s, 0, 1)``, rate ``u'(s) r(s) + u(s) r'(s)``
    (product rule, ``r' = 1`` on ``0 <= s < 1``), as :func:`road.iso8608` for ``s = t``.
    """
    ramp = np.clip(s / 1.0, 0.0, 1.0)
    slope = np.where((s >= 0.0) & (s < 1.0), 1.0, 0.0)
    return u * ramp, udot * ramp + u * slope


def _profile(coeff, freqs, n_samples):
    """Profile of the one-sided spectrum ``coeff`` and its rate (derivative ``2 pi i f``)."""
    return (np.fft.irfft(coeff, n_samples),
            np.fft.irfft(coeff * 2j * np.pi * freqs, n_samples))


def _delayed_profile(coeff, freqs, n_samples, dt, tau):
    """Profile and rate of spectrum ``coeff`` at ``t - tau``, and the local time ``t - tau``.

    The profile is a trigonometric polynomial of period ``n_samples dt``: a whole-sample delay
    rolls the samples (exact), a fractional one multiplies the spectrum by
    ``exp(-2 pi i f tau)``. The periodic wrap only reaches ``t < tau``, where the delayed
    fade-in is zero.
    """
    shift, whole = _split_delay(tau, dt)
    k = np.arange(n_samples)
    if whole:
        u, udot = _profile(coeff, freqs, n_samples)
        return np.roll(u, shift), np.roll(udot, shift), (k - shift) * dt
    u, udot = _profile(coeff * np.exp(-2j * np.pi * freqs * tau), freqs, n_samples)
    return u, udot, k * dt - tau


def iso8608_two_track(road_class='C', speed=20.0, duration=60.0, dt=1e-3, seed=0, track=1.4,
                      wheelbase=2.3, n_min=0.011, n_max=10.0, waviness=2.0,
                      coherence='isotropic'):
    """Random ISO 8608 road under four wheels, left/right tracks with isotropic coherence.

    Both tracks have the PSD ``G(f) = Gd(f / V) / V`` of :func:`road.iso8608_psd` on the FFT
    grid ``f_k`` (band ``n_min..n_max`` cycle/m, below Nyquist): left ``A_k e^(i phi_k)``,
    right ``A_k (gamma_k e^(i phi_k) + sqrt(1 - gamma_k^2) e^(i psi_k))`` with
    ``A_k = sqrt(2 G(f_k) df)``, independent uniform phases ``phi_k``, ``psi_k`` and
    ``gamma_k`` the coherence of :func:`isotropic_coherence` at ``n_k = f_k / V`` for tracks
    ``track`` [m] apart, so the left/right cross-spectrum is ``gamma G`` (magnitude-squared
    coherence ``gamma^2``). ``coherence=None`` makes the right track identical to the left.
    The rear wheels see the front profiles exactly ``tau = wheelbase / speed`` later, fade-in
    included: ``rear(t) = front(t - tau)`` and 0 before ``tau``. Heights and rates are exact
    (frequency-domain derivative, product rule for the 1 s fade-in); reproducible from ``seed``
    and the front-left track equals :func:`road.iso8608` with the same arguments.
    """
    owner = 'iso8608_two_track'
    if coherence is not None and not (isinstance(coherence, str)
                                      and coherence in COHERENCE_MODELS):
        raise ValueError(f'{owner}: coherence must be one of {COHERENCE_MODELS} (None: '
                         f'identical left and right tracks), got {coherence!r}')
    speed = _check_speed(owner, speed)
    track = _check_track(owner, track)
    wheelbase = _check_wheelbase(owner, wheelbase)
    check_range(owner, 'n_min', n_min, 1.0e-4, 100.0, 'cycle/m', 'lowest wavenumber')
    check_range(owner, 'n_max', n_max, 1.0e-4, 100.0, 'cycle/m', 'highest wavenumber')
    check_range(owner, 'waviness', waviness, 0.0 if coherence is None else 0.1, 5.0, '',
                'PSD slope')
    if n_min >= n_max:
        raise ValueError(f'{owner}: n_min ({n_min:g}) must be below n_max ({n_max:g})')
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f'{owner}: seed must be an integer >= 0, got {seed!r}')
    rd.iso8608_psd(rd.ISO8608_N0, road_class, waviness)  # validates the class
    road_class = str(road_class).upper()
    t = rd._grid(duration, dt)
    n_samples = t.size
    freqs = np.fft.rfftfreq(n_samples, dt)
    df = freqs[1]
    spatial = freqs / speed
    band = (spatial >= n_min) & (spatial <= n_max) & (freqs < 0.5 / dt)
    gd = np.zeros_like(freqs)
    gd[band] = rd.iso8608_psd(spatial[band], road_class, waviness) / speed
    amp = np.sqrt(2.0 * gd * df)
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0.0, 2.0 * np.pi, freqs.size)
    left = 0.5 * n_samples * amp * np.exp(1j * phase)
    if coherence is None:
        right = left
    else:
        psi = rng.uniform(0.0, 2.0 * np.pi, freqs.size)
        gamma = isotropic_coherence(spatial, track, waviness)
        right = 0.5 * n_samples * amp * (gamma * np.exp(1j * phase)
                                         + np.sqrt(1.0 - gamma ** 2) * np.exp(1j * psi))
    tau = wheelbase / speed
    tracks = (left,) if coherence is None else (left, right)
    fronts = [_fade(*_profile(c, freqs, n_samples), t) for c in tracks]
    rears = [_fade(*_delayed_profile(c, freqs, n_samples, dt, tau)) for c in tracks]
    parts = [fronts[0], fronts[-1], rears[0], rears[-1]]
    z = np.stack([p[0] for p in parts])
    zdot = np.stack([p[1] for p in parts])
    tag = '' if coherence is None else f'_{coherence}'
    return CarRoad(f'iso8608_{road_class}_{speed:g}mps_2track{tag}', dt, z, zdot, speed,
                   wheelbase)


def bump(height=0.05, length=2.0, speed=10.0, t0=0.5, side='both', duration=10.0, dt=1e-3,
         track=1.4, wheelbase=2.3):
    """``(1 - cos)`` bump of :func:`road.bump` under the ``side`` = left, right or both wheels.

    Front wheels cross it from ``t0``, rear wheels from ``t0 + wheelbase / speed``; heights and
    rates are analytic for all four. ``track`` is only checked: a bump spans one whole track
    (``'left'``/``'right'``) or the full width (``'both'``), whatever the track width.
    """
    if not isinstance(side, str) or side not in SIDES:
        raise ValueError(f'bump: side must be one of {SIDES} (wheels that cross the bump), got '
                         f'{side!r}')
    _check_track('bump', track)
    wheelbase = _check_wheelbase('bump', wheelbase)
    speed = _check_speed('bump', speed)
    front = rd.bump(height, length, speed, t0, duration, dt)
    rear = rd.bump(height, length, speed, t0 + wheelbase / speed, duration, dt)
    zero = np.zeros_like(front.z)
    on_left = side in ('left', 'both')
    on_right = side in ('right', 'both')
    rows = [(front, on_left), (front, on_right), (rear, on_left), (rear, on_right)]
    z = np.stack([r.z if on else zero for r, on in rows])
    zdot = np.stack([r.zdot if on else zero for r, on in rows])
    return CarRoad(f'bump_{side}', dt, z, zdot, speed, wheelbase)


def from_spec(spec, duration=None, dt=1e-3, wheelbase=2.3, track=1.4):
    """Build a car road from a mapping such as ``{'type': 'iso8608', 'road_class': 'C', ...}``.

    ``iso8608`` and ``bump`` give :func:`iso8608_two_track` and :func:`bump`; the single-track
    types ``step``, ``harmonic`` and ``sweep`` (:func:`road.from_spec`) are put under both
    tracks by :func:`from_track` at the spec's ``speed`` or, for these rig-like roads,
    ``RIG_SPEED`` = 10 m/s. ``wheelbase`` and ``track`` (vehicle geometry) are arguments, not
    spec keys.
    """
    if not isinstance(spec, dict):
        raise ValueError(f'car road: expected a mapping such as {{type: bump}}, got {spec!r}')
    spec = dict(spec)
    kind = spec.pop('type', None)
    makers = {'iso8608': iso8608_two_track, 'bump': bump}
    single = ('step', 'harmonic', 'sweep')
    kinds = sorted(list(makers) + list(single))
    if not isinstance(kind, str) or kind not in kinds:
        raise ValueError(f'car road type must be one of {kinds}, got {kind!r}')
    clash = sorted({'track', 'wheelbase'} & set(spec))
    if clash:
        raise ValueError(f'car road {kind}: give {" and ".join(clash)} as arguments of '
                         'from_spec (vehicle geometry), not in the road spec')
    if duration is not None:
        spec['duration'] = duration
    spec.pop('dt', None)
    if kind in single:
        speed = spec.pop('speed', RIG_SPEED)
        return from_track(rd.from_spec(dict(spec, type=kind), None, dt), wheelbase, speed)
    try:
        return makers[kind](dt=dt, wheelbase=wheelbase, track=track, **spec)
    except TypeError as exc:
        raise ValueError(f'car road {kind}: {exc}') from None
