"""Two-degree-of-freedom quarter car with tyre lift-off and end stops.

Seed 003, eqs. (4.3)-(4.4) and seed 001, eqs. (2)-(3), written about the static equilibrium:

    m_s z_s'' = S - m_s g,           S = P - k_s x - F_d - F_stop(x),   x = z_s - z_u
    m_u z_u'' = F_t - S - m_u g,     F_t = max(0, (m_s + m_u) g + k_t (z_r - z_u)
                                                 + c_t (z_r' - z_u'))

``P = m_s g + F_d0`` is the spring preload that balances gravity and the damper's static force
(accumulator), so the car rests at z = 0. The tyre cannot pull (lift-off) and the end stops are
stiff springs beyond the stroke limits.

Corner-level model options (all off by default; off, the step is the same arithmetic as
without them, bit for bit). The strut force becomes

    S = P - k_s x - k_s3 x^3 - F_d - F_fric - F_stop(x) - F_bs(x)
    F_fric = f_fric tanh(v / v_fric)                            (strut friction)
    F_bs = k_bs (|x| - x_bs)^2 sign(x)   for |x| > x_bs          (progressive bump/rebound stop)

and with a top mount (``k_tm > 0``) the strut acts between the wheel and the strut top, a node
of mass ``m_t = TOP_MOUNT_MASS_FRACTION m_s`` (taken from the sprung mass, so the static load is
unchanged) tied to the body by ``M = k_tm (z_t - z_s) + c_tm (v_t - v_s)``:

    (m_s - m_t) z_s'' = M,    m_t z_t'' = S - M - m_t g (about equilibrium),    x = z_t - z_u.

Every option's tangent enters the implicit step's Jacobian (3 x 3 with the top mount).
"""

from dataclasses import dataclass
import math

from numba import njit
import numpy as np

from mr_suspension.core.validation import check_declared, param, ParamsMixin

# Parameter array layout (QuarterCarParams.to_array): the base fields, the damper static force,
# then the corner-level model options.
(CAR_MS, CAR_MU, CAR_KS, CAR_KT, CAR_CT, CAR_XMAX, CAR_XMIN, CAR_KSTOP, CAR_G, CAR_FD0,
 CAR_FFRIC, CAR_VFRIC, CAR_XBS, CAR_KBS, CAR_KS3, CAR_KTM, CAR_CTM) = range(17)
