"""MR damper force laws: parameters, numba step functions, inverse maps and the work diagram.

Sign convention (all laws): stroke ``x = z_s - z_u`` (+ = extension/rebound), stroke rate
``v = dx/dt``, field current ``i`` [A] (after driver and fluid dynamics). The damper force ``F``
is positive when it resists extension, so the dissipated power is ``F * v``.

Every law has the same jitted signature ``force(p, s, x, v, i, dt) -> (F, dF/dv)`` where ``p``
is the law's float64 parameter array and ``s`` its (possibly empty) state array, updated in
place. ``dF/dv`` is the local tangent damping, used by the plant's linearly implicit step.
"""

from dataclasses import dataclass
import math

from numba import njit
import numpy as np

from mr_suspension.core import extended
from mr_suspension.core.fastmath import fast_tanh
from mr_suspension.core.validation import check_declared, check_positive, param, ParamsMixin

LAW_LINEAR = 0
LAW_BINGHAM = 1
LAW_TANH = 2
LAW_TANH_MAXVEL = 3
LAW_MECHANICAL = 4
LAW_BOUC_WEN = 5
LAW_EXTENDED = 6

MAXVEL_WINDOW_MAX = 4096
# Plausibility bounds shared by the laws (generous for any road-vehicle or rig damper).
F_MAX = 1.0e5  # [N] forces, yield forces, force per ampere
C_MAX = 1.0e6  # [N s/m] viscous damping (and per ampere)
K_MAX = 1.0e7  # [N/m] parallel stiffnesses
V_Y_MIN, V_Y_MAX = 1.0e-6, 10.0  # [m/s] smoothing velocities


@dataclass(frozen=True)
class LinearDamperParams(ParamsMixin):
    """Linear viscous damper ``F = c v + F0`` (passive reference, seed 001 eq. 2)."""

    c: float = param(1000.0, 0.0, C_MAX, 'N s/m', 'viscous damping')
    f0: float = param(0.0, -F_MAX, F_MAX, 'N', 'static force')

    law = 'linear'
    law_id = LAW_LINEAR
    n_state = 0

    def __post_init__(self):
        check_declared(self)


@dataclass(frozen=True)
class BinghamParams(ParamsMixin):
    """Smooth Bingham model ``F = F0 + c(i) v + Fc(i) tanh(v / v_y)`` (seed 003, eq. 5.2).

    ``c(i) = c0 + c1 i`` and ``Fc(i) = fc0 + fc1 i``; ``v_y`` smooths ``sgn`` (v_y -> 0 gives
    the Coulomb element of Stanway's model). Seed 003, Table 2 (1.5 V): Fc = 670 N,
    C0 = 50 N s/cm, F0 = -95 N.
    """

    f0: float = param(-95.0, -F_MAX, F_MAX, 'N', 'static force')
    c0: float = param(5000.0, 0.0, C_MAX, 'N s/m', 'damping at 0 A')
    c1: float = param(0.0, 0.0, C_MAX, 'N s/(m A)', 'damping per ampere')
    fc0: float = param(670.0, 0.0, F_MAX, 'N', 'yield force at 0 A')
    fc1: float = param(0.0, 0.0, F_MAX, 'N/A', 'yield force per ampere')
    v_y: float = param(0.01, V_Y_MIN, V_Y_MAX, 'm/s', 'yield smoothing velocity')

    law = 'bingham'
    law_id = LAW_BINGHAM
    n_state = 0

    def __post_init__(self):
        check_declared(self)


@dataclass(frozen=True)
class TanhParams(ParamsMixin):
    """Seed 002 current-driven model ``F = y_MR I tanh(c_MR v + k_MR x) + c_p v + k_p x``."""

    y_mr: float = param(900.0, 0.0, F_MAX, 'N/A', 'MR force per ampere')
    c_mr: float = param(30.0, 1.0e-3, 1.0e6, 's/m', 'tanh velocity scale')
    k_mr: float = param(20.0, -1.0e6, 1.0e6, '1/m', 'tanh displacement scale')
    c_p: float = param(1200.0, 0.0, C_MAX, 'N s/m', 'passive damping')
    k_p: float = param(1500.0, -K_MAX, K_MAX, 'N/m', 'passive stiffness')

    law = 'tanh'
    law_id = LAW_TANH
    n_state = 0

    def __post_init__(self):
        check_declared(self)


