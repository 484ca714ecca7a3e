"""Road and rig excitations: step, bump (seed 003), ISO 8608 random roads, harmonic and sweep.

Every generator returns a :class:`Road` sampled at ``dt`` with ``n + 1`` samples (the simulator
reads the road at mid-step) and the exact road velocity where it is known analytically.
"""

from dataclasses import dataclass
import math

import numpy as np

from mr_suspension.core.validation import check_range

# ISO 8608:2016 Table 2: geometric mean of the displacement PSD Gd(n0) at n0 = 0.1 cycle/m,
# classes A..H, in m^3 (16e-6 m^3 for class A, x4 per class).
ISO8608_N0 = 0.1
ISO8608_GD = {c: 16e-6 * 4.0 ** k for k, c in enumerate('ABCDEFGH')}


@dataclass(frozen=True)
class Road:
    """Road profile under one wheel: time [s], height [m] and its rate [m/s]."""

    name: str
    dt: float
    z: np.ndarray
    zdot: np.ndarray

    @property
    def t(self):
        """Sample times [s]."""
        return np.arange(self.z.size) * self.dt

    @property
    def n_steps(self):
        """Number of simulation steps the road covers."""
        return self.z.size - 1

    @property
    def duration(self):
        """Covered duration [s]."""
        return self.n_steps * self.dt


# Plausible road inputs (SI): any real road, rig or test track fits inside.
HEIGHT_MAX = 0.5  # [m] step/bump height, harmonic/sweep amplitude
SPEED_MAX = 100.0  # [m/s]
DURATION_MAX = 3600.0  # [s] one simulated hour
FREQ_MAX = 500.0  # [Hz]


def _grid(duration, dt):
    check_range('road', 'duration', duration, 1.0e-6, DURATION_MAX, 's', 'simulated time')
    check_range('road', 'dt', dt, 1.0e-6, 0.1, 's', 'time step')
    n = int(round(duration / dt))
    if n < 2:
        raise ValueError('road: duration must cover at least two steps')
    return np.arange(n + 1) * dt


def step(height=0.05, t0=0.5, rise=0.01, duration=10.0, dt=1e-3):
    """Step of ``height`` at ``t0`` smoothed by a half-cosine over ``rise`` (tyre envelope)."""
    t = _grid(duration, dt)
    check_range('step', 'height', height, -HEIGHT_MAX, HEIGHT_MAX, 'm', 'step height')
    check_range('step', 't0', t0, 0.0, DURATION_MAX, 's', 'start time')
    check_range('step', 'rise', rise, 1.0e-4, 100.0, 's', 'rise time')
    u = np.clip((t - t0) / rise, 0.0, 1.0)
    z = height * 0.5 * (1.0 - np.cos(np.pi * u))
    inside = (u > 0.0) & (u < 1.0)
    zdot = np.where(inside, height * 0.5 * np.pi / rise * np.sin(np.pi * u), 0.0)
    return Road('step', dt, z, zdot)


def bump(height=0.05, length=2.0, speed=10.0, t0=0.5, duration=10.0, dt=1e-3):
    """Single ``(1 - cos)`` bump of ``height`` and ``length`` crossed at ``speed`` (seed 003)."""
    check_range('bump', 'height', height, -HEIGHT_MAX, HEIGHT_MAX, 'm', 'bump height')
    check_range('bump', 'length', length, 0.01, 1000.0, 'm', 'bump length')
    check_range('bump', 'speed', speed, 0.01, SPEED_MAX, 'm/s', 'vehicle speed')
    check_range('bump', 't0', t0, 0.0, DURATION_MAX, 's', 'start time')
    t = _grid(duration, dt)
    tb = length / speed
    u = np.clip((t - t0) / tb, 0.0, 1.0)
    z = height * 0.5 * (1.0 - np.cos(2.0 * np.pi * u))
    inside = (u > 0.0) & (u < 1.0)
    zdot = np.where(inside, height * np.pi / tb * np.sin(2.0 * np.pi * u), 0.0)
    return Road('bump', dt, z, zdot)


def harmonic(amplitude=0.01, freq=1.0, duration=10.0, dt=1e-3):
    """Harmonic excitation ``z = A sin(2 pi f t)`` (seed 001 rig and frequency responses)."""
    check_range('harmonic', 'amplitude', amplitude, 0.0, HEIGHT_MAX, 'm', 'road amplitude')
    check_range('harmonic', 'freq', freq, 1.0e-3, FREQ_MAX, 'Hz', 'frequency')
    t = _grid(duration, dt)
    w = 2.0 * np.pi * freq
    return Road(f'harmonic_{freq:g}Hz', dt, amplitude * np.sin(w * t),
                amplitude * w * np.cos(w * t))


