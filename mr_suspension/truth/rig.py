"""Independent rig truth: an MR damper and its current driver as continuous-time ODEs.

Written apart from the fitting code (no import from ``identification``, ``core.extended``,
``core.driver`` or ``core.damper``): other baseline shapes, other effect shapes, another
discretisation. Sign convention as the package: stroke ``x`` + = extension, ``F`` + resists
extension, dissipated power ``F v``.

Current chain (command ``i_cmd`` held between samples, a DAC; negative commands read as 0)::

    coil:  tau_d di_c/dt = i_cmd(t) - i_c                        (driver, ``driver_tau``)
    field: tau di_f/dt = i_c(t - D) - i_f,  tau = tau_rise if i_c(t - D) > i_f else tau_fall

``D`` (``current_delay``) is a continuous dead time (any fraction of a sample); the lag is
``current_lag`` (``tau_rise = tau_fall``) or ``current_lag_asymmetric``. With
``current_site='driver'`` the dead time and lag sit before the coil measurement instead (the
measured coil current shows them). The field current is saturated by a magnetisation curve
``i_e = i_s (1 - exp(-i_f / i_s))`` (``current_saturation``), which feeds every
current-dependent coefficient: ``c = c0 + c1 i_e``, ``fy = fy0 + fy1 i_e``.

Force::

    F   = f0 + F_gas(x) + F_d  [+ F_in + F_seal: the effects outside the catalogue, below]
    F_d = m_c(T) c u (1 + rho tanh(u / v_s)) + m_y(T) fy y (1 + rho y)
    y   = S(u / v_y) (static yield), S = tanh | w / sqrt(1 + w^2) | (2/pi) atan(w)
    y   = z / z_max, dz/dt = A u - beta |u| |z|^(n-1) z - gamma u |z|^n    (Bouc-Wen;
          z_max = (A / (beta + gamma))^(1/n); Wen 1976, Spencer et al. 1997)
    dF_d/dt = k1 (v - u)                      (series spring; u solves F_d(u) = state)
    F_gas = -p0 A_r ((V0 / (V0 + A_r x))^n_g - 1)       (polytropic accumulator)
    C dT/dt = F_d u - T / R,  m_c = exp(-beta_c T),  m_y = max(1 - beta_y T, 0.1)

Two effects the diagnosis catalogue lacks (``OUTSIDE``; never drawn by the benchmark's
``EFFECTS`` cases, so those draws are unchanged), both on the rod motion, in parallel::

    F_in   = m_f a                          (fluid inertia, ``fluid_inertia``)
    F_seal = (F_c + (F_s - F_c) exp(-(v / v_s)^2)) sign(v)   (``seal_friction``, Stribeck)

``a`` is the piston acceleration (second derivative of the motion spline). ``m_f`` is the
fluid inertance seen at the piston: the MR fluid (density ~3000 kg/m^3) in the valve gap of
length ``L`` and area ``A_g`` moves ``A_p / A_g`` times faster than the piston, so its kinetic
energy is that of ``m_f = rho L A_p^2 / A_g`` at the piston. Over the gap's viscous
coefficient ``12 mu L A_p^2 / (w h^3)`` that is the inertance time ``rho h^2 / (12 mu)``, so
``m_f`` grows with the damper's size (``draw_truth``: 2-30 ms times the mid-current viscous
coefficient, about 1-100 kg). The seal friction is the rod seal and piston band: a static
(breakaway) level ``F_s`` that drops within ``v_s`` of rest to the Coulomb level ``F_c`` (a
Stribeck dip, not a monotone sigmoid: the force-velocity map overshoots near rest),
discontinuous at ``v = 0``; it acts on the rod velocity ``v``, outside any series spring.

``u`` is the damping-element velocity (``u = v`` without a series spring). Shapes:
``bingham_tanh``, ``algebraic``, ``arctan`` use the static ``y``; ``bouc_wen`` always uses the
Bouc-Wen state (pre-yield length ``1/A``). ``hysteresis`` adds a Bouc-Wen loop of pre-yield
length ``x_h`` (same ``beta/A``, ``gamma/A``, ``n``) in parallel with the static yield,
``y = (1 - w) S(u / v_y) + w z / z_max`` (``w = hyst_weight``); for ``bouc_wen`` it replaces
the baseline pre-yield length by ``x_h``. ``direction_asymmetry`` ``rho`` scales rebound against
compression (``|rho| <= 0.5`` keeps ``F_d`` monotone in ``u``).

Integration: the command chain by RK4 on a grid of ``2 * substeps`` steps per sample, each step
split at the (delayed) command edges and refined so ``h <= tau/2``; the force states
``(F_d, z, T)`` by RK4 with ``substeps`` steps per sample, each step split further when a
finite-difference Jacobian (Gershgorin bound ``lambda``) asks for it (``lambda h <= 2``),
so stiff series springs and thin Bouc-Wen loops stay stable. Motion between samples is the
cubic spline (not-a-knot) through the sampled displacement; velocity is its derivative.
"""

from dataclasses import asdict, dataclass, fields, replace
import math

from numba import njit
import numpy as np
from scipy.interpolate import CubicSpline

from mr_suspension.truth.programme import programme

__all__ = ['EFFECTS', 'OUTSIDE', 'SHAPES', 'RigTruth', 'draw_truth', 'simulate', 'contributions',
           'programme']

EFFECTS = ('current_delay', 'current_lag', 'current_lag_asymmetric', 'current_saturation',
           'hysteresis', 'series_stiffness', 'gas_spring', 'thermal_fade', 'direction_asymmetry')
