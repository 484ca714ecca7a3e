"""Extended MR-damper force law: smooth Bingham plus the force-law effects of the diagnosis.

Force (stroke ``x``, + = extension; stroke rate ``v``; field current ``i``)::

    F   = F0 + kg1 x + kg2 x^2 + F_d(u)                   (gas spring k2 in parallel, seed 000)
    F_d = M(u) [c(i) u + Fy(i) y(u)]                      (damping element, seed 003 eq. 5.2)
    c(i) = c0 + c1 i,  Fy(i) = fy0 + fy1 g(i),  g(i) = i_s tanh(i / i_s)   (saturation)
    M(u) = (1 - kappa E) (1 + rho tanh(u / v_y))          (thermal fade, direction asymmetry)
    y(u) = tanh(u / v_y), or the Dahl state ``dz/dx_d = (1 - z sgn u) / x_h`` (hysteresis),
           or w / (1 + |w|^n)^(1/n), w = u / v_y (yield shape, exponent n = yield_n)
    dF_d/dt = k1 (v - u)                                  (series stiffness k1, seed 000 Fig. 7)
    dE/dt = F_d u - E / tau_th                            (stored heat from dissipated energy)

``u`` is the damping-element velocity: ``u = v`` without series stiffness, else the root of
the backward-Euler balance ``F_d(u) = F_d,prev + k1 dt (v - u)``. Every effect is off at its
neutral value: ``i_s = 0``, ``x_h = 0``, ``k1 = 0``, ``kg1 = kg2 = 0``, ``kappa = 0``,
``rho = 0``. The Dahl step is exact for a constant ``u`` over the step:
``z+ = sgn u + (z - sgn u) exp(-|u| dt / x_h)``.

The state vector ``s`` (length ``EXT_NSTATE``, all zeros = at rest) holds
``[z, F_d, E, u, y, M, g, dF_d/du]``; the last five are the step's intermediates, which the
identification reads to build its regressors (and the next step's Newton predictor), so fitting
and simulation share this one function.
Current dynamics (dead time, lags) are not here: they belong to the driver (core.driver).
"""

from dataclasses import asdict, dataclass, fields
import math

from numba import njit
import numpy as np

from mr_suspension.core.fastmath import fast_tanh
from mr_suspension.core.validation import as_number, build, check_declared, param

EXT_NSTATE = 8
S_Z, S_FD, S_E, S_U, S_Y, S_M, S_G, S_DF = range(8)
(P_F0, P_C0, P_C1, P_FY0, P_FY1, P_VY, P_ISAT, P_XH, P_K1, P_KG1, P_KG2, P_KAPPA, P_TAUTH,
 P_RHO, P_YN) = range(15)
RHO_MAX = 0.5


