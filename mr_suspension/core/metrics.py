"""Ride and handling metrics: RMS, ISO 2631-1 Wk weighting and VDV, working space, tyre load.

The Wk weighting is the product of the ISO 2631-1:1997 Annex A filters: band limiting
(0.4 Hz high-pass, 100 Hz low-pass, Q = 1/sqrt 2), acceleration-velocity transition
(f3 = f4 = 12.5 Hz, Q4 = 0.63) and upward step (f5 = 2.37 Hz, Q5 = 0.91, f6 = 3.35 Hz, Q6 = 0.91).
"""

import math

from numba import njit
import numpy as np
from scipy import signal

WK_F1, WK_F2, WK_F3, WK_F4, WK_Q4 = 0.4, 100.0, 12.5, 12.5, 0.63
WK_F5, WK_Q5, WK_F6, WK_Q6 = 2.37, 0.91, 3.35, 0.91


def wk_analog():
    """Return the analogue Wk weighting as (numerator, denominator) polynomials in s."""
    w1, w2, w3, w4 = (2 * math.pi * f for f in (WK_F1, WK_F2, WK_F3, WK_F4))
    w5, w6 = 2 * math.pi * WK_F5, 2 * math.pi * WK_F6
    q1 = 1.0 / math.sqrt(2.0)
    num = np.polymul([1.0, 0.0, 0.0], [w2 ** 2])                      # high-pass x low-pass
    den = np.polymul([1.0, w1 / q1, w1 ** 2], [1.0, w2 / q1, w2 ** 2])
    num = np.polymul(num, np.array([1.0 / w3, 1.0]))                   # a-v transition
    den = np.polymul(den, [1.0 / w4 ** 2, 1.0 / (WK_Q4 * w4), 1.0])
    num = np.polymul(num, [1.0, w5 / WK_Q5, w5 ** 2])                 # upward step
    den = np.polymul(den, [1.0, w6 / WK_Q6, w6 ** 2])
    return num, den


def wk_gain(freq):
    """Magnitude of the analogue Wk weighting at ``freq`` [Hz]."""
    num, den = wk_analog()
    _, h = signal.freqs(num, den, worN=2 * np.pi * np.asarray(freq, dtype=float))
    return np.abs(h)


def wk_sos(dt):
    """Second-order sections of the Wk weighting discretised by the bilinear transform."""
    num, den = wk_analog()
    z, p, k = signal.tf2zpk(num, den)
    zd, pd, kd = signal.bilinear_zpk(z, p, k, 1.0 / dt)
    return signal.zpk2sos(zd, pd, kd)


@njit(cache=True)
def sos_step(sos, zi, x):
    """Filter one sample through second-order sections (direct form II transposed).

    ``zi`` (sections x 2) is updated in place; the same recursion as ``scipy.signal.sosfilt``,
    for use inside jitted time loops.
    """
    y = x
    for j in range(sos.shape[0]):
        x0 = y
        y = sos[j, 0] * x0 + zi[j, 0]
        zi[j, 0] = sos[j, 1] * x0 - sos[j, 4] * y + zi[j, 1]
        zi[j, 1] = sos[j, 2] * x0 - sos[j, 5] * y
    return y


def wk_filter(acc, dt):
    """Wk-weighted acceleration (causal filter, as a seat accelerometer's weighting would be)."""
    return signal.sosfilt(wk_sos(dt), np.asarray(acc, dtype=float))


def rms(x):
    """Root mean square."""
    x = np.asarray(x, dtype=float)
    return float(np.sqrt(np.mean(x * x))) if x.size else float('nan')


def vdv(acc_w, dt):
    """Vibration dose value ``(integral a_w^4 dt)^(1/4)`` [m/s^1.75] (ISO 2631-1, 6.3.2)."""
    return float(np.sum(np.asarray(acc_w, dtype=float) ** 4) * dt) ** 0.25


def settling_time(t, y, band=0.02, t_start=0.0, floor=1e-3):
    """Time from ``t_start`` after which ``y`` stays within ``band`` of its final value.

    The band is ``band`` times the largest deviation from the final value, but at least
    ``floor`` (in the units of ``y``). Returns ``inf`` if it never settles.
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    sel = t >= t_start
    t, y = t[sel], y[sel]
    if y.size < 2:
        return float('nan')
    final = np.mean(y[-max(1, y.size // 20):])
    dev = np.abs(y - final)
    tol = max(band * dev.max(), floor)
    outside = np.nonzero(dev > tol)[0]
    if outside.size == 0:
        return 0.0
    if outside[-1] >= y.size - 1:
        return float('inf')
    return float(t[outside[-1] + 1] - t_start)


def ride_metrics(result, t_event=0.0):
    """Compute the standard metrics of a simulation result (SI units).

    Body acceleration RMS/peak [m/s^2], Wk-weighted RMS [m/s^2] and VDV [m/s^1.75], working
    space RMS/peak [m], dynamic tyre load RMS ``rms(F_t - F_t0)`` [N], normalised dynamic tyre
    load RMS ``ntf_rms = rms(F_t - F_t0) / F_t0`` [-], normalised minimum tyre force
    ``ntf_min = min F_t / F_t0`` [-] (1 at rest, 0 at lift-off; F_t0 = (m_s + m_u) g), the
    minimum tyre force ``tyre_force_min`` [N], lift-off fraction, the peak sprung-unsprung
    displacement difference (seed 003 Tables 3-5), the body settling time after ``t_event``
    [s] and the energy the damper dissipated [J]. The same names and units as
    :func:`mr_suspension.sim.corner.batch_metrics`.
    """
    dt = result.dt
    acc = result.a_s
    acc_w = wk_filter(acc, dt)
    f_t0 = result.static_tyre_load
    dyn = result.f_t - f_t0
    stroke = result.stroke
    return {
        'body_acc_rms': rms(acc),
        'body_acc_peak': float(np.max(np.abs(acc))),
        'body_acc_wk_rms': rms(acc_w),
        'vdv': vdv(acc_w, dt),
        'working_space_rms': rms(stroke),
        'working_space_peak': float(np.max(np.abs(stroke))),
        'tyre_load_rms': rms(dyn),
        'ntf_rms': rms(dyn / f_t0),
        'ntf_min': float(np.min(result.f_t / f_t0)),
        'tyre_force_min': float(np.min(result.f_t)),
        'lift_off_fraction': float(np.mean(result.f_t <= 0.0)),
        'displacement_difference_peak': float(np.max(np.abs(stroke))),
        'settling_time': settling_time(result.t, result.z_s, t_start=t_event),
        'damper_energy': float(np.sum(result.f_d * result.stroke_rate) * dt),
    }


def sine_gain(t, y, freq, n_periods=None):
    """Amplitude of the ``freq`` component of ``y`` by least squares over whole periods."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    period = 1.0 / freq
    if n_periods is not None:
        sel = t >= t[-1] - n_periods * period
        t, y = t[sel], y[sel]
    w = 2 * np.pi * freq
    a = np.column_stack([np.sin(w * t), np.cos(w * t), np.ones_like(t)])
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    return float(np.hypot(coef[0], coef[1]))