# Effects outside the diagnosis catalogue (drawn only when asked for by name).
OUTSIDE = ('fluid_inertia', 'seal_friction')
KNOWN = EFFECTS + OUTSIDE
SHAPES = ('bingham_tanh', 'algebraic', 'arctan', 'bouc_wen')
SITES = ('field', 'driver')
RHO_MAX = 0.5
# Strength ranges (weak -> strong) of the effects outside the catalogue, relative to the
# damper's size (``draw_truth``): inertance time m_f / c_mid [s], seal Coulomb friction over
# the mid-current force at 0.1 m/s, breakaway over Coulomb.
FLUID_RANGE = (2e-3, 30e-3)
SEAL_FC_RANGE = (0.03, 0.3)
SEAL_RATIO_RANGE = (1.3, 3.0)
V_REF = 0.1
MAX_SPLIT = 400

# Parameter array of the force kernel.
(P_F0, P_C0, P_C1, P_FY0, P_FY1, P_VY, P_SHAPE, P_HA, P_HB, P_HG, P_HN, P_ZINV, P_HYST,
 P_K1, P_GPA, P_GA, P_GV0, P_GN, P_BC, P_BY, P_HC, P_HR, P_RHO, P_VS, NP) = range(25)


@dataclass(frozen=True)
class RigTruth:
    """Truth of one damper on one rig (SI units; the equations are in the module docstring).

    Baseline: ``shape``, ``f0`` [N], ``c0`` [N s/m] (> 0), ``c1`` [N s/(m A)], ``fy0`` [N],
    ``fy1`` [N/A], ``v_y`` [m/s]; Bouc-Wen ``bw_a``, ``bw_beta``, ``bw_gamma`` [1/m], ``bw_n``.
    Effects (off at the default): ``dead_time`` [s]; ``tau_rise``/``tau_fall`` [s] (both 0 or
    both > 0; equal = symmetric lag); ``i_sat`` [A]; ``x_h`` [m] with ``hyst_weight`` in
    (0, 1]; ``k_series`` [N/m]; ``gas_p0`` [Pa] with ``gas_area`` [m^2], ``gas_volume``
    [m^3], ``gas_n``; ``thermal_beta_c``, ``thermal_beta_y`` [1/K] with ``heat_capacity``
    [J/K] and ``thermal_resistance`` [K/W]; ``rho`` [-] with ``v_switch`` [m/s].
    Outside the catalogue: ``fluid_mass`` [kg]; ``seal_fc`` [N] with ``seal_fs`` [N]
    (``>= seal_fc``) and ``seal_vs`` [m/s].
    Driver: ``driver_tau`` [s], ``current_site`` ('field' or 'driver'), ``i_max`` [A]
    (largest command drawn). ``strengths``: drawn strength quantile per effect (0 weak).
    """

    shape: str = 'bingham_tanh'
    f0: float = 0.0
    c0: float = 800.0
    c1: float = 1000.0
    fy0: float = 80.0
    fy1: float = 600.0
    v_y: float = 0.01
    bw_a: float = 5000.0
    bw_beta: float = 2500.0
    bw_gamma: float = 2500.0
    bw_n: float = 2.0
    dead_time: float = 0.0
    tau_rise: float = 0.0
    tau_fall: float = 0.0
    i_sat: float = 0.0
    x_h: float = 0.0
    hyst_weight: float = 1.0
    k_series: float = 0.0
    gas_p0: float = 0.0
    gas_area: float = 2e-4
    gas_volume: float = 5e-5
    gas_n: float = 1.2
    thermal_beta_c: float = 0.0
    thermal_beta_y: float = 0.0
    heat_capacity: float = 1000.0
    thermal_resistance: float = 0.3
    rho: float = 0.0
    v_switch: float = 0.02
    fluid_mass: float = 0.0
    seal_fc: float = 0.0
    seal_fs: float = 0.0
    seal_vs: float = 0.005
    driver_tau: float = 0.0
    current_site: str = 'field'
    i_max: float = 1.0
    strengths: tuple = ()

    def __post_init__(self):
        if self.shape not in SHAPES:
            raise ValueError(f'RigTruth: unknown shape {self.shape!r}; known: {SHAPES}')
        if self.current_site not in SITES:
            raise ValueError(f'RigTruth: current_site must be one of {SITES}')
        for f in fields(self):
            val = getattr(self, f.name)
            if isinstance(val, float) and not math.isfinite(val):
                raise ValueError(f'RigTruth: {f.name} must be finite, got {val}')
        for name in ('c0', 'v_y', 'bw_a', 'gas_area', 'gas_volume', 'heat_capacity',
                     'thermal_resistance', 'v_switch', 'i_max', 'seal_vs'):
            if not getattr(self, name) > 0:
                raise ValueError(f'RigTruth: {name} must be > 0, got {getattr(self, name)}')
        for name in ('c1', 'fy0', 'fy1', 'dead_time', 'tau_rise', 'tau_fall', 'i_sat', 'x_h',
                     'k_series', 'gas_p0', 'thermal_beta_c', 'thermal_beta_y', 'driver_tau',
                     'fluid_mass', 'seal_fc', 'seal_fs'):
            if getattr(self, name) < 0:
                raise ValueError(f'RigTruth: {name} must be >= 0, got {getattr(self, name)}')
        if (self.tau_rise > 0) != (self.tau_fall > 0):
            raise ValueError('RigTruth: tau_rise and tau_fall must be both 0 or both > 0')
        if not 1.0 <= self.bw_n <= 6.0:
            raise ValueError(f'RigTruth: bw_n must be in [1, 6], got {self.bw_n}')
        if not (self.bw_beta + self.bw_gamma > 0 and self.bw_beta >= abs(self.bw_gamma)):
            raise ValueError('RigTruth: Bouc-Wen needs beta + gamma > 0 and beta >= |gamma|')
        if not 0.0 < self.hyst_weight <= 1.0:
            raise ValueError(f'RigTruth: hyst_weight must be in (0, 1], got {self.hyst_weight}')
        if abs(self.rho) > RHO_MAX:
            raise ValueError(f'RigTruth: |rho| must be <= {RHO_MAX}, got {self.rho}')
        if not 1.0 <= self.gas_n <= 1.67:
            raise ValueError(f'RigTruth: gas_n must be in [1, 1.67], got {self.gas_n}')
        if self.seal_fs < self.seal_fc:
            raise ValueError('RigTruth: seal_fs (breakaway) must be >= seal_fc (Coulomb)')
        if self.dead_time > 1.0:
            raise ValueError('RigTruth: dead_time must be <= 1 s')

    @property
    def effects(self):
        """Effects switched on by the parameters, in catalogue order."""
        on = {'current_delay': self.dead_time > 0,
              'current_lag': self.tau_rise > 0 and self.tau_rise == self.tau_fall,
              'current_lag_asymmetric': self.tau_rise > 0 and self.tau_rise != self.tau_fall,
              'current_saturation': self.i_sat > 0, 'hysteresis': self.x_h > 0,
              'series_stiffness': self.k_series > 0, 'gas_spring': self.gas_p0 > 0,
              'thermal_fade': self.thermal_beta_c > 0 or self.thermal_beta_y > 0,
              'direction_asymmetry': self.rho != 0, 'fluid_inertia': self.fluid_mass > 0,
              'seal_friction': self.seal_fs > 0}
        return tuple(e for e in KNOWN if on[e])

    def without(self, effect):
        """Return this truth with one effect switched off (its neutral parameters)."""
        off = {'current_delay': {'dead_time': 0.0},
               'current_lag': {'tau_rise': 0.0, 'tau_fall': 0.0},
               'current_lag_asymmetric': {'tau_rise': 0.0, 'tau_fall': 0.0},
               'current_saturation': {'i_sat': 0.0}, 'hysteresis': {'x_h': 0.0},
               'series_stiffness': {'k_series': 0.0}, 'gas_spring': {'gas_p0': 0.0},
               'thermal_fade': {'thermal_beta_c': 0.0, 'thermal_beta_y': 0.0},
               'direction_asymmetry': {'rho': 0.0}, 'fluid_inertia': {'fluid_mass': 0.0},
               'seal_friction': {'seal_fc': 0.0, 'seal_fs': 0.0}}
        if effect not in off:
            raise ValueError(f'RigTruth: unknown effect {effect!r}; known: {KNOWN}')
        return replace(self, **off[effect])

    @property
    def z_max(self):
        """Bouc-Wen bound ``(A / (beta + gamma))^(1/n)`` of the hysteretic state."""
        return (self.bw_a / (self.bw_beta + self.bw_gamma)) ** (1.0 / self.bw_n)

    def to_dict(self):
        """Return the parameters as a plain dict (JSON friendly), with the effect list."""
        d = asdict(self)
        d['strengths'] = {k: float(v) for k, v in self.strengths}
        d['effects'] = list(self.effects)
        return d

    def kernel_params(self):
        """Float64 parameter array of the force kernel (effective Bouc-Wen loop included)."""
        p = np.zeros(NP)
        p[P_F0], p[P_C0], p[P_C1] = self.f0, self.c0, self.c1
        p[P_FY0], p[P_FY1], p[P_VY] = self.fy0, self.fy1, self.v_y
        p[P_SHAPE] = SHAPES.index(self.shape)
        weight = 1.0 if self.shape == 'bouc_wen' else (self.hyst_weight if self.x_h > 0 else 0)
        scale = 1.0 / (self.x_h * self.bw_a) if self.x_h > 0 else 1.0
        p[P_HA] = self.bw_a * scale
        p[P_HB] = self.bw_beta * scale
        p[P_HG] = self.bw_gamma * scale
        p[P_HN] = self.bw_n
        p[P_ZINV] = 1.0 / self.z_max
        p[P_HYST] = weight
        p[P_K1] = self.k_series
        p[P_GPA] = self.gas_p0 * self.gas_area
        p[P_GA], p[P_GV0], p[P_GN] = self.gas_area, self.gas_volume, self.gas_n
        p[P_BC], p[P_BY] = self.thermal_beta_c, self.thermal_beta_y
        p[P_HC], p[P_HR] = self.heat_capacity, self.thermal_resistance
        p[P_RHO], p[P_VS] = self.rho, self.v_switch
        return p