@dataclass(frozen=True)
class TanhMaxVelParams(ParamsMixin):
    """Max-deflection-velocity variant (seed 002).

    ``F = I v c_MR / (max_{i-k..i} |v| + eps) + c_p v + k_p x``: the post-yield damping varies
    with the peak stroke rate over the last ``window`` seconds.
    """

    c_mr: float = param(900.0, 0.0, F_MAX, 'N/A', 'MR force per ampere')
    eps: float = param(0.02, V_Y_MIN, V_Y_MAX, 'm/s', 'velocity regularisation')
    c_p: float = param(1200.0, 0.0, C_MAX, 'N s/m', 'passive damping')
    k_p: float = param(1500.0, -K_MAX, K_MAX, 'N/m', 'passive stiffness')
    window: float = param(0.25, 1.0e-3, 10.0, 's', 'peak-velocity window')

    law = 'tanh_maxvel'
    law_id = LAW_TANH_MAXVEL
    n_state = MAXVEL_WINDOW_MAX + 3

    def __post_init__(self):
        check_declared(self)


@dataclass(frozen=True)
class MechanicalParams(ParamsMixin):
    """Seed 000 mechanical model (Fig. 7): damping d(xi_dot, i) in series with k1, parallel k2.

    ``F = k1 (x - xi) + F_acc(x)`` with ``k1 (x - xi) = d(xi_dot, i)``,
    ``d(u, i) = (c0 + c1 i) u + (fy0 + fy1 i) tanh(u / v_y)`` (Fig. 8 is a smooth Bingham-like
    curve) and the accumulator ``F_acc(x) = -(a2 x^2 + a1 x + a0)``: Table 3 gives
    ``k2 = 66736 x^2 - 165 x + 162``; its constant term is the static preload in N pushing the
    rod out (hence the minus sign in our tension-positive convention). k1 = 2.505e6 N/m.
    """

    k1: float = param(2.505e6, 1.0e3, 1.0e10, 'N/m', 'series stiffness')
    a2: float = param(66736.0, -1.0e9, 1.0e9, 'N/m^2', 'accumulator quadratic term')
    a1: float = param(-165.0, -K_MAX, K_MAX, 'N/m', 'accumulator linear term')
    a0: float = param(162.0, -F_MAX, F_MAX, 'N', 'accumulator preload')
    c0: float = param(800.0, 0.0, C_MAX, 'N s/m', 'damping at 0 A')
    c1: float = param(2500.0, 0.0, C_MAX, 'N s/(m A)', 'damping per ampere')
    fy0: float = param(60.0, 0.0, F_MAX, 'N', 'yield force at 0 A')
    fy1: float = param(900.0, 0.0, F_MAX, 'N/A', 'yield force per ampere')
    v_y: float = param(0.02, V_Y_MIN, V_Y_MAX, 'm/s', 'yield smoothing velocity')

    law = 'mechanical'
    law_id = LAW_MECHANICAL
    n_state = 1

    def __post_init__(self):
        check_declared(self)


@dataclass(frozen=True)
class BoucWenParams(ParamsMixin):
    """Modified Bouc-Wen model (Spencer et al. 1997), SI units, current ``i`` as the command.

    ``F = c1 y_dot + k1 (x - x0)``,
    ``z_dot = -gamma |w| z |z|^(n-1) - beta w |z|^n + A w`` with ``w = x_dot - y_dot``,
    ``y_dot = (alpha z + c0 x_dot + k0 (x - y)) / (c0 + c1)``, with ``alpha, c0, c1`` affine in
    the current. Defaults are Spencer's identified values (per volt, read here per ampere).
    """

    alpha_a: float = param(14000.0, 0.0, 1.0e8, 'N/m', 'Bouc-Wen stiffness at 0 A')
    alpha_b: float = param(69500.0, 0.0, 1.0e8, 'N/(m A)', 'Bouc-Wen stiffness per ampere')
    c0_a: float = param(2100.0, 1.0, C_MAX, 'N s/m', 'c0 at 0 A')
    c0_b: float = param(350.0, 0.0, C_MAX, 'N s/(m A)', 'c0 per ampere')
    c1_a: float = param(28300.0, 1.0, C_MAX, 'N s/m', 'c1 at 0 A')
    c1_b: float = param(295.0, 0.0, C_MAX, 'N s/(m A)', 'c1 per ampere')
    k0: float = param(4690.0, 0.0, K_MAX, 'N/m', 'stiffness k0')
    k1: float = param(500.0, 0.0, K_MAX, 'N/m', 'accumulator stiffness k1')
    x0: float = param(0.0, -1.0, 1.0, 'm', 'accumulator initial displacement')
    gamma: float = param(3.63e6, 0.0, 1.0e10, '1/m^2', 'Bouc-Wen gamma')
    beta: float = param(3.63e6, 0.0, 1.0e10, '1/m^2', 'Bouc-Wen beta')
    a_bw: float = param(301.0, 1.0e-3, 1.0e6, '', 'Bouc-Wen A')
    n_substeps: float = param(10.0, 1.0, 1000.0, '', 'integration substeps per step')

    law = 'bouc_wen'
    law_id = LAW_BOUC_WEN
    n_state = 2

    def __post_init__(self):
        check_declared(self)