def sweep(amplitude=0.005, f_start=0.5, f_end=20.0, duration=60.0, dt=1e-3):
    """Exponential sine sweep from ``f_start`` to ``f_end`` with constant amplitude."""
    check_range('sweep', 'amplitude', amplitude, 0.0, HEIGHT_MAX, 'm', 'road amplitude')
    check_range('sweep', 'f_start', f_start, 1.0e-3, FREQ_MAX, 'Hz', 'start frequency')
    check_range('sweep', 'f_end', f_end, 1.0e-3, FREQ_MAX, 'Hz', 'end frequency')
    if f_start == f_end:
        raise ValueError('sweep: f_start and f_end must differ; use --road harmonic for one '
                         'frequency')
    t = _grid(duration, dt)
    k = math.log(f_end / f_start) / t[-1]
    phase = 2.0 * np.pi * f_start * (np.exp(k * t) - 1.0) / k
    freq = f_start * np.exp(k * t)
    return Road('sweep', dt, amplitude * np.sin(phase),
                amplitude * 2.0 * np.pi * freq * np.cos(phase))


def iso8608_psd(n, road_class='C', waviness=2.0):
    """ISO 8608 displacement PSD ``Gd(n) = Gd(n0) (n / n0)^(-w)`` [m^3], n in cycle/m."""
    road_class = str(road_class).upper()
    if road_class not in ISO8608_GD:
        raise ValueError(f'iso8608: road class must be one of A..H, got {road_class!r}')
    return ISO8608_GD[road_class] * (np.asarray(n, dtype=float) / ISO8608_N0) ** (-waviness)


def iso8608(road_class='C', speed=20.0, duration=60.0, dt=1e-3, seed=0, n_min=0.011,
            n_max=10.0, waviness=2.0):
    """Random road of ISO 8608 class ``road_class`` at ``speed`` [m/s], reproducible from ``seed``.

    Random-phase harmonic synthesis on the FFT grid: ``z(t) = sum A_k cos(2 pi f_k t + phi_k)``
    with ``A_k = sqrt(2 G(f_k) df)`` and the time-frequency PSD ``G(f) = Gd(f / V) / V``, band
    limited to ``n_min..n_max`` cycle/m (and the Nyquist frequency). ``zdot`` is exact.
    """
    check_range('iso8608', 'speed', speed, 0.01, SPEED_MAX, 'm/s', 'vehicle speed')
    check_range('iso8608', 'n_min', n_min, 1.0e-4, 100.0, 'cycle/m', 'lowest wavenumber')
    check_range('iso8608', 'n_max', n_max, 1.0e-4, 100.0, 'cycle/m', 'highest wavenumber')
    check_range('iso8608', 'waviness', waviness, 0.0, 5.0, '', 'PSD slope')
    if n_min >= n_max:
        raise ValueError(f'iso8608: n_min ({n_min:g}) must be below n_max ({n_max:g})')
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f'iso8608: seed must be an integer >= 0, got {seed!r}')
    t = _grid(duration, dt)
    n_samples = t.size
    freqs = np.fft.rfftfreq(n_samples, dt)
    df = freqs[1]
    spatial = freqs / speed
    band = (spatial >= n_min) & (spatial <= n_max) & (freqs < 0.5 / dt)
    gd = np.zeros_like(freqs)
    gd[band] = iso8608_psd(spatial[band], road_class, waviness) / speed
    amp = np.sqrt(2.0 * gd * df)
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0.0, 2.0 * np.pi, freqs.size)
    coeff = 0.5 * n_samples * amp * np.exp(1j * phase)
    z = np.fft.irfft(coeff, n_samples)
    zdot = np.fft.irfft(coeff * 2j * np.pi * freqs, n_samples)
    ramp = np.clip(t / 1.0, 0.0, 1.0)  # 1 s fade-in so the car starts at rest
    return Road(f'iso8608_{road_class}_{speed:g}mps', dt, z * ramp,
                zdot * ramp + z * np.where(t < 1.0, 1.0, 0.0))


def from_spec(spec, duration=None, dt=1e-3):
    """Build a road from a mapping such as ``{'type': 'iso8608', 'road_class': 'C', ...}``."""
    if not isinstance(spec, dict):
        raise ValueError(f'road: expected a mapping such as {{type: step}}, got {spec!r}')
    spec = dict(spec)
    kind = spec.pop('type', None)
    makers = {'step': step, 'bump': bump, 'harmonic': harmonic, 'sweep': sweep,
              'iso8608': iso8608}
    if not isinstance(kind, str) or kind not in makers:
        raise ValueError(f'road type must be one of {sorted(makers)}, got {kind!r}')
    if duration is not None:
        spec['duration'] = duration
    spec['dt'] = dt
    try:
        return makers[kind](**spec)
    except TypeError as exc:
        raise ValueError(f'road {kind}: {exc}') from None