# ---------------------------------------------------------------------------- current chain

@njit(cache=True, error_model='numpy')
def _lag_rhs(u, y1, y2, tau1, tr, tf):
    d1 = (u - y1) / tau1 if tau1 > 0.0 else 0.0
    if tr > 0.0:
        tau = tr if y1 > y2 else tf
        d2 = (y1 - y2) / tau
    else:
        d2 = 0.0
    return d1, d2


@njit(cache=True, error_model='numpy')
def _lag_piece(u, y1, y2, h, tau1, tr, tf):
    """Advance both lags over ``h`` at a constant input ``u`` (RK4, ``h <= tau/2`` steps)."""
    tmin = 1e300
    if tau1 > 0.0:
        tmin = tau1
    if tr > 0.0:
        tmin = min(tmin, tr, tf)
    m = 1
    if tmin < 1e300:
        m = max(1, int(math.ceil(2.0 * h / tmin)))
    hs = h / m
    if tau1 <= 0.0:
        y1 = u
    for _ in range(m):
        a1, a2 = _lag_rhs(u, y1, y2, tau1, tr, tf)
        b1, b2 = _lag_rhs(u, y1 + 0.5 * hs * a1, y2 + 0.5 * hs * a2, tau1, tr, tf)
        c1, c2 = _lag_rhs(u, y1 + 0.5 * hs * b1, y2 + 0.5 * hs * b2, tau1, tr, tf)
        d1, d2 = _lag_rhs(u, y1 + hs * c1, y2 + hs * c2, tau1, tr, tf)
        y1 += hs * (a1 + 2.0 * b1 + 2.0 * c1 + d1) / 6.0
        y2 += hs * (a2 + 2.0 * b2 + 2.0 * c2 + d2) / 6.0
    if tr <= 0.0:
        y2 = y1
    return y1, y2