N_CAR = 17
BASE_FIELDS = ('m_s', 'm_u', 'k_s', 'k_t', 'c_t', 'stroke_max', 'stroke_min', 'k_stop', 'g')
OPTION_FIELDS = ('f_fric', 'v_fric', 'x_bs', 'k_bs', 'k_s3', 'k_tm', 'c_tm')
# State layout: body and wheel displacement and velocity, then the strut top (top mount only).
ZS, ZU, VS, VU, ZT, VT = range(6)
N_STATE = 6
# Mass of the strut-top node (spring seat, bearing, mount inner part) as a fraction of m_s.
TOP_MOUNT_MASS_FRACTION = 0.01


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
    # Corner-level model options (off by default; a vehicle file may omit them).
    f_fric: float = param(0.0, 0.0, 5000.0, 'N', 'strut friction amplitude, '
                          'F = f_fric tanh(v / v_fric)', required=False)
    v_fric: float = param(0.005, 1.0e-4, 0.1, 'm/s', 'strut friction smoothing velocity',
                          required=False)
    x_bs: float = param(0.0, 0.0, 1.0, 'm', 'free travel before the progressive stop',
                        required=False)
    k_bs: float = param(0.0, 0.0, 1.0e10, 'N/m^2', 'progressive stop coefficient, '
                        'F = k_bs (|x| - x_bs)^2 sign(x) beyond x_bs (0 = off)', required=False)
    k_s3: float = param(0.0, 0.0, 1.0e10, 'N/m^3', 'cubic spring term, F = k_s x + k_s3 x^3',
                        required=False)
    k_tm: float = param(0.0, 1.0e3, 1.0e8, 'N/m', 'top-mount stiffness (0 = rigid)', off=0.0,
                        required=False)
    c_tm: float = param(0.0, 0.0, 1.0e5, 'N s/m', 'top-mount damping', required=False)

    def __post_init__(self):
        check_declared(self)
        if self.c_tm > 0.0 and self.k_tm == 0.0:
            raise ValueError('QuarterCarParams: c_tm > 0 needs a top mount (k_tm > 0); set '
                             'k_tm or c_tm = 0')

    @property
    def options_on(self):
        """Names of the corner-level model options that are on (empty: the 2-DOF corner)."""
        out = []
        if self.f_fric > 0.0:
            out.append('strut_friction')
        if self.k_bs > 0.0:
            out.append('bump_stop')
        if self.k_s3 != 0.0:
            out.append('spring_nonlinearity')
        if self.k_tm > 0.0:
            out.append('top_mount')
        return tuple(out)

    def to_array(self, f_d0=0.0):
        """Return the jitted plant's array (layout ``CAR_*``); ``f_d0``: damper static force."""
        return np.array([float(getattr(self, n)) for n in BASE_FIELDS] + [float(f_d0)]
                        + [float(getattr(self, n)) for n in OPTION_FIELDS], dtype=np.float64)

    def strut_force(self, x, v=0.0):
        """Strut force about equilibrium ``k_s x + k_s3 x^3 + F_stop + F_bs + F_fric`` [N]."""
        x = np.asarray(x, dtype=float)
        f = self.k_s * x + self.k_s3 * x ** 3
        f = f + self.k_stop * (np.maximum(x - self.stroke_max, 0.0)
                               + np.minimum(x - self.stroke_min, 0.0))
        f = f + self.k_bs * np.maximum(np.abs(x) - self.x_bs, 0.0) ** 2 * np.sign(x)
        return f + self.f_fric * np.tanh(np.asarray(v, dtype=float) / self.v_fric)

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
def strut_motion(p, q):
    """Strut stroke and rate ``(x, v)``: body (or strut top with a top mount) minus wheel."""
    if p[CAR_KTM] > 0.0:
        return q[ZT] - q[ZU], q[VT] - q[VU]
    return q[ZS] - q[ZU], q[VS] - q[VU]


@njit(cache=True)
def strut_extra(p, x, v):
    """Option forces and tangents ``(F, dF/dx, dF/dv)``: cubic spring, progressive stop, friction.

    ``F = k_s3 x^3 + k_bs (|x| - x_bs)^2 sign(x) [|x| > x_bs] + f_fric tanh(v / v_fric)``.
    """
    f = 0.0
    k = 0.0
    c = 0.0
    if p[CAR_KS3] != 0.0:
        f += p[CAR_KS3] * x * x * x
        k += 3.0 * p[CAR_KS3] * x * x
    if p[CAR_KBS] > 0.0:
        e = abs(x) - p[CAR_XBS]
        if e > 0.0:
            f += p[CAR_KBS] * e * e * (1.0 if x > 0.0 else -1.0)
            k += 2.0 * p[CAR_KBS] * e
    if p[CAR_FFRIC] > 0.0:
        th = math.tanh(v / p[CAR_VFRIC])
        f += p[CAR_FFRIC] * th
        c += p[CAR_FFRIC] / p[CAR_VFRIC] * (1.0 - th * th)
    return f, k, c


@njit(cache=True)
def end_stop(p, x):
    """Linear end stops: ``(F_stop, k_stop or 0)``, ``F = k_stop (x - x_max)`` beyond rebound."""
    if x > p[CAR_XMAX]:
        return p[CAR_KSTOP] * (x - p[CAR_XMAX]), p[CAR_KSTOP]
    if x < p[CAR_XMIN]:
        return p[CAR_KSTOP] * (x - p[CAR_XMIN]), p[CAR_KSTOP]
    return 0.0, 0.0


