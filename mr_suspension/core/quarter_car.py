"""Two-degree-of-freedom quarter car with tyre lift-off and end stops.

Seed 003, eqs. (4.3)-(4.4) and seed 001, eqs. (2)-(3), written about the static equilibrium:

    m_s z_s'' = S - m_s g,           S = P - k_s x - F_d - F_stop(x),   x = z_s - z_u
    m_u z_u'' = F_t - S - m_u g,     F_t = max(0, (m_s + m_u) g + k_t (z_r - z_u)
                                                 + c_t (z_r' - z_u'))

``P = m_s g + F_d0`` is the spring preload that balances gravity and the damper's static force
(accumulator), so the car rests at z = 0. The tyre cannot pull (lift-off) and the end stops are
stiff springs beyond the stroke limits.
"""

from dataclasses import dataclass

from numba import njit
import numpy as np

from mr_suspension.core.validation import check_declared, param, ParamsMixin

# Parameter array layout (QuarterCarParams.to_array + the damper static force).
CAR_MS, CAR_MU, CAR_KS, CAR_KT, CAR_CT, CAR_XMAX, CAR_XMIN, CAR_KSTOP, CAR_G, CAR_FD0 = range(10)
# State layout: body and wheel displacement and velocity.
ZS, ZU, VS, VU = range(4)


@dataclass(frozen=True)
class QuarterCarParams(ParamsMixin):
    """Quarter-car parameters (SI). ``stroke_max``/``stroke_min``: rebound/bump stop positions."""

    m_s: float = param(241.5, 20.0, 5000.0, 'kg', 'sprung mass per corner')
    m_u: float = param(41.5, 2.0, 1000.0, 'kg', 'unsprung mass per corner')
    k_s: float = param(6000.0, 500.0, 2.0e6, 'N/m', 'suspension spring stiffness')
    k_t: float = param(14000.0, 5.0e3, 1.0e8, 'N/m', 'tyre stiffness')
    c_t: float = param(1500.0, 0.0, 1.0e5, 'N s/m', 'tyre damping')
    stroke_max: float = param(0.10, 1.0e-3, 1.0, 'm', 'rebound stop position')
    stroke_min: float = param(-0.10, -1.0, -1.0e-3, 'm', 'bump stop position, negative')
    k_stop: float = param(2.0e5, 0.0, 1.0e9, 'N/m', 'end-stop stiffness')
    g: float = param(9.81, 0.1, 100.0, 'm/s^2', 'gravitational acceleration')

    def __post_init__(self):
        check_declared(self)

    def to_array(self, f_d0=0.0):
        """Return the jitted plant's parameter array; ``f_d0`` is the damper's static force."""
        return np.append(ParamsMixin.to_array(self), float(f_d0))

    @property
    def static_tyre_load(self):
        """Static wheel load ``(m_s + m_u) g`` [N]."""
        return (self.m_s + self.m_u) * self.g

    def natural_frequencies(self):
        """Undamped natural frequencies [Hz] (body, wheel hop) from ``det(K - w^2 M) = 0``."""
        m = np.diag([self.m_s, self.m_u])
        k = np.array([[self.k_s, -self.k_s], [-self.k_s, self.k_s + self.k_t]])
        w2 = np.sort(np.linalg.eigvals(np.linalg.solve(m, k)).real)
        return np.sqrt(w2) / (2.0 * np.pi)

    def transfer(self, freq, c):
        """Linear frequency responses per unit road displacement with viscous damping ``c``.

        Returns a dict of complex arrays: ``z_s``, ``z_u``, ``acc`` (body acceleration),
        ``stroke`` (working space), ``tyre`` (dynamic tyre force) and ``ntf`` (tyre force over
        the static load), from ``[[m_s s^2 + c s + k_s, -(c s + k_s)], [-(c s + k_s),
        m_u s^2 + (c + c_t) s + k_s + k_t]] [Z_s, Z_u] = [0, (c_t s + k_t) Z_r]``.
        """
        s = 2j * np.pi * np.asarray(freq, dtype=float)
        a11 = self.m_s * s ** 2 + c * s + self.k_s
        a12 = -(c * s + self.k_s)
        a22 = self.m_u * s ** 2 + (c + self.c_t) * s + self.k_s + self.k_t
        rhs = self.c_t * s + self.k_t
        det = a11 * a22 - a12 * a12
        z_s = -a12 * rhs / det
        z_u = a11 * rhs / det
        tyre = rhs * (1.0 - z_u)
        return {'z_s': z_s, 'z_u': z_u, 'acc': s ** 2 * z_s, 'stroke': z_s - z_u,
                'tyre': tyre, 'ntf': tyre / self.static_tyre_load}