@njit(cache=True, error_model='numpy')
def _lag_chain(cmd, dt, nf, delay, tau1, tr, tf):
    """Delayed held command through a lag ``tau1`` then a rise/fall lag, on a fine grid.

    Returns the output on ``t = j dt / nf``, ``j = 0 .. (N - 1) nf``, from rest at ``cmd[0]``.
    Fine steps are split at the command edges ``t_k + delay``.
    """
    n = cmd.shape[0]
    h = dt / nf
    total = (n - 1) * nf + 1
    out = np.empty(total)
    u0 = cmd[0] if cmd[0] > 0.0 else 0.0
    y1 = u0
    y2 = u0
    out[0] = y2
    eps = 1e-9 * dt
    for j in range(total - 1):
        t = j * h
        tb = t + h
        while t < tb - eps:
            k = int(math.floor((t - delay) / dt + 1e-9))
            te = min(tb, (k + 1) * dt + delay)  # the next command edge ends the piece
            kk = min(max(k, 0), n - 1)
            u = cmd[kk] if cmd[kk] > 0.0 else 0.0
            y1, y2 = _lag_piece(u, y1, y2, te - t, tau1, tr, tf)
            t = te
        if tau1 <= 0.0:  # no lag: the output is the held input itself (right-continuous)
            kk = min(max(int(math.floor((tb - delay) / dt + 1e-9)), 0), n - 1)
            y1 = cmd[kk] if cmd[kk] > 0.0 else 0.0
            if tr <= 0.0:
                y2 = y1
        out[j + 1] = y2
    return out


# ------------------------------------------------------------------------------ force law

@njit(cache=True, error_model='numpy')
def _static_yield(shape, w):
    """Return the static yield function ``S(w)`` and ``S'(w)``."""
    if shape == 1:
        r = 1.0 / math.sqrt(1.0 + w * w)
        return w * r, r * r * r
    if shape == 2:
        return (2.0 / math.pi) * math.atan(w), (2.0 / math.pi) / (1.0 + w * w)
    t = math.tanh(w)
    return t, 1.0 - t * t


@njit(cache=True, error_model='numpy')
def _element(p, u, y, dy, ie, temp):
    """Damping-element force and ``dF_d/du`` for a yield value ``y`` with ``dy/du``."""
    c = p[P_C0] + p[P_C1] * ie
    fy = p[P_FY0] + p[P_FY1] * ie
    mc = 1.0
    my = 1.0
    if temp != 0.0:
        mc = math.exp(-p[P_BC] * temp)
        my = 1.0 - p[P_BY] * temp
        if my < 0.1:
            my = 0.1
    rho = p[P_RHO]
    a = 1.0
    da = 0.0
    if rho != 0.0:
        th = math.tanh(u / p[P_VS])
        a = 1.0 + rho * th
        da = rho * (1.0 - th * th) / p[P_VS]
    f = mc * c * u * a + my * fy * y * (1.0 + rho * y)
    df = mc * c * (a + u * da) + my * fy * (1.0 + 2.0 * rho * y) * dy
    return f, df


@njit(cache=True, error_model='numpy')
def _element_u(p, u, z, ie, temp):
    """Element force, slope and yield value at element velocity ``u`` and state ``z``."""
    w = p[P_HYST]
    if w >= 1.0:
        y = z * p[P_ZINV]
        dy = 0.0
    else:
        s, ds = _static_yield(int(p[P_SHAPE]), u / p[P_VY])
        y = (1.0 - w) * s + w * z * p[P_ZINV]
        dy = (1.0 - w) * ds / p[P_VY]
    f, df = _element(p, u, y, dy, ie, temp)
    return f, df, y


@njit(cache=True, error_model='numpy')
def _solve_u(p, target, z, ie, temp, u0):
    """Element velocity with ``F_d(u) = target`` (monotone: Newton kept inside a bracket).

    Returns ``(u, dF_d/du, y)`` at the root.
    """
    u = u0
    lo = -1e300
    hi = 1e300
    tol = 1e-11 * (abs(u0) + p[P_VY])
    ftol = 1e-12 * (abs(target) + p[P_FY0] + p[P_FY1] * abs(ie) + 1.0)
    df = p[P_C0]
    y = 0.0
    for _ in range(200):
        f, df, y = _element_u(p, u, z, ie, temp)
        g = f - target
        if abs(g) <= ftol:
            return u, df, y
        if g > 0.0:
            hi = u
        else:
            lo = u
        un = u - g / df if df > 0.0 else u - g / p[P_C0]
        if not (lo < un < hi):
            if lo > -1e300 and hi < 1e300:
                un = 0.5 * (lo + hi)
            elif lo > -1e300:
                un = lo + 2.0 * (abs(lo) + p[P_VY])
            else:
                un = hi - 2.0 * (abs(hi) + p[P_VY])
        if abs(un - u) <= tol:
            return un, df, y
        u = un
    return u, df, y