@njit(cache=True)
def tyre(p, q, z_r, zr_dot):
    """Tyre force ``(F_t,lin, F_t, k_t, c_t)``; the tyre cannot pull (0 and no stiffness then).

    ``F_t,lin = (m_s + m_u) g + k_t (z_r - z_u) + c_t (z_r' - z_u')`` (seed 003 eq. 4.4).
    """
    f_t_lin = ((p[CAR_MS] + p[CAR_MU]) * p[CAR_G] + p[CAR_KT] * (z_r - q[ZU])
               + p[CAR_CT] * (zr_dot - q[VU]))
    if f_t_lin > 0.0:
        return f_t_lin, f_t_lin, p[CAR_KT], p[CAR_CT]
    return f_t_lin, 0.0, 0.0, 0.0


@njit(cache=True)
def tyre_mid(f_t_lin, kt, ct, v_u, dv_u, h):
    """Tyre force at mid-step, consistent with the trapezoidal update, clamped at lift-off."""
    if kt > 0.0:
        return max(f_t_lin - kt * h * (0.5 * v_u + 0.25 * dv_u) - 0.5 * ct * dv_u, 0.0)
    return 0.0


@njit(cache=True)
def plant_step(p, q, f_d, c_d, z_r, zr_dot, dt):
    """Advance the corner one step; returns (body acc, wheel acc, tyre force) over the step.

    Linearly implicit trapezoidal rule: with ``J_z, J_v`` the Jacobians of the accelerations,
    ``(I - dt/2 J_v - dt^2/4 J_z) dv = dt (a_n + dt/2 J_z v_n)`` and
    ``z_{n+1} = z_n + dt/2 (v_n + v_{n+1})``. The damper enters as ``F_d + c_d (v - v_n)``
    with its tangent ``c_d``, which keeps the stiff pre-yield region of MR laws stable.
    ``z_r, zr_dot`` are the road at mid-step. The model options add their forces and tangents
    (:func:`strut_extra`); a top mount (``k_tm > 0``, state of :data:`N_STATE` entries) takes
    :func:`plant_step_mount`.
    """
    if p[CAR_KTM] > 0.0:
        return plant_step_mount(p, q, f_d, c_d, z_r, zr_dot, dt)
    ms = p[CAR_MS]
    mu = p[CAR_MU]
    x = q[ZS] - q[ZU]
    f_stop, k_x = end_stop(p, x)
    k_x += p[CAR_KS]
    c = c_d
    if p[CAR_KS3] != 0.0 or p[CAR_KBS] > 0.0 or p[CAR_FFRIC] > 0.0:
        f_x, k_e, c_e = strut_extra(p, x, q[VS] - q[VU])
        f_stop += f_x
        k_x += k_e
        c += c_e
    s_force = ms * p[CAR_G] + p[CAR_FD0] - p[CAR_KS] * x - f_d - f_stop
    f_t_lin, f_t, kt, ct = tyre(p, q, z_r, zr_dot)
    a_s = (s_force - ms * p[CAR_G]) / ms
    a_u = (f_t - s_force - mu * p[CAR_G]) / mu
    # Jacobians of (a_s, a_u) w.r.t. (z_s, z_u) and (v_s, v_u).
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
    f_t_mid = tyre_mid(f_t_lin, kt, ct, q[VU], dv_u, h)
    q[ZS] += h * (q[VS] + 0.5 * dv_s)
    q[ZU] += h * (q[VU] + 0.5 * dv_u)
    q[VS] += dv_s
    q[VU] += dv_u
    return dv_s / h, dv_u / h, f_t_mid


@njit(cache=True)
def _solve3(a, r):
    """Solve the 3 x 3 system ``a y = r`` (Gaussian elimination, partial pivoting)."""
    m = a.copy()
    y = r.copy()
    for i in range(3):
        piv = i
        for j in range(i + 1, 3):
            if abs(m[j, i]) > abs(m[piv, i]):
                piv = j
        if piv != i:
            for k in range(3):
                m[i, k], m[piv, k] = m[piv, k], m[i, k]
            y[i], y[piv] = y[piv], y[i]
        for j in range(i + 1, 3):
            f = m[j, i] / m[i, i]
            for k in range(i, 3):
                m[j, k] -= f * m[i, k]
            y[j] -= f * y[i]
    for i in range(2, -1, -1):
        acc = y[i]
        for k in range(i + 1, 3):
            acc -= m[i, k] * y[k]
        y[i] = acc / m[i, i]
    return y


