"""Inverse damper model: the current that makes a force law produce a desired force.

For every law of :mod:`mr_suspension.core.damper` (``linear``, ``bingham``, ``tanh``,
``tanh_maxvel``, ``mechanical``, ``bouc_wen``, ``extended``) at the measured motion ``(x, v)``
and the law's present internal state, the force ``F(i)`` is monotone in the current ``i``
(non-decreasing for ``v > 0``, non-increasing for ``v < 0``: more field, more dissipation).
The inverse solves ``F(i) - F_static = F_des`` on ``[i_min, i_max]`` by the Illinois variant of
regula falsi (Dowell & Jarratt 1971) on the bracket ``[i_min, i_max]``:

    i_{n+1} = i_a - g_a (i_b - i_a) / (g_b - g_a),   g(i) = F(i) - F_static - F_des.

For the laws that are affine in the current at a fixed state (Bingham ``F = F0 + (c0 + c1 i) v
+ (fc0 + fc1 i) tanh(v / v_y)``, seed 003 eq. 5.2; tanh ``F = y_MR I tanh(c_MR v + k_MR x)
+ c_p v + k_p x`` and the max-velocity law, seed 002; the extended law without yield
saturation and series stiffness) the first step is the exact closed form. Stateful laws
(series stiffness, Bouc-Wen, Dahl, thermal fade) are evaluated on a scratch copy of the law's
present state, i.e. on the force that the next step would produce. ``F_static`` is the force at
rest (accumulator preload), which the plant's spring preload balances, so ``F_des`` is the
dynamic force asked by a control law. If ``F_des`` lies outside ``[F(i_min), F(i_max)]`` the
nearer end of the current range is returned (saturation), so the result is always in range.

Passivity (a semi-active damper only dissipates, ``F v > 0``) is handled by
:func:`semi_active_current`: a desired force that would inject power (``F_des v <= 0``) is
replaced by the least dissipative setting ``i_min`` (clipping, Karnopp 1974; Dyke et al. 1996).
"""

import math

from numba import njit
import numpy as np

from mr_suspension.core import damper as dmp

INV_ITER = 24
INV_TOL = 1e-7


@njit(cache=True)
def maxvel_force_at(p, peak, x, v, i):
    """Return the max-velocity law's force (seed 002) for a given window peak ``|v|``.

    ``F = c_MR i v / (peak + eps) + c_p v + k_p x``.
    """
    if peak < abs(v):
        peak = abs(v)
    return p[0] * i * v / (peak + p[1]) + p[2] * v + p[3] * x


@njit(cache=True)
def force_at(law, p, s, tmp, x, v, i, dt):
    """Force the law would give at ``(x, v, i)`` from state ``s`` (``s`` is left untouched).

    ``tmp`` is scratch space at least as long as the law's state. For ``tanh_maxvel`` the
    state is the window peak ``|v|`` in ``s[0]`` (the ring buffer is not needed by the inverse).
    """
    if law == dmp.LAW_LINEAR:
        return p[0] * v + p[1]
    if law == dmp.LAW_BINGHAM:
        return dmp.bingham_force(p, v, i)[0]
    if law == dmp.LAW_TANH:
        return dmp.tanh_force(p, x, v, i)[0]
    if law == dmp.LAW_TANH_MAXVEL:
        return maxvel_force_at(p, s[0], x, v, i)
    n = tmp.shape[0] if tmp.shape[0] < s.shape[0] else s.shape[0]
    for k in range(n):
        tmp[k] = s[k]
    return dmp.damper_force(law, p, tmp, x, v, i, dt)[0]


