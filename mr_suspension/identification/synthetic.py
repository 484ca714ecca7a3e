"""Synthetic rig records from a truth model richer than the baseline, and the DoE rig programme.

The programme (``doe_programme``) follows seed 000's three series and seed 002's DoE remarks:
(i) harmonic motion at several frequencies, amplitudes and displacement offsets at constant
currents (force-velocity map, saturation, hysteresis vs series stiffness, gas spring), (ii)
current steps up and down at constant damper speed (dead time, lag, rise vs fall), (iii) random
motion with random current levels (broadband, 0-10 Hz); a long record keeps heating the damper
(thermal fade). ``make_record`` runs the truth model (current dynamics then
``extended_force``) and adds AR(1)-coloured noise.
"""

import numpy as np

from mr_suspension.core.extended import ExtendedDamperParams, simulate_extended
from mr_suspension.identification.data import build_record, LoadOptions
from mr_suspension.identification.engine import EFFECTS, field_current


def _window(n, ramp):
    w = np.ones(n)
    r = min(ramp, n // 2)
    if r > 0:
        h = 0.5 - 0.5 * np.cos(np.linspace(0, np.pi, r))
        w[:r] = h
        w[n - r:] = h[::-1]
    return w


def doe_programme(duration=60.0, rate=1000.0, stroke=0.02, v_max=0.25, i_max=1.0, seed=0,
                  kind='full'):
    """Rig programme ``(t, x, i_cmd)``: displacement [m] and current command [A].

    ``kind='full'``: 40 % harmonic blocks (0.5-6 Hz, offsets, 4 current levels), 30 % current
    steps at constant speed, 30 % random motion and current. ``'harmonic'``: only harmonic
    blocks at constant currents; ``'single'``: one frequency and amplitude, constant currents.
    """
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate
    n = int(round(duration * rate))
    t = np.arange(n) * dt
    x = np.zeros(n)
    cur = np.zeros(n)
    levels = i_max * np.array([0.0, 0.35, 0.7, 1.0])
    if kind == 'full':
        n1, n2 = int(0.4 * n), int(0.7 * n)
    else:
        n1 = n2 = n
    # (i) harmonic blocks at constant current.
    k = 0
    j = 0
    freqs = [0.5, 1.0, 2.0, 4.0, 6.0] if kind != 'single' else [1.5]
    while k < n1:
        f = freqs[j % len(freqs)] if kind == 'single' else freqs[rng.integers(len(freqs))]
        a = min(stroke, 0.8 * v_max / (2 * np.pi * f))
        if kind != 'single':
            a *= rng.uniform(0.5, 1.0)
        off = rng.uniform(-0.5, 0.5) * stroke if kind == 'full' else 0.0
        m = min(int(max(1.5, 3.0 / f) * rate), n1 - k)
        tt = np.arange(m) * dt
        w = _window(m, int(0.15 * rate))
        x[k:k + m] = (off + a * np.sin(2 * np.pi * f * tt)) * w
        cur[k:k + m] = levels[j % len(levels)]
        k += m
        j += 1
    # (ii) current steps at constant speed: triangle wave, two current edges per ramp.
    if n2 > n1:
        m = n2 - n1
        s = 0.5 * v_max
        amp = 0.8 * stroke
        ramp = 2 * amp / s
        tt = np.arange(m) * dt
        ph = (tt / ramp) % 2.0
        tri = np.where(ph < 1.0, -amp + 2 * amp * ph, amp - 2 * amp * (ph - 1.0))
        x[n1:n2] = tri * _window(m, int(0.1 * rate))
        q = np.floor(tt / (ramp / 2) + 0.5).astype(int)
        hi = levels[rng.integers(2, 4, size=q.max() + 2)]
        lo = levels[rng.integers(0, 2, size=q.max() + 2)]
        cur[n1:n2] = np.where(q % 2 == 0, lo[q], hi[q])
    # (iii) random motion and random current levels.
    if n > n2:
        m = n - n2
        from scipy import signal
        b, a = signal.butter(2, 3.0 / (0.5 * rate))
        xr = signal.lfilter(b, a, rng.standard_normal(m + 2000))[2000:]
        xr *= 0.5 * stroke / np.std(xr)
        x[n2:] = np.clip(xr, -1.5 * stroke, 1.5 * stroke) * _window(m, int(0.1 * rate))
        kk = n2
        while kk < n:
            h = int(rng.uniform(0.03, 0.3) * rate)
            cur[kk:kk + h] = rng.uniform(0, i_max)
            kk += h
    return t, x, cur


def random_truth(rng, effects=(), i_max=1.0):
    """Draw truth parameters: a random baseline plus the given effects (SI)."""
    d = {'f0': rng.uniform(-30, 30), 'c0': rng.uniform(300, 1500),
         'c1': rng.uniform(500, 2500) / i_max, 'fy0': rng.uniform(30, 150),
         'fy1': rng.uniform(300, 1200) / i_max, 'v_y': rng.uniform(0.005, 0.03)}
    dyn = {'dead_time': 0.0, 'tau_rise': 0.0, 'tau_fall': 0.0}
    for e in effects:
        if e not in EFFECTS:
            raise ValueError(f'unknown effect {e!r}; known: {EFFECTS}')
        if e == 'current_delay':
            dyn['dead_time'] = round(rng.uniform(0.010, 0.040), 3)
        elif e == 'current_lag':
            dyn['tau_rise'] = dyn['tau_fall'] = rng.uniform(0.010, 0.050)
        elif e == 'current_lag_asymmetric':
            dyn['tau_rise'] = rng.uniform(0.001, 0.006)
            dyn['tau_fall'] = rng.uniform(0.020, 0.060)
        elif e == 'current_saturation':
            d['i_sat'] = rng.uniform(0.3, 0.7) * i_max
        elif e == 'hysteresis':
            d['x_h'] = rng.uniform(0.0005, 0.002)
        elif e == 'series_stiffness':
            d['k_series'] = float(np.exp(rng.uniform(np.log(3e5), np.log(2e6))))
        elif e == 'gas_spring':
            d['k_gas1'] = rng.uniform(3e3, 1.5e4)
            d['k_gas2'] = rng.uniform(1e5, 5e5) * rng.choice([-1, 1])
        elif e == 'thermal_fade':
            d['kappa'] = rng.uniform(0.1, 0.3)  # fade fraction, scaled to 1/J below
            d['tau_thermal'] = rng.uniform(100.0, 1000.0)
        elif e == 'direction_asymmetry':
            d['rho'] = rng.uniform(0.1, 0.3) * rng.choice([-1, 1])
        elif e == 'yield_shape':
            # Slow (arctan-like) tails: a sharper corner than tanh hides below the noise.
            d['yield_n'] = rng.uniform(0.8, 1.4)
    return d, dyn


def make_record(effects=(), seed=0, duration=30.0, rate=1000.0, noise=0.015, kind='full',
                truth=None):
    """Return ``(record, truth)``: a synthetic rig record and its truth model.

    ``truth`` is a dict ``{'damper': ExtendedDamperParams, 'current_dynamics': {...},
    'clean': noise-free force, 'noise_rms': N}``. The noise is AR(1) with a 5 ms correlation
    time and RMS ``noise`` times the force standard deviation.
    """
    rng = np.random.default_rng(seed)
    t, x, cur = doe_programme(duration, rate, seed=seed + 7919, kind=kind)
    dt = 1.0 / rate
    v = np.gradient(x, dt)
    if truth is None:
        d, dyn = random_truth(rng, effects)
        if 'kappa' in d:
            frac = d.pop('kappa')
            p0 = ExtendedDamperParams(**d).to_array()
            f0 = simulate_extended(p0, x, v, cur, dt)[0]
            energy = float(np.sum(np.abs(f0 * v)) * dt)
            d['kappa'] = frac / energy
        params = ExtendedDamperParams(**d)
    else:
        params, dyn = truth['damper'], truth['current_dynamics']
    i_f = field_current(cur, dt, dyn['dead_time'], dyn['tau_rise'], dyn['tau_fall'])
    clean = simulate_extended(params.to_array(), x, v, i_f, dt)[0]
    a = np.exp(-dt / 0.005)
    w = rng.standard_normal(t.size)
    e = np.empty_like(w)
    acc = 0.0
    for k in range(t.size):
        acc = a * acc + w[k]
        e[k] = acc
    e *= noise * np.std(clean) / np.std(e)
    rec = build_record(f'synthetic-{seed}', {'time': t, 'displacement': x, 'velocity': v,
                                             'force': clean + e, 'current_command': cur},
                       LoadOptions())
    return rec, {'damper': params, 'current_dynamics': dyn, 'clean': clean,
                 'noise_rms': float(np.std(e)), 'effects': tuple(effects)}