@njit(cache=True)
def plant_step_mount(p, q, f_d, c_d, z_r, zr_dot, dt):
    """Step of the corner with a top mount: body, strut top and wheel, 3 x 3 implicit step.

    ``(m_s - m_t) a_s = M``, ``m_t a_t = S - M - m_t g``, ``m_u a_u = F_t - S - m_u g`` about
    equilibrium with ``M = m_b g + k_tm (z_t - z_s) + c_tm (v_t - v_s)``, ``S`` the strut force
    at ``x = z_t - z_u`` and ``m_t = TOP_MOUNT_MASS_FRACTION m_s``; same linearly implicit
    trapezoidal rule as :func:`plant_step` on ``(z_s, z_t, z_u)``. ``q`` needs
    :data:`N_STATE` entries.
    """
    if q.shape[0] < N_STATE:
        raise ValueError('plant_step: a top mount needs the 6-entry state (N_STATE)')
    ms = p[CAR_MS]
    mu = p[CAR_MU]
    g = p[CAR_G]
    mt = TOP_MOUNT_MASS_FRACTION * ms
    mb = ms - mt
    ktm = p[CAR_KTM]
    ctm = p[CAR_CTM]
    x = q[ZT] - q[ZU]
    v = q[VT] - q[VU]
    f_stop, k_x = end_stop(p, x)
    k_x += p[CAR_KS]
    f_x, k_e, c_e = strut_extra(p, x, v)
    k_x += k_e
    c = c_d + c_e
    s_force = ms * g + p[CAR_FD0] - p[CAR_KS] * x - f_d - f_stop - f_x
    m_dyn = ktm * (q[ZT] - q[ZS]) + ctm * (q[VT] - q[VS])
    f_t_lin, f_t, kt, ct = tyre(p, q, z_r, zr_dot)
    a = np.empty(3)
    a[0] = m_dyn / mb
    a[1] = (s_force - mb * g - m_dyn - mt * g) / mt
    a[2] = (f_t - s_force - mu * g) / mu
    # Jacobians w.r.t. (z_s, z_t, z_u) and (v_s, v_t, v_u).
    jz = np.zeros((3, 3))
    jv = np.zeros((3, 3))
    jz[0, 0] = -ktm / mb
    jz[0, 1] = ktm / mb
    jz[1, 0] = ktm / mt
    jz[1, 1] = -(k_x + ktm) / mt
    jz[1, 2] = k_x / mt
    jz[2, 1] = k_x / mu
    jz[2, 2] = -(k_x + kt) / mu
    jv[0, 0] = -ctm / mb
    jv[0, 1] = ctm / mb
    jv[1, 0] = ctm / mt
    jv[1, 1] = -(c + ctm) / mt
    jv[1, 2] = c / mt
    jv[2, 1] = c / mu
    jv[2, 2] = -(c + ct) / mu
    h = dt
    vel = np.array([q[VS], q[VT], q[VU]])
    lhs = np.eye(3) - 0.5 * h * jv - 0.25 * h * h * jz
    rhs = h * (a + 0.5 * h * (jz @ vel))
    dv = _solve3(lhs, rhs)
    f_t_mid = tyre_mid(f_t_lin, kt, ct, q[VU], dv[2], h)
    q[ZS] += h * (q[VS] + 0.5 * dv[0])
    q[ZT] += h * (q[VT] + 0.5 * dv[1])
    q[ZU] += h * (q[VU] + 0.5 * dv[2])
    q[VS] += dv[0]
    q[VT] += dv[1]
    q[VU] += dv[2]
    return dv[0] / h, dv[2] / h, f_t_mid