@njit(cache=True)
def inverse_current(law, p, s, tmp, x, v, f_des, f_static, i_min, i_max, dt):
    """Return the current in ``[i_min, i_max]`` whose ``F(i) - f_static`` is nearest ``f_des``.

    Illinois regula falsi on the monotone ``g(i) = F(i) - f_static - f_des`` (module doc).
    Returns ``i_min`` for a non-finite request.
    """
    if not (f_des == f_des and x == x and v == v):
        return i_min
    g_a = force_at(law, p, s, tmp, x, v, i_min, dt) - f_static - f_des
    if i_max <= i_min:
        return i_min
    g_b = force_at(law, p, s, tmp, x, v, i_max, dt) - f_static - f_des
    a = i_min
    b = i_max
    if g_a == 0.0:
        return a
    if g_b == 0.0:
        return b
    if (g_a > 0.0) == (g_b > 0.0):
        # Not bracketed: the request is beyond what the damper can do; nearer end.
        return a if abs(g_a) <= abs(g_b) else b
    side = 0
    c = a
    for _ in range(INV_ITER):
        c = a - g_a * (b - a) / (g_b - g_a)
        if not (a <= c <= b) or not c == c:
            c = 0.5 * (a + b)
        g_c = force_at(law, p, s, tmp, x, v, c, dt) - f_static - f_des
        if abs(g_c) <= 1e-9 * (1.0 + abs(f_des)) or (b - a) <= INV_TOL:
            return c
        if (g_c > 0.0) == (g_b > 0.0):
            b = c
            g_b = g_c
            if side == -1:
                g_a *= 0.5
            side = -1
        else:
            a = c
            g_a = g_c
            if side == 1:
                g_b *= 0.5
            side = 1
    return c


@njit(cache=True)
def semi_active_current(law, p, s, tmp, x, v, f_des, f_static, i_min, i_max, dt):
    """Passivity-clipped inverse: ``i_min`` when ``F_des v <= 0`` (power would be injected).

    Otherwise :func:`inverse_current`; saturates at ``i_max`` when more force is asked than
    the damper gives, at ``i_min`` when less than its zero-field force.
    """
    if not (f_des * v > 0.0):
        return i_min
    return inverse_current(law, p, s, tmp, x, v, f_des, f_static, i_min, i_max, dt)


def damper_model_array(params):
    """Return ``(law_id, p, n_state)`` of a damper parameter object for the inverse."""
    return dmp.law_id_of(params), params.to_array(), dmp.n_state_of(params)


def static_force(params, dt=1e-3):
    """Force of the law at rest (``x = v = 0``, zero current) from a zero state."""
    s = np.zeros(max(64, dmp.n_state_of(params) + 8))
    return float(dmp.damper_force(dmp.law_id_of(params), params.to_array(), s, 0.0, 0.0, 0.0,
                                  dt)[0])


def inverse(params, x, v, f_des, i_min=0.0, i_max=2.0, state=None, dt=1e-3, passive=True):
    """Python front end: current for the desired dynamic force ``f_des`` [N].

    ``params`` is a damper parameter object (any law, including ``extended``), ``x, v`` the
    stroke [m] and stroke rate [m/s], ``state`` the law's state (zeros by default; for
    ``tanh_maxvel`` a one-element array holding the window peak ``|v|``). With ``passive``
    the passivity constraint is applied (``i_min`` when ``f_des v <= 0``).
    """
    for name, value in (('x', x), ('v', v), ('f_des', f_des), ('i_min', i_min),
                        ('i_max', i_max), ('dt', dt)):
        if not math.isfinite(float(value)):
            raise ValueError(f'inverse: {name} must be finite, got {value!r}')
    if i_min < 0.0 or i_max < i_min:
        raise ValueError('inverse: need 0 <= i_min <= i_max')
    law, p, n = damper_model_array(params)
    s = np.zeros(max(n, 1)) if state is None else np.array(state, dtype=np.float64)
    tmp = np.zeros(max(n, 1) + 8)
    f0 = static_force(params, dt)
    fn = semi_active_current if passive else inverse_current
    return float(fn(law, p, s, tmp, float(x), float(v), float(f_des), f0, float(i_min),
                    float(i_max), float(dt)))