@njit(cache=True, error_model='numpy')
def _rhs(p, s, v, ie, ug, d):
    """State derivative ``d`` of ``s = (F_d, z, T)``; returns ``(u, F_d, y)``."""
    series = p[P_K1] > 0.0
    temp = s[2]
    z = s[1]
    if series:
        u, _df, y = _solve_u(p, s[0], z, ie, temp, ug)
        f = s[0]
    else:
        u = v
        f, _df, y = _element_u(p, u, z, ie, temp)
    d[0] = p[P_K1] * (v - u) if series else 0.0
    if p[P_HYST] > 0.0:
        az = abs(z)
        zn = az ** p[P_HN] if az > 0.0 else 0.0
        sg = 1.0 if u * z > 0.0 else (-1.0 if u * z < 0.0 else 0.0)
        d[1] = u * (p[P_HA] - zn * (p[P_HB] * sg + p[P_HG]))
    else:
        d[1] = 0.0
    if p[P_BC] > 0.0 or p[P_BY] > 0.0:
        d[2] = (f * u - temp / p[P_HR]) / p[P_HC]
    else:
        d[2] = 0.0
    return u, f, y


@njit(cache=True, error_model='numpy')
def _inputs(coef, dt, ief, hf, tau):
    """Displacement, velocity (cubic spline) and effective current (fine grid) at ``tau``."""
    nseg = coef.shape[1]
    k = int(tau / dt)
    if k > nseg - 1:
        k = nseg - 1
    if k < 0:
        k = 0
    s = tau - k * dt
    x = ((coef[0, k] * s + coef[1, k]) * s + coef[2, k]) * s + coef[3, k]
    v = (3.0 * coef[0, k] * s + 2.0 * coef[1, k]) * s + coef[2, k]
    q = tau / hf
    m = int(q)
    if m >= ief.shape[0] - 1:
        return x, v, ief[ief.shape[0] - 1]
    if m < 0:
        return x, v, ief[0]
    fr = q - m
    return x, v, ief[m] + fr * (ief[m + 1] - ief[m])


@njit(cache=True, error_model='numpy')
def _stiffness(p, s, v, ie, ug):
    """Spectral radius of the ``(F_d, z)`` Jacobian (analytic, exact for the 2 x 2 block).

    With ``u(F_d, z)`` from ``F_d = D(u, z)``: ``du/dF = 1/D_u``, ``du/dz = -D_z/D_u``;
    ``dF'/dF = -k1/D_u``, ``dF'/dz = k1 D_z/D_u``, ``dz'/dz = Phi du/dz + u Phi_z``,
    ``dz'/dF = Phi/D_u`` with ``z' = u Phi``. The slow temperature is left out.
    """
    series = p[P_K1] > 0.0
    hyst = p[P_HYST] > 0.0
    temp = s[2]
    z = s[1]
    u = ug if series else v  # the last stage's element velocity is close enough here
    _f, du, y = _element_u(p, u, z, ie, temp)
    if du <= 0.0:
        du = 1e-300
    dz = 0.0
    phi = 0.0
    phiz = 0.0
    if hyst:
        my = 1.0 - p[P_BY] * temp
        if my < 0.1:
            my = 0.1
        dz = (my * (p[P_FY0] + p[P_FY1] * ie) * (1.0 + 2.0 * p[P_RHO] * y) * p[P_ZINV]
              * p[P_HYST])
        az = abs(z)
        sg = 1.0 if u * z > 0.0 else (-1.0 if u * z < 0.0 else 0.0)
        w = p[P_HB] * sg + p[P_HG]
        phi = p[P_HA] - (az ** p[P_HN] if az > 0.0 else 0.0) * w
        if az > 0.0:
            phiz = -p[P_HN] * az ** (p[P_HN] - 1.0) * (1.0 if z > 0.0 else -1.0) * w
    if series and hyst:
        k1 = p[P_K1]
        a = -k1 / du
        b = k1 * dz / du
        c = phi / du
        d = -phi * dz / du + u * phiz
        tr = 0.5 * (a + d)
        det = a * d - b * c
        disc = tr * tr - det
        if disc >= 0.0:
            r = math.sqrt(disc)
            return max(abs(tr + r), abs(tr - r))
        return math.sqrt(det)
    if series:
        return p[P_K1] / du
    return abs(u * phiz) if hyst else 0.0