@dataclass(frozen=True)
class ExtendedDamperParams:
    """Parameters of the extended law (SI); the field order is the jitted array order.

    ``f0`` [N], ``c0`` [N s/m], ``c1`` [N s/(m A)], ``fy0`` [N], ``fy1`` [N/A], ``v_y`` [m/s]
    smooth-Bingham baseline; ``i_sat`` [A] yield saturation (0 = off); ``x_h`` [m] Dahl
    pre-yield length (0 = off, smooth tanh); ``k_series`` [N/m] series stiffness (0 = rigid);
    ``k_gas1`` [N/m], ``k_gas2`` [N/m^2] gas spring; ``kappa`` [1/J] fade per stored heat
    (0 = off), ``tau_thermal`` [s] cooling time constant; ``rho`` [-] rebound/compression
    asymmetry, ``|rho| <= 0.5``; ``yield_n`` [-] exponent of the algebraic yield sigmoid
    ``w / (1 + |w|^n)^(1/n)`` instead of ``tanh(w)`` (0 = off: n = 2 is the algebraic sigmoid,
    n near 1 a slow arctan-like tail, large n a sharp Bingham corner).
    """

    # Very wide ranges: the diagnosis fit must be able to represent any real damper; they only
    # reject values no damper has (e.g. k_series = 1e-300 N/m, a 1e9 N yield force).
    f0: float = param(0.0, -1.0e7, 1.0e7, 'N', 'static force')
    c0: float = param(1000.0, -1.0e8, 1.0e8, 'N s/m', 'damping at 0 A')
    c1: float = param(0.0, -1.0e8, 1.0e8, 'N s/(m A)', 'damping per ampere')
    fy0: float = param(100.0, -1.0e7, 1.0e7, 'N', 'yield force at 0 A')
    fy1: float = param(500.0, -1.0e7, 1.0e7, 'N/A', 'yield force per ampere')
    v_y: float = param(0.01, 1.0e-7, 100.0, 'm/s', 'yield smoothing velocity')
    i_sat: float = param(0.0, 1.0e-4, 1.0e3, 'A', 'yield saturation current', off=0.0)
    x_h: float = param(0.0, 1.0e-7, 1.0, 'm', 'Dahl pre-yield length', off=0.0)
    k_series: float = param(0.0, 1.0, 1.0e12, 'N/m', 'series stiffness', off=0.0)
    k_gas1: float = param(0.0, -1.0e9, 1.0e9, 'N/m', 'gas spring linear term')
    k_gas2: float = param(0.0, -1.0e12, 1.0e12, 'N/m^2', 'gas spring quadratic term')
    kappa: float = param(0.0, 0.0, 1.0e6, '1/J', 'thermal fade per stored heat')
    tau_thermal: float = param(600.0, 1.0e-3, 1.0e8, 's', 'cooling time constant')
    rho: float = param(0.0, -RHO_MAX, RHO_MAX, '', 'rebound/compression asymmetry')
    yield_n: float = param(0.0, 0.3, 20.0, '', 'yield sigmoid exponent', off=0.0,
                           required=False)

    law = 'extended'

    def __post_init__(self):
        check_declared(self)

    def to_array(self):
        """Return the float64 parameter array ``p`` of ``extended_force``."""
        return np.array([float(getattr(self, f.name)) for f in fields(self)], dtype=np.float64)

    def to_dict(self):
        """Return the parameters as a plain dict (JSON/YAML friendly)."""
        return {k: float(v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data, source=None):
        """Build from a mapping (a ``law`` key is ignored); unknown keys raise ValueError.

        ``source``: the file the mapping came from; then every parameter is required.
        """
        if not isinstance(data, dict):
            raise ValueError(f'{source or cls.__name__}: expected a mapping of parameters, got '
                             f'{type(data).__name__}')
        data = {k: as_number(cls.__name__, k, v) for k, v in data.items() if k != 'law'}
        return build(cls, data, source=source)

    @classmethod
    def from_array(cls, p):
        """Build from a parameter array in field order."""
        names = [f.name for f in fields(cls)]
        if len(p) != len(names):
            raise ValueError(f'ExtendedDamperParams: expected {len(names)} values, got {len(p)}')
        return cls(**{n: float(v) for n, v in zip(names, p)})


@njit(cache=True, fastmath=True, error_model='numpy')
def _element(p, s, u, i, dt):
    """Damping-element force ``F_d(u)`` and ``dF_d/du`` with the intermediates (y, M, g)."""
    vy = p[P_VY]
    isat = p[P_ISAT]
    g = isat * fast_tanh(i / isat) if isat > 0.0 else i
    c = p[P_C0] + p[P_C1] * i
    fy = p[P_FY0] + p[P_FY1] * g
    xh = p[P_XH]
    if xh > 0.0:
        z = s[S_Z]
        a = dt / xh
        if u > 0.0:
            e = math.exp(-a * u)
            y = 1.0 + (z - 1.0) * e
            dy = a * (1.0 - z) * e
        elif u < 0.0:
            e = math.exp(a * u)
            y = -1.0 + (z + 1.0) * e
            dy = a * (z + 1.0) * e
        else:
            y = z
            dy = a * (1.0 - abs(z))
    elif p[P_YN] > 0.0:
        yn = p[P_YN]
        w = u / vy
        q = 1.0 + abs(w) ** yn
        r = q ** (-1.0 / yn)
        y = w * r
        dy = r / (q * vy)
    else:
        y = fast_tanh(u / vy)
        dy = (1.0 - y * y) / vy
    mth = 1.0 - p[P_KAPPA] * s[S_E]
    if mth < 0.05:
        mth = 0.05
    t = y if xh <= 0.0 and p[P_YN] <= 0.0 else fast_tanh(u / vy)
    m = mth * (1.0 + p[P_RHO] * t)
    dm = mth * p[P_RHO] * (1.0 - t * t) / vy
    core = c * u + fy * y
    return m * core, dm * core + m * (c + fy * dy), y, m, g


@njit(cache=True, fastmath=True, error_model='numpy')
def extended_force(p, s, x, v, i, dt):
    """Advance one step; return ``(F, dF/dv)`` (equations in the module docstring).

    ``p`` parameter array (``ExtendedDamperParams.to_array()``), ``s`` state (updated in place),
    ``x`` stroke [m], ``v`` stroke rate [m/s], ``i`` field current [A], ``dt`` step [s].
    """
    k1 = p[P_K1]
    if k1 > 0.0:
        kdt = k1 * dt
        fprev = s[S_FD]
        # Monotone root of h(u) = F_d(u) - F_prev - k1 dt (v - u) (h' = F_d' + k1 dt > 0):
        # a few Newton steps from the previous step's linearisation (its u and dF_d/du); if
        # they do not settle, bracket the root and finish with Newton safeguarded by bisection.
        u = s[S_U] + kdt * (v - s[S_U]) / (s[S_DF] + kdt)
        tol = 1e-10 * (abs(v) + p[P_VY])
        done = False
        for _ in range(4):
            fd, dfd, y, m, g = _element(p, s, u, i, dt)
            h = fd - fprev - kdt * (v - u)
            un = u - h / (max(dfd, 0.0) + kdt)
            if abs(un - u) <= tol:
                done = True
                break
            u = un
        if not done:
            fd, dfd, y, m, g = _element(p, s, u, i, dt)
            h = fd - fprev - kdt * (v - u)
            step = abs(v - u) + p[P_VY]
            lo = u
            hi = u
            if h > 0.0:
                for _ in range(200):
                    lo = hi - step
                    step *= 2.0
                    if _element(p, s, lo, i, dt)[0] - fprev - kdt * (v - lo) <= 0.0:
                        break
                    hi = lo
            else:
                for _ in range(200):
                    hi = lo + step
                    step *= 2.0
                    if _element(p, s, hi, i, dt)[0] - fprev - kdt * (v - hi) >= 0.0:
                        break
                    lo = hi
            u = 0.5 * (lo + hi)
            for _ in range(200):
                fd, dfd, y, m, g = _element(p, s, u, i, dt)
                h = fd - fprev - kdt * (v - u)
                if h > 0.0:
                    hi = u
                else:
                    lo = u
                un = u - h / (max(dfd, 0.0) + kdt)
                if not (lo < un < hi):
                    un = 0.5 * (lo + hi)
                if abs(un - u) <= tol or hi - lo <= tol:
                    break
                u = un
        if dfd < 0.0:
            dfd = 0.0
        tangent = dfd * kdt / (dfd + kdt)
    else:
        u = v
        fd, dfd, y, m, g = _element(p, s, u, i, dt)
        tangent = dfd if dfd > 0.0 else 0.0
    force = p[P_F0] + p[P_KG1] * x + p[P_KG2] * x * x + fd
    if p[P_XH] > 0.0:
        s[S_Z] = y
    s[S_FD] = fd
    if p[P_KAPPA] > 0.0:
        s[S_E] = s[S_E] * math.exp(-dt / p[P_TAUTH]) + fd * u * dt
    s[S_U] = u
    s[S_DF] = dfd if dfd > 0.0 else 0.0
    s[S_Y] = y
    s[S_M] = m
    s[S_G] = g
    return force, tangent


@njit(cache=True, fastmath=True, error_model='numpy', nogil=True)
def simulate_extended(p, x, v, i, dt):
    """Run ``extended_force`` along a record from rest; return ``(F, u, y, M, g)`` arrays."""
    n = x.shape[0]
    s = np.zeros(EXT_NSTATE)
    f = np.empty(n)
    u = np.empty(n)
    y = np.empty(n)
    m = np.empty(n)
    g = np.empty(n)
    for k in range(n):
        f[k] = extended_force(p, s, x[k], v[k], i[k], dt)[0]
        u[k] = s[S_U]
        y[k] = s[S_Y]
        m[k] = s[S_M]
        g[k] = s[S_G]
    return f, u, y, m, g
