"""Rig programmes of the independent truth: displacement and current command on a uniform grid.

Segment types (each starts and ends at rest, by a raised-cosine taper of the displacement):

* ``harmonic``: ``x = off + a sin(2 pi f t)`` at one held current, ``f`` 0.3-12 Hz (log),
  ``a <= 0.9 v_max / (2 pi f)``, random offsets (force-velocity map, gas spring, hysteresis);
* ``steps``: constant-speed strokes (a smoothed square wave in velocity, ``tanh(6 sin)``) with
  one current edge at mid-stroke, alternately up and down (dead time, lag, rise vs fall);
* ``random``: band-limited noise motion (4th-order Butterworth, 1.5-8 Hz) with random currents
  held 30-300 ms;
* ``continuous``: harmonic or random motion under a sinusoidal or triangular current command
  (intermediate currents, saturation);
* ``sweep``: a logarithmic sine sweep 0.3-1 Hz to 6-15 Hz at a held current, amplitude
  limited by the speed (series stiffness grows with frequency, hysteresis does not).

``kind`` chooses the mix: ``'full'`` (35 % harmonic, 25 % steps, 20 % random, 10 %
continuous, 10 % sweep, segments shuffled), one segment type alone, ``'single'`` (one frequency
and amplitude, current levels cycled) or ``'constant'`` (harmonic blocks at one current).
"""

import numpy as np
from scipy import signal

KINDS = ('full', 'harmonic', 'steps', 'random', 'continuous', 'sweep', 'single', 'constant')
MIX = {'full': (('harmonic', 0.35), ('steps', 0.25), ('random', 0.2), ('continuous', 0.1),
                ('sweep', 0.1))}
SEG_SECONDS = {'harmonic': (1.5, 4.0), 'steps': (2.0, 5.0), 'random': (2.0, 5.0),
               'continuous': (3.0, 6.0), 'sweep': (4.0, 10.0), 'single': (2.0, 3.0),
               'constant': (1.5, 4.0)}


def _taper(m, ramp):
    w = np.ones(m)
    r = min(ramp, m // 3)
    if r > 1:
        h = 0.5 - 0.5 * np.cos(np.linspace(0.0, np.pi, r))
        w[:r] = h
        w[m - r:] = h[::-1]
    return w


def _levels(rng, i_max):
    mid = np.sort(rng.uniform(0.05, 0.95, size=3))
    return i_max * np.concatenate([[0.0], mid, [1.0]])


class _Ctx:
    """Scales shared by the segments of one programme."""

    def __init__(self, rng, rate, stroke, v_max, i_max):
        self.rng = rng
        self.rate = rate
        self.dt = 1.0 / rate
        self.stroke = stroke
        self.v_max = v_max
        self.i_max = i_max
        self.levels = _levels(rng, i_max)
        self.single_f = float(np.exp(rng.uniform(np.log(0.8), np.log(3.0))))
        self.single_a = min(stroke, 0.9 * v_max / (2 * np.pi * self.single_f))
        self.count = 0


def _harmonic(c, m, single=False, constant=False):
    rng = c.rng
    tt = np.arange(m) * c.dt
    if single:
        f, a, off = c.single_f, c.single_a, 0.0
    else:
        f = float(np.exp(rng.uniform(np.log(0.3), np.log(12.0))))
        a = min(c.stroke, 0.9 * c.v_max / (2 * np.pi * f)) * rng.uniform(0.3, 1.0)
        off = rng.uniform(-0.5, 0.5) * c.stroke
    x = (off + a * np.sin(2 * np.pi * f * tt)) * _taper(m, int(0.15 * c.rate))
    if constant:
        lev = c.levels[-1] * 0.6
    elif single:
        lev = c.levels[c.count % c.levels.size]
    else:
        lev = rng.choice(c.levels)
    return x, np.full(m, lev)


def _steps(c, m):
    rng = c.rng
    amp = rng.uniform(0.5, 0.9) * c.stroke
    s = rng.uniform(0.3, 0.8) * c.v_max
    s = min(s, 2 * amp / 0.2)  # strokes of at least 0.2 s: time for the current to settle
    t_r = 2 * amp / s
    tt = np.arange(m) * c.dt
    kappa = 6.0
    v = s * np.tanh(kappa * np.sin(np.pi * tt / t_r)) / np.tanh(kappa)
    x = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1])) * c.dt])
    x = (x - 0.5 * s * t_r * 0.95) * _taper(m, int(0.1 * c.rate))
    cur = np.empty(m)
    stroke_idx = np.floor(tt / t_r - 0.5).astype(int)  # edge at mid-stroke
    lev = rng.choice(c.levels)
    last = None
    for k in np.unique(stroke_idx):
        hi = lev >= np.median(c.levels)
        pool = c.levels[c.levels < lev] if hi else c.levels[c.levels > lev]
        if pool.size == 0:
            pool = c.levels[c.levels != lev]
        if last is not None:
            lev = rng.choice(pool)
        cur[stroke_idx == k] = lev
        last = k
    return x, cur