@njit(cache=True, error_model='numpy')
def _run_force(p, coef, dt, ief, substeps):
    """Integrate ``(F_d, z, T)`` over the record; return per-sample arrays.

    Returns ``F_d, u, y, z, T, splits`` at the sample times (``splits`` = total RK4 steps).
    """
    nseg = coef.shape[1]
    n = nseg + 1
    hf = dt / (2 * substeps)
    h = dt / substeps
    series = p[P_K1] > 0.0
    hyst = p[P_HYST] > 0.0
    thermal = p[P_BC] > 0.0 or p[P_BY] > 0.0
    stiff = series or hyst
    fd = np.empty(n)
    uu = np.empty(n)
    yy = np.empty(n)
    zz = np.empty(n)
    tt = np.empty(n)
    s = np.zeros(3)
    d = np.empty(3)
    x0, v0, ie0 = _inputs(coef, dt, ief, hf, 0.0)
    ug = v0
    if series:
        s[0] = _element_u(p, v0, 0.0, ie0, 0.0)[0]
    splits = 0
    k1 = np.empty(3)
    k2 = np.empty(3)
    k3 = np.empty(3)
    k4 = np.empty(3)
    st = np.empty(3)
    for k in range(n):
        tk = k * dt
        if k > 0 and (stiff or thermal):
            for j in range(substeps):
                ta = (k - 1) * dt + j * h
                m = 1
                if stiff:
                    xa, va, iea = _inputs(coef, dt, ief, hf, ta)
                    lam = _stiffness(p, s, va, iea, ug)
                    m = int(math.ceil(lam * h / 2.0))
                    if m > MAX_SPLIT:
                        return fd, uu, yy, zz, tt, -1
                    m = max(m, 1)
                hm = h / m
                for q in range(m):
                    t1 = ta + q * hm
                    xa, va, iea = _inputs(coef, dt, ief, hf, t1)
                    ug = _rhs(p, s, va, iea, ug, k1)[0]
                    xb, vb, ieb = _inputs(coef, dt, ief, hf, t1 + 0.5 * hm)
                    for i in range(3):
                        st[i] = s[i] + 0.5 * hm * k1[i]
                    ug = _rhs(p, st, vb, ieb, ug, k2)[0]
                    for i in range(3):
                        st[i] = s[i] + 0.5 * hm * k2[i]
                    ug = _rhs(p, st, vb, ieb, ug, k3)[0]
                    xc, vc, iec = _inputs(coef, dt, ief, hf, t1 + hm)
                    for i in range(3):
                        st[i] = s[i] + hm * k3[i]
                    ug = _rhs(p, st, vc, iec, ug, k4)[0]
                    for i in range(3):
                        s[i] += hm * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]) / 6.0
                splits += m
        xk, vk, iek = _inputs(coef, dt, ief, hf, tk)
        u, f, y = _rhs(p, s, vk, iek, ug, d)
        ug = u
        fd[k] = s[0] if series else f
        uu[k] = u
        yy[k] = y
        zz[k] = s[1]
        tt[k] = s[2]
    return fd, uu, yy, zz, tt, splits


def _saturate(i, i_sat):
    if i_sat <= 0:
        return i
    return np.sign(i) * i_sat * (1.0 - np.exp(-np.abs(i) / i_sat))


def gas_force(truth, x):
    """Polytropic accumulator force ``-p0 A ((V0 / (V0 + A x))^n - 1)`` [N] (0 when off)."""
    x = np.asarray(x, dtype=float)
    if truth.gas_p0 <= 0:
        return np.zeros_like(x)
    vol = np.maximum(truth.gas_volume + truth.gas_area * x, 0.05 * truth.gas_volume)
    return -truth.gas_p0 * truth.gas_area * ((truth.gas_volume / vol) ** truth.gas_n - 1.0)


def inertia_force(truth, a):
    """Fluid inertia ``m_f a`` [N] at piston acceleration ``a`` [m/s^2] (0 when off)."""
    a = np.asarray(a, dtype=float)
    return truth.fluid_mass * a if truth.fluid_mass > 0 else np.zeros_like(a)


def seal_force(truth, v):
    """Stribeck seal friction ``(F_c + (F_s - F_c) exp(-(v/v_s)^2)) sign(v)`` [N] (0 when off)."""
    v = np.asarray(v, dtype=float)
    if truth.seal_fs <= 0:
        return np.zeros_like(v)
    level = truth.seal_fc + (truth.seal_fs - truth.seal_fc) * np.exp(-(v / truth.seal_vs) ** 2)
    return level * np.sign(v)


def _check_inputs(t, x, i_cmd, substeps):
    t = np.asarray(t, dtype=float).ravel()
    x = np.asarray(x, dtype=float).ravel()
    i_cmd = np.asarray(i_cmd, dtype=float).ravel()
    if not (t.size == x.size == i_cmd.size):
        raise ValueError(f'simulate: t, x, i_cmd have {t.size}, {x.size}, {i_cmd.size} samples')
    if t.size < 4:
        raise ValueError('simulate: need at least 4 samples')
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(x)) and np.all(np.isfinite(i_cmd))):
        raise ValueError('simulate: t, x and i_cmd must be finite')
    dt = (t[-1] - t[0]) / (t.size - 1)
    if not dt > 0 or np.max(np.abs(np.diff(t) - dt)) > 1e-6 * dt:
        raise ValueError('simulate: t must be uniform and increasing')
    if int(substeps) != substeps or not 1 <= substeps <= 1000:
        raise ValueError(f'simulate: substeps must be an integer in [1, 1000], got {substeps}')
    return t, x, i_cmd, dt, int(substeps)


