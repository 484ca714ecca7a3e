"""Velocity estimation from a car's sensors (body and wheel accelerometers, stroke sensor).

Body velocity (drift-bounded integration of the body acceleration, gravity already removed)::

    v_s[k] = lam v_s[k-1] + dt a_s[k],     lam = exp(-2 pi f_hp dt)

i.e. ``V_s(s) = A_s(s) / (s + w_hp)``: an integrator whose low-frequency gain is bounded, so an
accelerometer bias ``b`` gives a bounded velocity error ``b / w_hp`` instead of a ramp (the
usual leaky integrator of skyhook implementations, e.g. Savaresi et al., *Semi-Active
Suspension Control Design for Vehicles*, 2010, ch. 6). Phase lead ``atan(f_hp / f)``.

Stroke rate (complementary filter of the differentiated stroke and the integrated relative
acceleration ``a_s - a_u``)::

    v[k] = v[k-1] + dt (a_s[k] - a_u[k]) + L ((x[k] - x[k-1]) / dt - v[k-1] - dt (a_s - a_u)),
    L = 1 - exp(-2 pi f_cr dt)

Low frequencies come from the stroke sensor, high frequencies from the accelerometers, so the
estimate has no filter lag; without a wheel accelerometer (``a_u`` NaN) it degrades to the
filtered derivative ``V = s X w_lp / (s + w_lp)`` with ``f_lp`` (group delay ``1 / w_lp``).
Wheel velocity ``v_u = v_s - v``. Tyre deflection from Newton's law on both masses,
``k_t (z_u - z_r) ~ -(m_s a_s + m_u a_u)`` (tyre damping neglected).

State slots live in the controller state vector (``E_*`` below).
"""

import math

from numba import njit

E_VS, E_V, E_XPREV, E_INIT = 0, 1, 2, 3


@njit(cache=True)
def estimate_step(s, a_s, a_u, x, dt, f_hp, f_cr, f_lp):
    """Advance the estimator one sample; returns ``(v_s, v)`` estimates (see module doc)."""
    if not (a_s == a_s):
        a_s = 0.0
    if s[E_INIT] == 0.0:
        s[E_INIT] = 1.0
        s[E_XPREV] = x if x == x else 0.0
        s[E_VS] = 0.0
        s[E_V] = 0.0
    lam = math.exp(-2.0 * math.pi * f_hp * dt)
    s[E_VS] = lam * s[E_VS] + dt * a_s
    if x == x:
        dx = (x - s[E_XPREV]) / dt
        s[E_XPREV] = x
        if a_u == a_u:
            pred = s[E_V] + dt * (a_s - a_u)
            gain = 1.0 - math.exp(-2.0 * math.pi * f_cr * dt)
            s[E_V] = pred + gain * (dx - pred)
        else:
            gain = 1.0 - math.exp(-2.0 * math.pi * f_lp * dt)
            s[E_V] = s[E_V] + gain * (dx - s[E_V])
    return s[E_VS], s[E_V]
