"""Frequency-estimation-based controller (FEBC), seed 002 (Lozoya-Santos et al. 2010).

Seed 002 describes FEBC only as a model-free, one-sensor controller that estimates the
frequency of the motion and commands a current (not a force) for both comfort and road
holding; it gives no equation. This is our reconstruction from that description:

1. the stroke (the one sensor) is high-passed by subtracting a slow mean,
   ``m[k] = m[k-1] + (dt / tau_m) (x[k] - m[k-1])``, ``tau_m = 1 s``;
2. the dominant frequency is estimated from zero crossings of ``x - m`` (hysteresis
   ``x_band``): each half period ``T/2`` between crossings gives ``f = 1 / (2 (T/2))``,
   smoothed by ``f_est += (1 - exp(-T/2 / tau)) (f - f_est)``; with no crossing for longer
   than the last half period the estimate decays as ``f <= 1 / (2 t_since)``;
3. the current is scheduled by band: ``i_body`` below ``f1`` (body mode: damp it),
   ``i_min`` between ``f1`` and ``f2`` (the comfort band between body mode and wheel hop,
   where damping transmits road input), ``i_road`` above ``f2`` (wheel hop: road holding).
"""

import math

from numba import njit

F_MEAN, F_SIGN, F_TCROSS, F_FEST = 0, 1, 2, 3
FEBC_TAU_MEAN = 1.0


@njit(cache=True)
def febc_step(s, x, dt, f1, f2, i_low, i_mid, i_high, tau, x_band):
    """Advance the frequency estimator on stroke ``x`` and return the scheduled current."""
    if x == x:
        s[F_MEAN] += dt / FEBC_TAU_MEAN * (x - s[F_MEAN])
        y = x - s[F_MEAN]
        s[F_TCROSS] += dt
        sign = s[F_SIGN]
        new = sign
        if y > x_band:
            new = 1.0
        elif y < -x_band:
            new = -1.0
        if new != sign:
            if sign != 0.0:
                half = s[F_TCROSS]
                f = 0.5 / half
                if s[F_FEST] <= 0.0:
                    s[F_FEST] = f
                else:
                    s[F_FEST] += (1.0 - math.exp(-half / tau)) * (f - s[F_FEST])
            s[F_TCROSS] = 0.0
            s[F_SIGN] = new
    f_est = s[F_FEST]
    if s[F_TCROSS] > 0.0:
        f_cap = 0.5 / s[F_TCROSS]
        if f_est > f_cap:
            f_est = f_cap
    if f_est < f1:
        return i_low
    if f_est < f2:
        return i_mid
    return i_high
