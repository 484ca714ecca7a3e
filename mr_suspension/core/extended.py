"""Extended MR-damper force law: smooth Bingham plus the force-law effects of the diagnosis.

Force (stroke ``x``, + = extension; stroke rate ``v``; field current ``i``)::

    F   = F0 + kg1 x + kg2 x^2 + kg3 x^3 + F_d(u)         (gas spring k2 in parallel, seed 000)
    F_d = M_th [c(i) u A(u) + Fy(i) y (1 + rho y)]        (damping element, seed 003 eq. 5.2)
    c(i) = c0 + c1 g(i),  Fy(i) = fy0 + fy1 g(i)          (the field drives both)
    g(i) = i, or i_s tanh(w), or i_s w / (1 + |w|^m)^(1/m), w = i / i_s   (saturation, m = sat_n;
           m = 1 is the Frohlich-Kennelly magnetisation curve)
    M_th = 1 - kappa E,  A(u) = 1 + rho tanh(u / v_y)     (thermal fade, direction asymmetry)
    y(u) = S(u) = tanh(u / v_y), or w / (1 + |w|^n)^(1/n), w = u / v_y (yield shape, n = yield_n)
    y    = (1 - w_h) S(u) + w_h z                         (hysteresis: share w_h of the yield
    dz/dt = (u / x_h) [1 - |z|^n_h ((1 - r_h) sgn(u z) + r_h)]      force in a Bouc-Wen loop)
    dF_d/dt = k1 (v - u)                                  (series stiffness k1, seed 000 Fig. 7)
    dE/dt = F_d u - E / tau_th                            (stored heat from dissipated energy)

``u`` is the damping-element velocity: ``u = v`` without series stiffness, else the root of
the BDF2 balance ``F_d(u) = a F_d,n-1 - b F_d,n-2 + beta k1 dt (v - u)`` (variable step,
``w = dt_n / dt_n-1``: ``a = (1 + w)^2 / (1 + 2 w)``, ``b = w^2 / (1 + 2 w)``,
``beta = (1 + w) / (1 + 2 w)``; 4/3, 1/3, 2/3 at a constant step; backward Euler on the
first step and when ``w > 2.4``, where variable-step BDF2 stops being zero-stable).
Backward Euler would advance the spring's force by half a step
(``(1 - z^-1) / dt ~ s exp(-s dt / 2)``), which a fit reads as a force-channel delay of half a
sample on records with a soft spring; BDF2 is second order and, unlike the trapezoidal rule,
damps stiff springs instead of ringing. Every effect is off at its
neutral value: ``i_s = 0``, ``x_h = 0``, ``k1 = 0``, ``kg1 = kg2 = kg3 = 0``, ``kappa = 0``,
``rho = 0``. The hysteretic state is the normalised Bouc-Wen state (Wen 1976, Spencer et al.
1997: ``|z| <= 1``, pre-yield length ``x_h``, exponent ``n_h >= 1``, ``r_h = gamma / (beta +
gamma)`` shapes the unloading branch); ``n_h = 1, r_h = 0, w_h = 1`` is the Dahl model
``dz/dx_d = (1 - z sgn u) / x_h``. The loop is rate-independent: its state follows
the element's stroke ``d = (u_n-1 + u_n) dt / 2`` over the step (trapezoid; split at a
reversal inside the step; ``u_n dt`` would run the loop half a step ahead of the motion). In one
direction ``zeta = z sgn d`` obeys the autonomous ``dzeta/dxi = g(zeta)``, ``xi = |x_d| /
x_h``, so ``zeta+ = zeta + Z(xi0 + |d| / x_h) - Z(xi0)`` with ``Z`` the solution from
``zeta = -1`` tabulated once per parameter set (RK4, cubic Hermite look-up, ``bw_table``) and
``xi0 = Z^-1(zeta)``; for Dahl it is the closed form
``z+ = sgn d + (z - sgn d) exp(-|d| / x_h)``.

The state vector ``s`` (length ``EXT_NSTATE``, all zeros = at rest) holds
``[z, F_d, E, u, Y, M, g, dF_d/du, F_d,n-1, dt_n-1]`` with ``Y = M_th y (1 + rho y)`` and
``M = M_th A(u)`` (``F_d = M c u + Fy Y``; the last two are the BDF2 history); ``u`` to
``dF_d/du`` are the step's intermediates, which the identification
reads to build its regressors (and the next step's Newton predictor), so fitting and
simulation share this one function. The asymmetry of the yield force follows the yield state
``y`` (the sign of the force the plug carries), not the rate: with a loop, the yield force
keeps its side's scale through a reversal until the loop turns it over (a rate-following
scale steps it by ``2 rho Fy`` at every reversal). Without a loop ``y = tanh(u / v_y)`` and
both forms are ``M_th A(u) (c u + Fy y)``.
Current dynamics (dead time, lags) are not here: they belong to the driver (core.driver).
"""