LAWS = {
    'linear': LinearDamperParams,
    'bingham': BinghamParams,
    'tanh': TanhParams,
    'tanh_maxvel': TanhMaxVelParams,
    'mechanical': MechanicalParams,
    'bouc_wen': BoucWenParams,
}


def damper_from_dict(data, source=None):
    """Build damper parameters from ``{'law': name, ...parameters}`` (YAML/JSON).

    ``source``: the file the mapping came from; then every parameter of the law is required.
    """
    if not isinstance(data, dict):
        raise ValueError(f'{source or "damper"}: expected a mapping with a "law" key, got '
                         f'{type(data).__name__}')
    data = dict(data)
    law = data.pop('law', None)
    known = sorted(LAWS) + ['extended']
    if law is None:
        raise ValueError(f'{source or "damper"}: missing required key law; add one of {known}')
    if law == 'extended':
        return extended.ExtendedDamperParams.from_dict(data, source=source)
    if not isinstance(law, str) or law not in LAWS:
        raise ValueError(f'unknown damper law {law!r}; known: {known}')
    return LAWS[law].from_dict(data, source=source)


def law_id_of(params):
    """Return the integer law id used by the jitted dispatcher."""
    if isinstance(params, extended.ExtendedDamperParams):
        return LAW_EXTENDED
    return params.law_id


def n_state_of(params):
    """Return the length of the law's state vector (at least 1 so arrays are never empty)."""
    if isinstance(params, extended.ExtendedDamperParams):
        return max(1, extended.EXT_NSTATE)
    return max(1, params.n_state)


@njit(cache=True)
def linear_force(p, x, v):
    """Linear viscous damper ``F = c v + F0``."""
    return p[0] * v + p[1], p[0]


@njit(cache=True)
def bingham_force(p, v, i):
    """Smooth Bingham ``F = F0 + (c0 + c1 i) v + (fc0 + fc1 i) tanh(v / v_y)`` (seed 003)."""
    c = p[1] + p[2] * i
    fc = p[3] + p[4] * i
    th = fast_tanh(v / p[5])
    return p[0] + c * v + fc * th, c + fc * (1.0 - th * th) / p[5]


@njit(cache=True)
def tanh_force(p, x, v, i):
    """Seed 002 ``F = y_MR I tanh(c_MR v + k_MR x) + c_p v + k_p x``."""
    th = fast_tanh(p[1] * v + p[2] * x)
    return p[0] * i * th + p[3] * v + p[4] * x, p[0] * i * (1.0 - th * th) * p[1] + p[3]


@njit(cache=True)
def maxvel_force(p, s, x, v, i, dt):
    """Seed 002 max-deflection-velocity model; ``s`` = [count, head, peak, |v| ring buffer]."""
    n = int(p[4] / dt + 0.5)
    if n < 1:
        n = 1
    if n > MAXVEL_WINDOW_MAX:
        n = MAXVEL_WINDOW_MAX
    count = int(s[0])
    head = int(s[1])
    av = abs(v)
    expired = s[3 + head] if count >= n else 0.0
    s[3 + head] = av
    head = (head + 1) % n
    if count < n:
        count += 1
    if av >= s[2]:
        s[2] = av
    elif expired >= s[2]:
        m = 0.0
        for k in range(count):
            if s[3 + k] > m:
                m = s[3 + k]
        s[2] = m
    s[0] = count
    s[1] = head
    g = p[0] * i / (s[2] + p[1])
    return g * v + p[2] * v + p[3] * x, g + p[2]


@njit(cache=True)
def _mech_d(p, u, i):
    c = p[4] + p[5] * i
    fy = p[6] + p[7] * i
    th = fast_tanh(u / p[8])
    return c * u + fy * th, c + fy * (1.0 - th * th) / p[8]


@njit(cache=True)
def mechanical_force(p, s, x, v, i, dt):
    """Seed 000 series model; implicit Euler on the internal coordinate ``xi`` (s[0]).

    Solves ``d(u, i) + k1 dt u = k1 (x - xi_n)`` for ``u = xi_dot`` by Newton safeguarded
    with bisection (the left side is monotone in ``u``), then ``xi += dt u``. Tangent: ``d'``
    in series with ``k1 dt``.
    """
    k1 = p[0]
    rhs = k1 * (x - s[0])
    # g(u) = (c + k1 dt) u + fy tanh(u / v_y) - rhs is increasing, and its root lies within
    # fy / (c + k1 dt) of rhs / (c + k1 dt): Newton steps, falling back to bisection.
    slope = p[4] + p[5] * i + k1 * dt
    fy = p[6] + p[7] * i
    lo = (rhs - fy) / slope
    hi = (rhs + fy) / slope
    u = rhs / slope
    for _ in range(60):
        d, dd = _mech_d(p, u, i)
        g = d + k1 * dt * u - rhs
        if g > 0.0:
            hi = u
        else:
            lo = u
        un = u - g / (dd + k1 * dt)
        if not (lo < un < hi):
            un = 0.5 * (lo + hi)
        if abs(un - u) <= 1e-13 * (1.0 + abs(u)):
            u = un
            break
        u = un
    d, dd = _mech_d(p, u, i)
    s[0] += dt * u
    f_acc = -(p[1] * x * x + p[2] * x + p[3])
    tangent = dd * k1 * dt / (dd + k1 * dt)
    return d + f_acc, tangent