def simulate(truth, t, x, i_cmd, substeps=10):
    """Run the truth along a programme; return a dict of arrays at the sample times.

    ``t`` uniform time [s], ``x`` displacement [m], ``i_cmd`` command [A] (held between
    samples). Keys: ``force`` (clean, N), ``velocity`` (spline derivative), ``displacement``,
    ``current_command``, ``coil_current``, ``field_current`` (after the current effects),
    ``effective_current`` (after saturation), ``element_velocity``, ``yield_state`` (``y``),
    ``bw_z`` (raw Bouc-Wen state), ``temperature`` (rise, K), ``gas_force``, ``acceleration``
    (spline), ``inertia_force``, ``seal_force``, ``rk4_steps``.
    """
    t, x, i_cmd, dt, substeps = _check_inputs(t, x, i_cmd, substeps)
    tr = truth
    cs = CubicSpline(t - t[0], x)
    coef = np.ascontiguousarray(cs.c)
    v = cs(t - t[0], 1)
    nf = 2 * substeps
    cmd = np.ascontiguousarray(i_cmd)
    if tr.current_site == 'field':
        coil_f = _lag_chain(cmd, dt, nf, 0.0, tr.driver_tau, 0.0, 0.0)
        field_f = _lag_chain(cmd, dt, nf, tr.dead_time, tr.driver_tau, tr.tau_rise,
                             tr.tau_fall)
    else:
        coil_f = _lag_chain(cmd, dt, nf, tr.dead_time, tr.driver_tau, tr.tau_rise, tr.tau_fall)
        field_f = coil_f
    ie_f = np.ascontiguousarray(_saturate(field_f, tr.i_sat))
    p = tr.kernel_params()
    fd, u, y, z, temp, steps = _run_force(p, coef, dt, ie_f, substeps)
    if steps < 0:
        raise ValueError(f'simulate: the truth is too stiff for {substeps} substeps (a step '
                         f'would need more than {MAX_SPLIT} splits); raise substeps or soften '
                         'k_series / the Bouc-Wen pre-yield length')
    fg = gas_force(tr, x)
    acc = cs(t - t[0], 2)
    fin = inertia_force(tr, acc)
    fs = seal_force(tr, v)
    force = tr.f0 + fg + fd
    if tr.fluid_mass > 0:  # added only when on: the catalogue's records stay bit-identical
        force = force + fin
    if tr.seal_fs > 0:
        force = force + fs
    return {'time': t, 'displacement': x, 'velocity': v, 'current_command': i_cmd,
            'force': force, 'coil_current': coil_f[::nf].copy(),
            'field_current': field_f[::nf].copy(), 'effective_current': ie_f[::nf].copy(),
            'element_velocity': u, 'yield_state': y, 'bw_z': z, 'temperature': temp,
            'gas_force': fg, 'acceleration': acc, 'inertia_force': fin, 'seal_force': fs,
            'rk4_steps': int(steps)}


def contributions(truth, t, x, i_cmd, substeps=10, base=None):
    """RMS [N] of ``F(all effects) - F(that effect off)`` at the samples, per effect.

    ``base`` is a ``simulate`` result of ``truth`` on the same inputs (recomputed if None).
    """
    if base is None:
        base = simulate(truth, t, x, i_cmd, substeps)
    out = {}
    for e in truth.effects:
        f = simulate(truth.without(e), t, x, i_cmd, substeps)['force']
        out[e] = float(np.sqrt(np.mean((base['force'] - f) ** 2)))
    return out


def driver_contribution(truth, t, x, i_cmd, substeps=10, base=None):
    """RMS [N] of the force change when the driver lag is removed (ideal driver)."""
    if truth.driver_tau <= 0:
        return 0.0
    if base is None:
        base = simulate(truth, t, x, i_cmd, substeps)
    f = simulate(replace(truth, driver_tau=0.0), t, x, i_cmd, substeps)['force']
    return float(np.sqrt(np.mean((base['force'] - f) ** 2)))


# ------------------------------------------------------------------------------------ draws

def _logq(q, weak, strong):
    """Log interpolation: ``weak`` at quantile 0, ``strong`` at 1."""
    return float(weak * (strong / weak) ** q)


def _loguniform(rng, lo, hi):
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _quantiles(rng, effects, strength):
    out = {}
    for e in effects:
        if strength is None:
            q = rng.uniform()
        elif isinstance(strength, dict):
            q = float(strength.get(e, rng.uniform()))
        else:
            q = float(strength) + rng.normal(0.0, 0.08)
        out[e] = float(np.clip(q, 0.0, 1.0))
    return out