from dataclasses import asdict, dataclass, fields
import functools
import math

from numba import njit
import numpy as np

from mr_suspension.core.fastmath import fast_tanh
from mr_suspension.core.validation import as_number, build, check_declared, param

EXT_NSTATE = 10
S_Z, S_FD, S_E, S_U, S_Y, S_M, S_G, S_DF, S_FD2, S_DTP = range(10)
(P_F0, P_C0, P_C1, P_FY0, P_FY1, P_VY, P_ISAT, P_XH, P_K1, P_KG1, P_KG2, P_KAPPA, P_TAUTH,
 P_RHO, P_YN, P_HW, P_HN, P_HR, P_SN, P_KG3) = range(20)
P_TAB = 20  # Bouc-Wen table (bw_table) appended to the parameter array: [h_xi, zeta.., g..]
BW_NT = 512
RHO_MAX = 0.5


@dataclass(frozen=True)
class ExtendedDamperParams:
    """Parameters of the extended law (SI); the field order is the jitted array order.

    ``f0`` [N], ``c0`` [N s/m], ``c1`` [N s/(m A)], ``fy0`` [N], ``fy1`` [N/A], ``v_y`` [m/s]
    smooth-Bingham baseline; ``i_sat`` [A] field saturation (0 = off), ``sat_n`` [-] the
    exponent of its curve ``w / (1 + |w|^m)^(1/m)`` instead of ``tanh(w)`` (0 = tanh; 1 =
    Frohlich-Kennelly); ``x_h`` [m] Dahl pre-yield length (0 = off, smooth tanh);
    ``k_series`` [N/m] series stiffness (0 = rigid); ``k_gas1`` [N/m], ``k_gas2`` [N/m^2],
    ``k_gas3`` [N/m^3] gas spring; ``kappa`` [1/J] fade per stored heat (0 = off),
    ``tau_thermal`` [s] cooling time constant; ``rho`` [-] rebound/compression asymmetry,
    ``|rho| <= 0.5``; ``yield_n`` [-] exponent of the algebraic yield sigmoid
    ``w / (1 + |w|^n)^(1/n)`` instead of ``tanh(w)`` (0 = off: n = 2 is the algebraic sigmoid,
    n near 1 a slow arctan-like tail, large n a sharp Bingham corner); ``hyst_weight`` [-]
    share ``w_h`` of the yield force carried by the hysteretic (Bouc-Wen) state, ``hyst_n``
    [-] its exponent ``n_h``, ``hyst_r`` [-] its unloading shape ``r_h = gamma/(beta+gamma)``
    (all three used only with ``x_h > 0``; 1, 1, 0 is the Dahl loop).
    """

    # Very wide ranges: the diagnosis fit must be able to represent any real damper; they only
    # reject values no damper has (e.g. k_series = 1e-300 N/m, a 1e9 N yield force).
    f0: float = param(0.0, -1.0e7, 1.0e7, 'N', 'static force')
    c0: float = param(1000.0, -1.0e8, 1.0e8, 'N s/m', 'damping at 0 A')
    c1: float = param(0.0, -1.0e8, 1.0e8, 'N s/(m A)', 'damping per ampere')
    fy0: float = param(100.0, -1.0e7, 1.0e7, 'N', 'yield force at 0 A')
    fy1: float = param(500.0, -1.0e7, 1.0e7, 'N/A', 'yield force per ampere')
    v_y: float = param(0.01, 1.0e-7, 100.0, 'm/s', 'yield smoothing velocity')
    i_sat: float = param(0.0, 1.0e-4, 1.0e3, 'A', 'field saturation current', off=0.0)
    x_h: float = param(0.0, 1.0e-7, 1.0, 'm', 'Dahl pre-yield length', off=0.0)
    k_series: float = param(0.0, 1.0, 1.0e12, 'N/m', 'series stiffness', off=0.0)
    k_gas1: float = param(0.0, -1.0e9, 1.0e9, 'N/m', 'gas spring linear term')
    k_gas2: float = param(0.0, -1.0e12, 1.0e12, 'N/m^2', 'gas spring quadratic term')
    kappa: float = param(0.0, 0.0, 1.0e6, '1/J', 'thermal fade per stored heat')
    tau_thermal: float = param(600.0, 1.0e-3, 1.0e8, 's', 'cooling time constant')
    rho: float = param(0.0, -RHO_MAX, RHO_MAX, '', 'rebound/compression asymmetry')
    yield_n: float = param(0.0, 0.3, 20.0, '', 'yield sigmoid exponent', off=0.0,
                           required=False)
    hyst_weight: float = param(1.0, 1.0e-3, 1.0, '', 'share of the yield force in the '
                               'hysteretic branch', required=False)
    hyst_n: float = param(1.0, 1.0, 6.0, '', 'Bouc-Wen exponent', required=False)
    hyst_r: float = param(0.0, -1.0, 0.5, '', 'Bouc-Wen unloading shape gamma/(beta+gamma)',
                          required=False)
    sat_n: float = param(0.0, 0.3, 20.0, '', 'magnetisation curve exponent', off=0.0,
                         required=False)
    k_gas3: float = param(0.0, -1.0e15, 1.0e15, 'N/m^3', 'gas spring cubic term',
                          required=False)

    law = 'extended'

    def __post_init__(self):
        check_declared(self)

    def to_array(self):
        """Return the float64 parameter array ``p`` of ``extended_force``.

        A Bouc-Wen loop other than Dahl appends its table (``bw_table``) after the fields.
        """
        p = np.array([float(getattr(self, f.name)) for f in fields(self)], dtype=np.float64)
        if self.x_h > 0.0 and not (self.hyst_n == 1.0 and self.hyst_r == 0.0):
            p = np.concatenate([p, _cached_table(self.hyst_n, self.hyst_r)])
        return p

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
        if len(p) != len(names) and not (len(p) == P_TAB + 1 + 2 * BW_NT):
            raise ValueError(f'ExtendedDamperParams: expected {len(names)} values, got {len(p)}')
        p = p[:len(names)]
        return cls(**{n: float(v) for n, v in zip(names, p)})