def _random_motion(c, m):
    rng = c.rng
    fc = float(np.exp(rng.uniform(np.log(1.5), np.log(8.0))))
    b, a = signal.butter(4, min(fc / (0.5 * c.rate), 0.9))
    pad = int(2 * c.rate / fc) + 10
    xr = signal.filtfilt(b, a, rng.standard_normal(m + 2 * pad))[pad:pad + m]
    xr *= rng.uniform(0.3, 0.5) * c.stroke / max(np.std(xr), 1e-12)
    lim = 1.5 * c.stroke
    xr = lim * np.tanh(xr / lim)
    vpk = np.max(np.abs(np.gradient(xr, c.dt)))
    if vpk > c.v_max:
        xr *= c.v_max / vpk
    return xr * _taper(m, int(0.1 * c.rate))


def _random(c, m):
    rng = c.rng
    x = _random_motion(c, m)
    cur = np.empty(m)
    k = 0
    while k < m:
        h = max(1, int(rng.uniform(0.03, 0.3) * c.rate))
        cur[k:k + h] = rng.uniform(0.0, c.i_max)
        k += h
    return x, cur


def _continuous(c, m):
    rng = c.rng
    tt = np.arange(m) * c.dt
    if rng.uniform() < 0.5:
        f = float(np.exp(rng.uniform(np.log(0.5), np.log(5.0))))
        a = min(c.stroke, 0.9 * c.v_max / (2 * np.pi * f)) * rng.uniform(0.4, 1.0)
        x = a * np.sin(2 * np.pi * f * tt) * _taper(m, int(0.15 * c.rate))
    else:
        x = _random_motion(c, m)
    fi = float(np.exp(rng.uniform(np.log(0.1), np.log(3.0))))
    ph = rng.uniform(0, 2 * np.pi)
    depth = rng.uniform(0.5, 1.0)
    if rng.uniform() < 0.5:
        wave = np.sin(2 * np.pi * fi * tt + ph)
    else:
        wave = signal.sawtooth(2 * np.pi * fi * tt + ph, 0.5)
    cur = np.clip(c.i_max * 0.5 * (1.0 + depth * wave), 0.0, c.i_max)
    return x, cur


def _sweep(c, m):
    rng = c.rng
    tt = np.arange(m) * c.dt
    fa = rng.uniform(0.3, 1.0)
    fb = rng.uniform(6.0, 15.0)
    dur = m * c.dt
    k = np.log(fb / fa) / dur
    f = fa * np.exp(k * tt)
    phase = 2 * np.pi * fa * (np.exp(k * tt) - 1.0) / k
    a = np.minimum(c.stroke, 0.9 * c.v_max / (2 * np.pi * f)) * rng.uniform(0.4, 1.0)
    x = a * np.sin(phase) * _taper(m, int(0.15 * c.rate))
    return x, np.full(m, rng.choice(c.levels[1:]))  # a sweep at 0 A shows no field


_SEGMENTS = {'harmonic': _harmonic, 'steps': _steps, 'random': _random,
             'continuous': _continuous, 'sweep': _sweep,
             'single': lambda c, m: _harmonic(c, m, single=True),
             'constant': lambda c, m: _harmonic(c, m, constant=True)}


def programme(rng, duration=20.0, rate=1000.0, kind='full', stroke=None, v_max=None,
              i_max=1.0):
    """Return a rig programme ``(t, x, i_cmd)``: time [s], displacement [m], command [A].

    ``rng`` a numpy Generator; ``stroke`` the largest amplitude [m] (drawn 8-30 mm if None),
    ``v_max`` the largest speed [m/s] (drawn 0.15-0.5 m/s if None), ``i_max`` the largest
    command [A]. Segment types and the ``kind`` mixes are in the module docstring.
    """
    if kind not in KINDS:
        raise ValueError(f'programme: unknown kind {kind!r}; known: {", ".join(KINDS)}')
    if not (np.isfinite(duration) and duration > 0 and np.isfinite(rate) and rate > 0):
        raise ValueError('programme: duration and rate must be finite and > 0')
    if not (np.isfinite(i_max) and i_max > 0):
        raise ValueError('programme: i_max must be finite and > 0')
    n = int(round(duration * rate))
    if n < 10:
        raise ValueError(f'programme: {n} samples; need at least 10 (duration * rate)')
    stroke = rng.uniform(0.008, 0.03) if stroke is None else float(stroke)
    v_max = rng.uniform(0.15, 0.5) if v_max is None else float(v_max)
    if not (stroke > 0 and v_max > 0):
        raise ValueError('programme: stroke and v_max must be > 0')
    c = _Ctx(rng, float(rate), stroke, v_max, float(i_max))
    mix = MIX.get(kind, ((kind, 1.0),))
    pieces = []
    for name, frac in mix:
        budget = int(round(frac * n))
        lo, hi = SEG_SECONDS[name]
        while budget > 0:
            m = int(rng.uniform(lo, hi) * rate)
            if budget - m < int(0.5 * lo * rate):
                m = budget  # no stub shorter than half a segment: extend this one
            pieces.append((name, m))
            budget -= m
    order = rng.permutation(len(pieces)) if kind == 'full' else np.arange(len(pieces))
    x = np.zeros(n)
    cur = np.zeros(n)
    k = 0
    for j in order:
        name, m = pieces[j]
        m = min(m, n - k)
        if m <= 0:
            break
        xs, cs = _SEGMENTS[name](c, m)
        c.count += 1
        x[k:k + m] = xs
        cur[k:k + m] = cs
        k += m
    t = np.arange(n) / rate
    return t, x, cur