def draw_truth(rng, effects=(), shape=None, strength=None, i_max=1.0, driver_tau=None,
               current_site='field'):
    """Draw a random ``RigTruth``: a baseline of ``shape`` (random if None) plus ``effects``.

    ``strength`` in [0, 1] places every effect parameter on its range (log scale) from weak
    (0) to strong (1), jittered by N(0, 0.08); a dict gives one quantile per effect; None
    draws each uniformly. Ranges (weak -> strong): dead time 1 -> 60 ms; lag 1 -> 150 ms;
    asymmetric lag fast 0.5-20 ms, slow/fast 1.5 -> 60 (either edge slower); saturation
    ``i_s`` 10 -> 0.25 ``i_max``; hysteresis ``x_h`` 0.1 -> 3 mm with weight 0.05 -> 1
    (``bouc_wen``: 1.5 -> 10 times its pre-yield length 0.1-1 mm); series ``k1``
    5e7 -> 5e4 N/m; gas column ``V0/A`` 0.6 -> 0.05 m at 0.5-4 MPa, rod 8-25 mm;
    thermal ``beta_c`` 0.003 -> 0.08 /K, ``C`` 3000 -> 100 J/K, ``R`` 0.05-1 K/W;
    ``|rho|`` 0.03 -> 0.5. ``driver_tau`` None draws 0.05-0.5 ms. Outside the catalogue
    (``OUTSIDE``), scaled by the damper's size (both grow with the piston area, as the
    force does): fluid mass ``m_f = tau_f c_mid`` with ``c_mid = c0 + c1 i_max / 2`` and the
    inertance time ``tau_f`` 2 -> 30 ms (``rho h^2 / (12 mu)`` of a Poiseuille gap ``h``:
    a few ms at 1 mm, tens at 2 mm with a thin fluid); seal friction ``F_c`` 0.03 -> 0.3
    ``F_ref`` (``F_ref = c_mid 0.1 m/s + fy0 + fy1 i_max / 2``, the mid-current force at
    0.1 m/s), breakaway ``F_s / F_c`` 1.3 -> 3, ``v_s`` 1-10 mm/s. A truth without them draws
    exactly as before they existed.
    """
    effects = tuple(effects)
    for e in effects:
        if e not in KNOWN:
            raise ValueError(f'draw_truth: unknown effect {e!r}; known: {KNOWN}')
    if 'current_lag' in effects and 'current_lag_asymmetric' in effects:
        raise ValueError('draw_truth: current_lag and current_lag_asymmetric exclude each other')
    if shape is None:
        shape = SHAPES[int(rng.integers(len(SHAPES)))]
    if shape not in SHAPES:
        raise ValueError(f'draw_truth: unknown shape {shape!r}; known: {SHAPES}')
    if strength is not None and not isinstance(strength, dict):
        if not (np.isfinite(strength) and 0.0 <= strength <= 1.0):
            raise ValueError(f'draw_truth: strength must be in [0, 1], got {strength}')
    if not (np.isfinite(i_max) and i_max > 0):
        raise ValueError('draw_truth: i_max must be > 0')
    d = {'shape': shape, 'i_max': float(i_max), 'current_site': current_site,
         'f0': rng.uniform(-100.0, 100.0), 'c0': _loguniform(rng, 200.0, 4000.0),
         'c1': _loguniform(rng, 150.0, 7500.0) / i_max, 'fy0': _loguniform(rng, 10.0, 450.0),
         'fy1': _loguniform(rng, 100.0, 3600.0) / i_max, 'v_y': _loguniform(rng, 0.002, 0.08)}
    x_y = _loguniform(rng, 1e-4, 1e-3)
    r = rng.uniform(-0.5, 0.5)  # gamma / (beta + gamma)
    d['bw_n'] = rng.uniform(1.0, 3.0)
    d['bw_a'] = 1.0 / x_y
    d['bw_beta'] = d['bw_a'] * (1.0 - r)
    d['bw_gamma'] = d['bw_a'] * r
    d['v_switch'] = _loguniform(rng, 0.005, 0.05)
    d['driver_tau'] = (_loguniform(rng, 5e-5, 5e-4) if driver_tau is None
                       else float(driver_tau))
    qs = _quantiles(rng, effects, strength)
    jit = lambda: rng.uniform(-0.1, 0.1)  # noqa: E731
    for e, q in qs.items():
        if e == 'current_delay':
            d['dead_time'] = _logq(q, 1e-3, 60e-3)
        elif e == 'current_lag':
            d['tau_rise'] = d['tau_fall'] = _logq(q, 1e-3, 150e-3)
        elif e == 'current_lag_asymmetric':
            fast = _loguniform(rng, 0.5e-3, 20e-3)
            slow = min(fast * _logq(q, 1.5, 60.0), 0.2)
            if rng.uniform() < 0.25:
                d['tau_rise'], d['tau_fall'] = slow, fast
            else:
                d['tau_rise'], d['tau_fall'] = fast, slow
        elif e == 'current_saturation':
            d['i_sat'] = _logq(q, 10.0, 0.25) * i_max
        elif e == 'hysteresis':
            d['x_h'] = _logq(np.clip(q + jit(), 0, 1), 1e-4, 3e-3)
            d['hyst_weight'] = _logq(q, 0.05, 1.0)
            if shape == 'bouc_wen':
                d['x_h'] = x_y * _logq(q, 1.5, 10.0)
        elif e == 'series_stiffness':
            d['k_series'] = _logq(np.clip(q + jit(), 0, 1), 5e7, 5e4)
        elif e == 'gas_spring':
            area = np.pi * (0.5 * rng.uniform(0.008, 0.025)) ** 2
            d['gas_p0'] = rng.uniform(0.5e6, 4e6)
            d['gas_area'] = area
            d['gas_volume'] = area * _logq(q, 0.6, 0.05)
            d['gas_n'] = rng.uniform(1.0, 1.4)
        elif e == 'thermal_fade':
            d['thermal_beta_c'] = _logq(q, 0.003, 0.08)
            d['thermal_beta_y'] = d['thermal_beta_c'] * rng.uniform(0.1, 0.6)
            d['heat_capacity'] = _logq(np.clip(q + jit(), 0, 1), 3000.0, 100.0)
            d['thermal_resistance'] = _loguniform(rng, 0.05, 1.0)
        elif e == 'direction_asymmetry':
            d['rho'] = _logq(q, 0.03, 0.5) * rng.choice([-1.0, 1.0])
        elif e == 'fluid_inertia':
            d['fluid_mass'] = _logq(q, *FLUID_RANGE) * (d['c0'] + 0.5 * d['c1'] * i_max)
        elif e == 'seal_friction':
            f_ref = (V_REF * (d['c0'] + 0.5 * d['c1'] * i_max) + d['fy0']
                     + 0.5 * d['fy1'] * i_max)
            d['seal_fc'] = _logq(q, *SEAL_FC_RANGE) * f_ref
            d['seal_fs'] = d['seal_fc'] * _logq(np.clip(q + jit(), 0, 1), *SEAL_RATIO_RANGE)
            d['seal_vs'] = _loguniform(rng, 1e-3, 1e-2)
    d['strengths'] = tuple(sorted(qs.items()))
    return RigTruth(**{k: (float(v) if isinstance(v, (float, np.floating)) else v)
                       for k, v in d.items()})