@njit(cache=True, fastmath=True, error_model='numpy')
def _bw_g(zeta, n, r):
    """Bouc-Wen slope ``dzeta/dxi = 1 - |zeta|^n ((1 - r) sgn(zeta) + r)`` (module docstring)."""
    a = abs(zeta) ** n
    return 1.0 - a if zeta >= 0.0 else 1.0 + a * (1.0 - 2.0 * r)


@njit(cache=True)
def bw_table(n, r):
    """Tabulate ``zeta(xi)`` from ``zeta = -1`` on a uniform ``xi`` grid; return the array part.

    ``[h_xi, zeta_0..zeta_{N-1}, g_0..g_{N-1}]`` (``N = BW_NT``): RK4 with 8 steps per interval
    up to ``xi = 40 / n + 6`` (``1 - zeta`` below 1e-15: the loop is closed), ``g`` the slope.
    """
    nt = BW_NT
    h = (40.0 / n + 6.0) / (nt - 1)
    out = np.empty(1 + 2 * nt)
    out[0] = h
    z = -1.0
    sub = 8
    hs = h / sub
    for k in range(nt):
        if k > 0:
            for _ in range(sub):
                k1 = _bw_g(z, n, r)
                k2 = _bw_g(z + 0.5 * hs * k1, n, r)
                k3 = _bw_g(z + 0.5 * hs * k2, n, r)
                k4 = _bw_g(z + hs * k3, n, r)
                z = min(z + hs * (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0, 1.0)
        out[1 + k] = z
        out[1 + nt + k] = _bw_g(z, n, r)
    return out


@functools.lru_cache(maxsize=512)
def _cached_table(n, r):
    t = bw_table(n, r)
    t.flags.writeable = False
    return t


@njit(cache=True, fastmath=True, error_model='numpy')
def _bw_at(p, xi):
    """Cubic Hermite look-up of the tabulated ``zeta(xi)`` (held beyond the table)."""
    nt = BW_NT
    h = p[P_TAB]
    q = xi / h
    if q >= nt - 1:
        return p[P_TAB + nt]
    if q <= 0.0:
        return -1.0
    k = int(q)
    t = q - k
    z0 = p[P_TAB + 1 + k]
    z1 = p[P_TAB + 2 + k]
    g0 = p[P_TAB + 1 + nt + k] * h
    g1 = p[P_TAB + 2 + nt + k] * h
    t2 = t * t
    t3 = t2 * t
    return ((2.0 * t3 - 3.0 * t2 + 1.0) * z0 + (t3 - 2.0 * t2 + t) * g0
            + (3.0 * t2 - 2.0 * t3) * z1 + (t3 - t2) * g1)


@njit(cache=True, fastmath=True, error_model='numpy')
def _bw_xi(p, zeta):
    """Inverse look-up ``xi`` with ``zeta(xi) = zeta`` (bisection on the table, one Newton)."""
    nt = BW_NT
    h = p[P_TAB]
    if zeta <= -1.0:
        return 0.0
    lo = 0
    hi = nt - 1
    if zeta >= p[P_TAB + nt]:
        return h * (nt - 1)
    while hi - lo > 1:
        mid = (lo + hi) >> 1
        if p[P_TAB + 1 + mid] <= zeta:
            lo = mid
        else:
            hi = mid
    z0 = p[P_TAB + 1 + lo]
    z1 = p[P_TAB + 1 + hi]
    xi = h * (lo + (zeta - z0) / (z1 - z0) if z1 > z0 else lo)
    g = p[P_TAB + 1 + nt + lo]
    if g > 1e-12:
        xi += (zeta - _bw_at(p, xi)) / g
        xi = min(max(xi, h * lo), h * hi)
    return xi


@njit(cache=True, fastmath=True, error_model='numpy')
def _loop_step(p, z, d):
    """Loop state after a stroke of ``d x_h`` in one direction: ``(z+, dz+/dd)`` (exact)."""
    if p.shape[0] <= P_TAB:  # Dahl: closed form
        if d > 0.0:
            e = math.exp(-d)
            return 1.0 + (z - 1.0) * e, (1.0 - z) * e
        if d < 0.0:
            e = math.exp(d)
            return -1.0 + (z + 1.0) * e, (z + 1.0) * e
        return z, 1.0 - abs(z)
    n = p[P_HN]
    r = p[P_HR]
    if d == 0.0:
        return z, 0.5 * (_bw_g(z, n, r) + _bw_g(-z, n, r))
    sg = 1.0 if d > 0.0 else -1.0
    zeta = sg * z
    xi0 = _bw_xi(p, zeta)
    zn = zeta + _bw_at(p, xi0 + abs(d)) - _bw_at(p, xi0)
    zn = min(max(zn, -1.0), 1.0)
    return sg * zn, _bw_g(zn, n, r)


@njit(cache=True, fastmath=True, error_model='numpy')
def _hysteretic(p, z, u0, u, dt):
    """Loop state over a step with ``u`` linear from ``u0`` to ``u``: ``(z+, dz+/du)``.

    The loop is rate-independent, so the state follows the element's stroke over the step,
    the trapezoid ``(u0 + u) dt / 2`` (split at a reversal inside the step). Taking ``u dt``
    (``u`` held over the step) ran the loop half a step ahead of the motion: a fit read that
    as a force-channel delay of half a sample on Bouc-Wen dampers.
    """
    a = 0.5 * dt / p[P_XH]
    if u0 * u >= 0.0:
        zn, dz = _loop_step(p, z, a * (u0 + u))
        return zn, a * dz
    w = u0 / (u0 - u)  # share of the step before the reversal
    zm = _loop_step(p, z, a * u0 * w)[0]
    zn, dz = _loop_step(p, zm, a * u * (1.0 - w))
    # The slope holds the reversal's instant (w moves with u too): it only steers Newton.
    return zn, a * (1.0 - w) * dz


@njit(cache=True, fastmath=True, error_model='numpy')
def _element(p, s, u, i, dt):
    """Damping-element force ``F_d(u)``, ``dF_d/du``, intermediates (Y, M, g), hysteretic state."""
    vy = p[P_VY]
    isat = p[P_ISAT]
    g = i
    if isat > 0.0:
        wi = i / isat
        sn = p[P_SN]
        g = isat * (fast_tanh(wi) if sn <= 0.0 else wi / (1.0 + abs(wi) ** sn) ** (1.0 / sn))
    c = p[P_C0] + p[P_C1] * g
    fy = p[P_FY0] + p[P_FY1] * g
    xh = p[P_XH]
    if p[P_YN] > 0.0:
        yn = p[P_YN]
        w = u / vy
        q = 1.0 + abs(w) ** yn
        r = q ** (-1.0 / yn)
        y = w * r
        dy = r / (q * vy)
    else:
        y = fast_tanh(u / vy)
        dy = (1.0 - y * y) / vy
    zh = 0.0
    if xh > 0.0:
        zh, dzh = _hysteretic(p, s[S_Z], s[S_U], u, dt)
        wh = p[P_HW]
        if wh >= 1.0:
            y = zh
            dy = dzh
        else:
            y = (1.0 - wh) * y + wh * zh
            dy = (1.0 - wh) * dy + wh * dzh
    mth = 1.0 - p[P_KAPPA] * s[S_E]
    if mth < 0.05:
        mth = 0.05
    rho = p[P_RHO]
    t = y if xh <= 0.0 and p[P_YN] <= 0.0 else fast_tanh(u / vy)
    m = mth * (1.0 + rho * t)
    dm = mth * rho * (1.0 - t * t) / vy
    yr = mth * (1.0 + rho * y) * y
    dyr = mth * (1.0 + 2.0 * rho * y) * dy
    return m * c * u + fy * yr, dm * c * u + m * c + fy * dyr, yr, m, g, zh


@njit(cache=True, fastmath=True, error_model='numpy')
def extended_force(p, s, x, v, i, dt):
    """Advance one step; return ``(F, dF/dv)`` (equations in the module docstring).

    ``p`` parameter array (``ExtendedDamperParams.to_array()``), ``s`` state (updated in place),
    ``x`` stroke [m], ``v`` stroke rate [m/s], ``i`` field current [A], ``dt`` step [s].
    """
    k1 = p[P_K1]
    if k1 > 0.0:
        fprev = s[S_FD]
        kdt = k1 * dt
        # BDF2 (variable step; zero-stable for step ratios below 1 + sqrt 2); backward Euler
        # from rest and after a step more than 2.4 times the last (a stalled caller).
        if 0.0 < s[S_DTP] and dt <= 2.4 * s[S_DTP]:
            w = dt / s[S_DTP]
            den = 1.0 + 2.0 * w
            fprev = ((1.0 + w) ** 2 * fprev - w * w * s[S_FD2]) / den
            kdt = kdt * (1.0 + w) / den
        # Monotone root of h(u) = F_d(u) - F_prev - kdt (v - u) (h' = F_d' + kdt > 0):
        # a few Newton steps from the previous step's linearisation (its u and dF_d/du); if
        # they do not settle, bracket the root and finish with Newton safeguarded by bisection.
        u = s[S_U] + kdt * (v - s[S_U]) / (s[S_DF] + kdt)
        tol = 1e-10 * (abs(v) + p[P_VY])
        done = False
        for _ in range(4):
            fd, dfd, y, m, g, zh = _element(p, s, u, i, dt)
            h = fd - fprev - kdt * (v - u)
            un = u - h / (max(dfd, 0.0) + kdt)
            if abs(un - u) <= tol:
                done = True
                break
            u = un
        if not done:
            fd, dfd, y, m, g, zh = _element(p, s, u, i, dt)
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
                fd, dfd, y, m, g, zh = _element(p, s, u, i, dt)
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
        fd, dfd, y, m, g, zh = _element(p, s, u, i, dt)
        tangent = dfd if dfd > 0.0 else 0.0
    force = p[P_F0] + (p[P_KG1] + (p[P_KG2] + p[P_KG3] * x) * x) * x + fd
    if p[P_XH] > 0.0:
        s[S_Z] = zh
    s[S_FD2] = s[S_FD]
    s[S_FD] = fd
    s[S_DTP] = dt
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
    """Run ``extended_force`` along a record from rest; return ``(F, u, Y, M, g)`` arrays."""
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


_FORCE_ONLY = np.array([P_F0, P_C0, P_C1, P_FY0, P_FY1, P_KG1, P_KG2, P_KG3, P_TAUTH])


def trajectory_key(p):
    """Bytes of ``p`` that the ``u, Y, M, g`` of ``simulate_extended`` depend on.

    Without series stiffness and thermal fade ``u = v`` and ``M_th = 1`` (module docstring),
    so they do not depend on ``F0, c0, c1, Fy0, Fy1, kg1, kg2, kg3`` (nor on ``tau_th``): those
    slots are zeroed. With either effect the force feeds the state back: all of ``p``.
    """
    if p[P_K1] > 0.0 or p[P_KAPPA] > 0.0:
        return p.tobytes()
    q = p.copy()
    q[_FORCE_ONLY] = 0.0
    return q.tobytes()