@njit(cache=True)
def tyre_force(p, q, z_r, zr_dot):
    """Tyre normal force ``max(0, F_t0 + k_t (z_r - z_u) + c_t (z_r' - z_u'))`` [N]."""
    f = (p[CAR_MS] + p[CAR_MU]) * p[CAR_G] + p[CAR_KT] * (z_r - q[ZU]) \
        + p[CAR_CT] * (zr_dot - q[VU])
    return f if f > 0.0 else 0.0


@njit(cache=True)
def plant_step(p, q, f_d, c_d, z_r, zr_dot, dt):
    """Advance the corner one step; returns (body acc, wheel acc, tyre force) over the step.

    Linearly implicit trapezoidal rule: with ``J_z, J_v`` the Jacobians of the accelerations,
    ``(I - dt/2 J_v - dt^2/4 J_z) dv = dt (a_n + dt/2 J_z v_n)`` and
    ``z_{n+1} = z_n + dt/2 (v_n + v_{n+1})``. The damper enters as ``F_d + c_d (v - v_n)``
    with its tangent ``c_d``, which keeps the stiff pre-yield region of MR laws stable.
    ``z_r, zr_dot`` are the road at mid-step.
    """
    ms = p[CAR_MS]
    mu = p[CAR_MU]
    x = q[ZS] - q[ZU]
    k_x = p[CAR_KS]
    f_stop = 0.0
    if x > p[CAR_XMAX]:
        f_stop = p[CAR_KSTOP] * (x - p[CAR_XMAX])
        k_x += p[CAR_KSTOP]
    elif x < p[CAR_XMIN]:
        f_stop = p[CAR_KSTOP] * (x - p[CAR_XMIN])
        k_x += p[CAR_KSTOP]
    s_force = ms * p[CAR_G] + p[CAR_FD0] - p[CAR_KS] * x - f_d - f_stop
    f_t_lin = (ms + mu) * p[CAR_G] + p[CAR_KT] * (z_r - q[ZU]) + p[CAR_CT] * (zr_dot - q[VU])
    kt = 0.0
    ct = 0.0
    f_t = 0.0
    if f_t_lin > 0.0:
        f_t = f_t_lin
        kt = p[CAR_KT]
        ct = p[CAR_CT]
    a_s = (s_force - ms * p[CAR_G]) / ms
    a_u = (f_t - s_force - mu * p[CAR_G]) / mu
    # Jacobians of (a_s, a_u) w.r.t. (z_s, z_u) and (v_s, v_u).
    c = c_d
    jz11 = -k_x / ms
    jz12 = k_x / ms
    jz21 = k_x / mu
    jz22 = -(k_x + kt) / mu
    jv11 = -c / ms
    jv12 = c / ms
    jv21 = c / mu
    jv22 = -(c + ct) / mu
    h = dt
    a11 = 1.0 - 0.5 * h * jv11 - 0.25 * h * h * jz11
    a12 = -0.5 * h * jv12 - 0.25 * h * h * jz12
    a21 = -0.5 * h * jv21 - 0.25 * h * h * jz21
    a22 = 1.0 - 0.5 * h * jv22 - 0.25 * h * h * jz22
    r1 = h * (a_s + 0.5 * h * (jz11 * q[VS] + jz12 * q[VU]))
    r2 = h * (a_u + 0.5 * h * (jz21 * q[VS] + jz22 * q[VU]))
    det = a11 * a22 - a12 * a21
    dv_s = (r1 * a22 - a12 * r2) / det
    dv_u = (a11 * r2 - a21 * r1) / det
    # Tyre force at mid-step (consistent with the trapezoidal update), clamped at lift-off.
    f_t_mid = 0.0
    if kt > 0.0:
        f_t_mid = f_t_lin - kt * h * (0.5 * q[VU] + 0.25 * dv_u) - 0.5 * ct * dv_u
        if f_t_mid < 0.0:
            f_t_mid = 0.0
    q[ZS] += h * (q[VS] + 0.5 * dv_s)
    q[ZU] += h * (q[VU] + 0.5 * dv_u)
    q[VS] += dv_s
    q[VU] += dv_u
    return dv_s / h, dv_u / h, f_t_mid