@njit(cache=True)
def bouc_wen_force(p, s, x, v, i, dt):
    """Spencer modified Bouc-Wen, n = 2; ``s`` = [z, y]; z by implicit Euler in substeps."""
    alpha = p[0] + p[1] * i
    c0 = p[2] + p[3] * i
    c1 = p[4] + p[5] * i
    k0 = p[6]
    nsub = int(p[12])
    h = dt / nsub
    z = s[0]
    y = s[1]
    ydot = 0.0
    for _ in range(nsub):
        ydot = (alpha * z + c0 * v + k0 * (x - y)) / (c0 + c1)
        w = v - ydot
        # Implicit Euler with frozen w: -gamma |w| z |z| - beta w z^2 = -w z^2 (gamma sg + beta)
        # with sg = sign(w z), so z_new = z + h w (A - (gamma sg + beta) z_new^2): Newton on
        # that quadratic, the branch sg taken from the current iterate.
        zn = z
        for _k in range(8):
            sg = 1.0 if w * zn >= 0.0 else -1.0
            a = h * w * (p[9] * sg + p[10])
            f = zn - z - h * w * p[11] + a * zn * zn
            df = 1.0 + 2.0 * a * zn
            if df < 0.5:
                df = 0.5
            zn -= f / df
        z = zn
        y += h * ydot
    s[0] = z
    s[1] = y
    force = c1 * ydot + p[7] * (x - p[8])
    return force, c1 * c0 / (c0 + c1)


@njit(cache=True)
def damper_force(law, p, s, x, v, i, dt):
    """Dispatch to the force law ``law``; returns ``(F, dF/dv)`` and updates ``s`` in place."""
    if law == LAW_BINGHAM:
        return bingham_force(p, v, i)
    if law == LAW_TANH:
        return tanh_force(p, x, v, i)
    if law == LAW_TANH_MAXVEL:
        return maxvel_force(p, s, x, v, i, dt)
    if law == LAW_MECHANICAL:
        return mechanical_force(p, s, x, v, i, dt)
    if law == LAW_BOUC_WEN:
        return bouc_wen_force(p, s, x, v, i, dt)
    if law == LAW_EXTENDED:
        return extended.extended_force(p, s, x, v, i, dt)
    return linear_force(p, x, v)


@njit(cache=True)
def force_series(law, p, x, v, i, dt):
    """Evaluate a law along a record (arrays ``x, v, i``) from a zero state; returns F."""
    n = x.shape[0]
    s = np.zeros(MAXVEL_WINDOW_MAX + 3 if law == LAW_TANH_MAXVEL else 64)
    out = np.empty(n)
    for k in range(n):
        out[k] = damper_force(law, p, s, x[k], v[k], i[k], dt)[0]
    return out


def work_diagram_damping(x, f, freq, amplitude=None):
    """Equivalent damping from a work diagram, ``C_eq = W / (pi omega X^2)`` (seed 001, eq. 1).

    ``W`` is the loop area of force over displacement (shoelace formula on whole cycles,
    sign-independent), ``omega = 2 pi freq``, ``X`` the displacement amplitude (half the
    peak-to-peak travel unless given).
    """
    x = np.asarray(x, dtype=float)
    f = np.asarray(f, dtype=float)
    if x.shape != f.shape or x.size < 8:
        raise ValueError('work diagram needs equal-length displacement and force (>= 8 samples)')
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(f))):
        raise ValueError('work diagram: displacement and force must be finite')
    check_positive('work_diagram_damping', freq=freq)
    if amplitude is None:
        amplitude = 0.5 * (x.max() - x.min())
    check_positive('work_diagram_damping', amplitude=amplitude)
    area = abs(np.sum(f * np.roll(x, -1) - x * np.roll(f, -1))) * 0.5
    # np.roll closes the polygon; the number of cycles follows from the travel.
    cycles = np.sum(np.abs(np.diff(x))) / (4.0 * amplitude)
    cycles = max(1.0, round(cycles))
    return area / cycles / (math.pi * 2.0 * math.pi * freq * amplitude ** 2)
