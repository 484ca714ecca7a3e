"""Independent vehicle truth: a quarter car with hidden corner effects and realistic sensors.

Written apart from the core plant (no import of ``core.quarter_car``, ``sim.simulator``,
``core.damper``, ``core.driver`` or ``identification``): own integrator (RK4 with substeps
chosen from a stiffness bound), own effect shapes. Values of the nominal corner are read from
``config/vehicles/city_car.yaml``, ``config/dampers/rd1005_bingham.yaml`` and
``config/drivers/wonder_box.yaml``; ``core.road`` only generates the road profile.

Positions are absolute in the nominal car's frame (z up; stroke ``x = z_t - z_u`` + =
extension, ``z_t = z_s`` without a top mount); preloads are those of the nominal car, so a
different load (``sprung_mass``) sags the corner to its own static equilibrium, where each run
starts::

    body    m_b z_s'' = M - m_b g,   M = (m_nom - m_t) g + k_tm (z_t - z_s) + c_tm (v_t - v_s)
    strut   m_t z_t'' = S - M - m_t g                       (top mount; else body = strut top)
    wheel   m_u z_u'' = F_t - S - m_u g
    S   = P - F_spring(x) - F_d - F_f - F_stop(x) - F_bs(x),  P = m_nom g + f0
    F_t = max(0, (m_nom + m_u) g + k_t (z_r - z_u) + c_t (z_r' - z_u'))

Shapes (all differ from the core's options):

* damper (Bingham-tanh): ``F_d = f0 + (c0 + c1 i_f) v + (fc0 + fc1 i_f) tanh(v / v_y)``;
* ``spring_nonlinearity``: progressive rate ``k_s cosh(x / x_p)``, ``F = k_s x_p sinh(x / x_p)``;
* ``strut_friction``: Dahl bristle ``dF_f/dt = sigma (v - |v| F_f / F_c)``,
  ``sigma = F_c / x_pre``;
* ``bump_stop``: polynomial stop ``F_bs = sign(x) k_b e^2 (1 + e / e_0)``, ``e = |x| - x_bs > 0``;
* ``top_mount``: Kelvin-Voigt mount with a strut-top mass ``m_t`` (2 kg of the sprung mass);
* ``sprung_mass``: ``m_s`` differs from the nominal by 8 to 30 %;
* current chain: command held per sample, dead time ``D`` (``current_delay`` adds 5-30 ms), coil
  ``tau di_c/dt = u(t - D) - i_c`` (rise/fall), an extra lag at the field
  (``current_lag``: 8-40 ms, ``current_lag_asymmetric``: rise and fall differ 3-6x), fluid lag
  (the driver file's: none while rising, 16 ms falling);
* ``current_saturation``: the field saturates, ``i_e = i_sat (1 - exp(-i_f / i_sat))``;
* ``direction_asymmetry``: the damping force times ``1 + rho tanh(v / 0.02 m/s)``.

Sensors (1 kHz): IMUs give the specific force ``a + g`` (+9.81 at rest) with white and AR(1)
coloured noise; ``acc_bias``/``acc_scale`` act on the body IMU; stroke with white noise
(``stroke_lag``: first-order lag 5-30 ms); ``clipping`` clips the body IMU at a rail; an
optional measured coil current (+ white noise).
"""

from dataclasses import dataclass, field, replace
import math
from pathlib import Path

from numba import njit
import numpy as np
import yaml

import mr_suspension.core.road as rd
from mr_suspension.truth.redraw import Redrawable

EFFECTS = ('strut_friction', 'bump_stop', 'top_mount', 'spring_nonlinearity', 'sprung_mass',
           'current_delay', 'current_lag', 'current_lag_asymmetric', 'current_saturation',
           'direction_asymmetry')
SENSOR_FAULTS = ('acc_bias', 'acc_scale', 'stroke_lag', 'clipping')
COMMANDS = ('random', 'skyhook', 'constant')
COLUMN_ORDER = ('time', 'body_acc', 'wheel_acc', 'stroke', 'current_command', 'coil_current',
                'road')
MOUNT_MASS = 2.0  # [kg] strut-top mass with a top mount (taken from the sprung mass)
BUMP_E0 = 0.01  # [m] depth into the polynomial stop at which its force doubles the quadratic

# Parameter vector of the kernel.
(P_MS, P_MNOM, P_MU, P_KS, P_KT, P_CT, P_XMAX, P_XMIN, P_KSTOP, P_G, P_F0, P_C0, P_C1, P_FC0,
 P_FC1, P_VY, P_XP, P_FC, P_XPRE, P_KB, P_XBS, P_KTM, P_CTM, P_MT, P_DEAD, P_TRISE, P_TFALL,
 P_XRISE, P_XFALL, P_FRISE, P_FFALL, P_IMAX, P_ISAT, P_RHO, NP) = range(35)
RHO_SWITCH = 0.02  # [m/s] velocity over which the direction asymmetry switches sign
NY = 10  # z_s, v_s, z_u, v_u, z_t, v_t, F_f, i_c, i_x, i_f


def _config_dir():
    return Path(__file__).resolve().parents[2] / 'config'


def _read(kind, name):
    with open(_config_dir() / kind / f'{name}.yaml', encoding='utf-8') as fh:
        return yaml.safe_load(fh)


@dataclass(frozen=True)
class VehicleTruth:
    """Truth of one corner (SI; the equations are in the module docstring).

    Off values: ``f_fric = 0``, ``k_bs = 0``, ``x_p = 0``, ``k_tm = 0``, ``m_s = m_nom``,
    ``extra_delay = 0``, ``lag_rise = lag_fall = 0``.
    """

    m_s: float
    m_nom: float
    m_u: float
    k_s: float
    k_t: float
    c_t: float
    stroke_max: float
    stroke_min: float
    k_stop: float
    g: float
    f0: float
    c0: float
    c1: float
    fc0: float
    fc1: float
    v_y: float
    x_p: float = 0.0
    f_fric: float = 0.0
    x_pre: float = 5e-4
    k_bs: float = 0.0
    x_bs: float = 0.05
    k_tm: float = 0.0
    c_tm: float = 0.0
    dead_time: float = 0.003
    extra_delay: float = 0.0
    tau_rise: float = 0.007
    tau_fall: float = 0.004
    lag_rise: float = 0.0
    lag_fall: float = 0.0
    fluid_rise: float = 0.0
    fluid_fall: float = 0.016
    i_max: float = 2.0
    i_sat: float = 0.0
    rho: float = 0.0
    effects: tuple = ()

    def array(self):
        p = np.zeros(NP)
        vals = {P_MS: self.m_s, P_MNOM: self.m_nom, P_MU: self.m_u, P_KS: self.k_s,
                P_KT: self.k_t, P_CT: self.c_t, P_XMAX: self.stroke_max,
                P_XMIN: self.stroke_min, P_KSTOP: self.k_stop, P_G: self.g, P_F0: self.f0,
                P_C0: self.c0, P_C1: self.c1, P_FC0: self.fc0, P_FC1: self.fc1,
                P_VY: self.v_y, P_XP: self.x_p, P_FC: self.f_fric, P_XPRE: self.x_pre,
                P_KB: self.k_bs, P_XBS: self.x_bs, P_KTM: self.k_tm, P_CTM: self.c_tm,
                P_MT: MOUNT_MASS if self.k_tm > 0.0 else 0.0,
                P_DEAD: self.dead_time + self.extra_delay, P_TRISE: self.tau_rise,
                P_TFALL: self.tau_fall, P_XRISE: self.lag_rise, P_XFALL: self.lag_fall,
                P_FRISE: self.fluid_rise, P_FFALL: self.fluid_fall, P_IMAX: self.i_max,
                P_ISAT: self.i_sat, P_RHO: self.rho}
        for k, v in vals.items():
            p[k] = v
        return p

    def without(self, effect):
        """Return the same corner with ``effect`` switched off."""
        off = {'strut_friction': {'f_fric': 0.0}, 'bump_stop': {'k_bs': 0.0},
               'top_mount': {'k_tm': 0.0, 'c_tm': 0.0}, 'spring_nonlinearity': {'x_p': 0.0},
               'sprung_mass': {'m_s': self.m_nom}, 'current_delay': {'extra_delay': 0.0},
               'current_lag': {'lag_rise': 0.0, 'lag_fall': 0.0},
               'current_lag_asymmetric': {'lag_rise': 0.0, 'lag_fall': 0.0},
               'current_saturation': {'i_sat': 0.0}, 'direction_asymmetry': {'rho': 0.0}}[effect]
        return replace(self, effects=tuple(e for e in self.effects if e != effect), **off)


def nominal_truth():
    """Return the nominal corner (city car, RD-1005 Bingham, Wonder Box) from config."""
    car = _read('vehicles', 'city_car')
    dmp = _read('dampers', 'rd1005_bingham')
    drv = _read('drivers', 'wonder_box')
    if dmp.get('law') != 'bingham':
        raise ValueError('nominal damper must be a bingham law')
    return VehicleTruth(
        m_s=car['m_s'], m_nom=car['m_s'], m_u=car['m_u'], k_s=car['k_s'], k_t=car['k_t'],
        c_t=car['c_t'], stroke_max=car['stroke_max'], stroke_min=car['stroke_min'],
        k_stop=car['k_stop'], g=car['g'], f0=dmp['f0'], c0=dmp['c0'], c1=dmp['c1'],
        fc0=dmp['fc0'], fc1=dmp['fc1'], v_y=dmp['v_y'], dead_time=drv['dead_time'],
        tau_rise=drv['tau_rise'], tau_fall=drv['tau_fall'],
        fluid_rise=drv.get('fluid_tau_rise', 0.0), fluid_fall=drv['fluid_tau_fall'],
        i_max=drv['i_max'])


def draw_truth(rng, effects=(), strength=None, spread=0.0):
    """Draw a corner with ``effects``; ``strength`` in [0, 1] fixes every effect's quantile.

    Each range spans at least a factor 3 (weak to strong). ``spread`` (0 to 0.5): the damper
    coefficients ``c0, c1, fc0, fc1`` and the tyre stiffness ``k_t`` vary by a factor
    uniform in ``1 +- spread`` (a production spread, not an effect).
    """
    if not 0.0 <= spread <= 0.5:
        raise ValueError(f'draw_truth: spread must be in [0, 0.5], got {spread!r}')
    t = nominal_truth()
    kw = {}
    if spread > 0.0:
        for name in ('c0', 'c1', 'fc0', 'fc1', 'k_t'):
            kw[name] = getattr(t, name) * float(rng.uniform(1.0 - spread, 1.0 + spread))

    def q():
        return float(rng.uniform()) if strength is None else float(strength)

    def span(lo, hi):  # log-uniform between lo and hi
        return lo * (hi / lo) ** q()

    for e in effects:
        if e == 'strut_friction':
            kw['f_fric'] = span(15.0, 150.0)
            kw['x_pre'] = float(rng.uniform(2e-4, 1e-3))
        elif e == 'bump_stop':
            kw['x_bs'] = float(rng.uniform(0.012, 0.03))
            kw['k_bs'] = span(1.0e6, 2.0e7)
        elif e == 'top_mount':
            kw['k_tm'] = span(1.0e6, 5.0e4)  # a softer mount is a stronger effect
            kw['c_tm'] = float(rng.uniform(50.0, 600.0))
        elif e == 'spring_nonlinearity':
            kw['x_p'] = span(0.035, 0.01)  # smaller x_p: more progressive
        elif e == 'sprung_mass':
            kw['m_s'] = t.m_nom * (1.0 + rng.choice((-1.0, 1.0)) * span(0.08, 0.3))
        elif e == 'current_delay':
            kw['extra_delay'] = span(0.005, 0.03)
        elif e == 'current_lag':
            kw['lag_rise'] = kw['lag_fall'] = span(0.008, 0.04)
        elif e == 'current_lag_asymmetric':
            fast = span(0.003, 0.01)
            ratio = float(rng.uniform(3.0, 6.0))
            slow = fast * ratio
            pair = (slow, fast) if rng.uniform() < 0.5 else (fast, slow)
            kw['lag_rise'], kw['lag_fall'] = pair
        elif e == 'current_saturation':
            kw['i_sat'] = span(1.5, 0.4)  # smaller i_sat: stronger saturation
        elif e == 'direction_asymmetry':
            kw['rho'] = float(rng.choice((-1.0, 1.0))) * span(0.1, 0.4)
        else:
            raise ValueError(f'unknown effect {e!r}; known: {EFFECTS}')
    return replace(t, effects=tuple(effects), **kw)


@njit(cache=True)
def _spring(p, x):
    """Spring force and rate: linear, or progressive ``k_s x_p sinh(x / x_p)``."""
    if p[P_XP] > 0.0:
        return p[P_KS] * p[P_XP] * math.sinh(x / p[P_XP]), p[P_KS] * math.cosh(x / p[P_XP])
    return p[P_KS] * x, p[P_KS]


@njit(cache=True)
def _deriv(p, y, t, u, z_r, zr_dot, dy):
    """Right-hand side of the truth ODE at time ``t`` (command ``u`` already delayed)."""
    g = p[P_G]
    ms = p[P_MS]
    mu = p[P_MU]
    mt = p[P_MT]
    mnom = p[P_MNOM]
    mount = p[P_KTM] > 0.0
    zs, vs, zu, vu = y[0], y[1], y[2], y[3]
    zt = y[4] if mount else zs
    vt = y[5] if mount else vs
    x = zt - zu
    v = vt - vu
    # Current chain: coil lag (rise/fall), extra field lag (effect), fluid lag.
    ic, ix, i_f = y[7], y[8], y[9]
    tau = p[P_TRISE] if u > ic else p[P_TFALL]
    dy[7] = (u - ic) / tau if tau > 0.0 else 0.0
    if p[P_XRISE] > 0.0:
        tau = p[P_XRISE] if ic > ix else p[P_XFALL]
        dy[8] = (ic - ix) / tau
    else:
        dy[8] = 0.0
        ix = ic
    dix = dy[8] if p[P_XRISE] > 0.0 else dy[7]
    if p[P_FRISE] <= 0.0 and (ix > i_f or (ix == i_f and dix >= 0.0)):
        dy[9] = dix  # no fluid lag while rising: the field follows
        i_f = ix
    else:
        tau = p[P_FRISE] if ix > i_f else p[P_FFALL]
        dy[9] = (ix - i_f) / tau
    f_f = 0.0
    if p[P_FC] > 0.0:
        f_f = y[6]
        dy[6] = p[P_FC] / p[P_XPRE] * (v - abs(v) * f_f / p[P_FC])
    else:
        dy[6] = 0.0
    s = _strut(p, x, v, i_f, f_f)
    f_t = (mnom + mu) * g + p[P_KT] * (z_r - zu) + p[P_CT] * (zr_dot - vu)
    if f_t < 0.0:
        f_t = 0.0
    dy[0] = vs
    dy[2] = vu
    dy[3] = (f_t - s - mu * g) / mu
    if mount:
        mb = ms - mt
        m = (mnom - mt) * g + p[P_KTM] * (zt - zs) + p[P_CTM] * (vt - vs)
        dy[1] = (m - mb * g) / mb
        dy[4] = vt
        dy[5] = (s - m - mt * g) / mt
    else:
        dy[1] = (s - ms * g) / ms
        dy[4] = 0.0
        dy[5] = 0.0
    return f_t


@njit(cache=True)
def _run(p, y0, road_z, road_zd, cmd, mode, i_sky, dt, nsub, out):
    """Integrate over the road; ``out[k]`` = [a_s, a_u, x, v, i_cmd, i_c, z_s, z_u, F_t, i_f].

    ``mode`` 0: the command ``cmd[k]`` given; 1: on-off skyhook from the true state at each
    sample (``i_sky`` when ``v_s v > 0`` else 0), held over the sample.
    """
    n = road_z.shape[0]
    y = y0.copy()
    dy = np.zeros(NY)
    k1 = np.zeros(NY)
    k2 = np.zeros(NY)
    k3 = np.zeros(NY)
    k4 = np.zeros(NY)
    tmp = np.zeros(NY)
    h = dt / nsub
    delay = p[P_DEAD]
    mount = p[P_KTM] > 0.0
    for k in range(n):
        # Outputs at sample k.
        f_t = _deriv(p, y, k * dt, 0.0, road_z[k], road_zd[k], dy)
        zt = y[4] if mount else y[0]
        vt = y[5] if mount else y[1]
        if mode == 1:
            cmd[k] = i_sky if y[1] * (vt - y[3]) > 0.0 else 0.0
        out[k, 0] = dy[1]
        out[k, 1] = dy[3]
        out[k, 2] = zt - y[2]
        out[k, 3] = vt - y[3]
        out[k, 4] = cmd[k]
        out[k, 5] = y[7]
        out[k, 6] = y[0]
        out[k, 7] = y[2]
        out[k, 8] = f_t
        out[k, 9] = y[9]
        if k == n - 1:
            break
        for j in range(nsub):
            t0 = k * dt + j * h
            for stage in range(4):
                if stage == 0:
                    ts = t0
                    for m in range(NY):
                        tmp[m] = y[m]
                elif stage == 3:
                    ts = t0 + h
                    for m in range(NY):
                        tmp[m] = y[m] + h * k3[m]
                else:
                    ts = t0 + 0.5 * h
                    kk = k1 if stage == 1 else k2
                    for m in range(NY):
                        tmp[m] = y[m] + 0.5 * h * kk[m]
                # Command held per sample, seen after the dead time (negative = 0 A).
                kd = min(int(math.floor((ts - delay) / dt + 1e-9)), k)
                u = cmd[kd] if kd >= 0 else 0.0
                u = min(max(u, 0.0), p[P_IMAX])
                a = (ts - k * dt) / dt
                zr = (1.0 - a) * road_z[k] + a * road_z[k + 1]
                zrd = (1.0 - a) * road_zd[k] + a * road_zd[k + 1]
                kout = k1 if stage == 0 else (k2 if stage == 1 else (k3 if stage == 2 else k4))
                _deriv(p, tmp, ts, u, zr, zrd, kout)
            for m in range(NY):
                y[m] += h / 6.0 * (k1[m] + 2.0 * k2[m] + 2.0 * k3[m] + k4[m])
            # A zero rise time constant of the fluid: no lag while rising.
            ix = y[8] if p[P_XRISE] > 0.0 else y[7]
            if p[P_FRISE] <= 0.0 and y[9] < ix:
                y[9] = ix
            if y[9] < 0.0:
                y[9] = 0.0


def _substeps(tr, dt):
    """RK4 substeps per sample from a stiffness bound (``|lambda| h <= 2``)."""
    c_max = tr.c0 + tr.c1 * tr.i_max + (tr.fc0 + tr.fc1 * tr.i_max) / tr.v_y + tr.c_tm
    m_min = min(tr.m_u, MOUNT_MASS if tr.k_tm > 0.0 else tr.m_u)
    lam = max(c_max / m_min, math.sqrt((tr.k_t + tr.k_stop + tr.k_tm) / m_min),
              1.0 / min(t for t in (tr.tau_fall, tr.fluid_rise, tr.fluid_fall) if t > 0.0))
    if tr.f_fric > 0.0:
        lam = max(lam, 2.0 / tr.x_pre, math.sqrt(tr.f_fric / tr.x_pre / m_min))
    return max(2, int(math.ceil(lam * dt / 2.0)))


def _equilibrium(tr):
    """Return the state at the corner's static equilibrium (nominal preloads, actual load)."""
    g = tr.g
    dz_u = -(tr.m_s - tr.m_nom) * g / tr.k_t
    # Strut: m_nom g - F_spring(x) - F_stop(x) - F_bs(x) = m_s g, solved by bisection.
    p = tr.array()

    def strut(x):
        s = _spring(p, x)[0]
        if x > tr.stroke_max:
            s += tr.k_stop * (x - tr.stroke_max)
        elif x < tr.stroke_min:
            s += tr.k_stop * (x - tr.stroke_min)
        e = abs(x) - tr.x_bs
        if tr.k_bs > 0.0 and e > 0.0:
            s += math.copysign(tr.k_bs * e * e * (1.0 + e / BUMP_E0), x)
        return tr.m_nom * g - s - tr.m_s * g

    lo, hi = -0.5, 0.5
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if strut(mid) > 0.0:
            lo = mid
        else:
            hi = mid
    x = 0.5 * (lo + hi)
    y = np.zeros(NY)
    y[2] = dz_u
    zt = dz_u + x
    if tr.k_tm > 0.0:
        y[4] = zt
        y[0] = zt - (tr.m_s - tr.m_nom) * g / tr.k_tm
    else:
        y[0] = zt
    return y


def simulate_truth(tr, road, cmd=None, mode='given', i_sky=1.0, nsub=None):
    """Integrate the truth over ``road`` (a ``core.road.Road``); returns a dict of arrays.

    ``cmd``: current command per sample [A] (``mode='given'``) or None with
    ``mode='skyhook'``. Keys: ``body_acc``, ``wheel_acc`` (true accelerations), ``stroke``,
    ``stroke_rate``, ``current_command``, ``coil_current``, ``field_current``, ``z_s``,
    ``z_u``, ``tyre_force``.
    """
    n = road.z.size
    if mode == 'given':
        if cmd is None or np.asarray(cmd).shape != (n,):
            raise ValueError(f'simulate_truth: cmd must have one value per road sample ({n})')
        c = np.array(cmd, dtype=float)
        m = 0
    elif mode == 'skyhook':
        c = np.zeros(n)
        m = 1
    else:
        raise ValueError(f'simulate_truth: mode must be given or skyhook, got {mode!r}')
    if not np.all(np.isfinite(c)):
        raise ValueError('simulate_truth: command contains NaN or inf')
    out = np.zeros((n, 10))
    nsub = _substeps(tr, road.dt) if nsub is None else int(nsub)
    _run(tr.array(), _equilibrium(tr), road.z, road.zdot, c, m, float(i_sky), road.dt, nsub,
         out)
    if not np.all(np.isfinite(out)):
        raise FloatingPointError('simulate_truth: the truth diverged; check the parameters')
    keys = ('body_acc', 'wheel_acc', 'stroke', 'stroke_rate', 'current_command',
            'coil_current', 'z_s', 'z_u', 'tyre_force', 'field_current')
    return {k: out[:, j].copy() for j, k in enumerate(keys)}


@njit(cache=True)
def _strut(p, x, v, i_f, f_f):
    """Strut force ``S`` on the strut top (module docstring) at stroke ``x``, rate ``v``."""
    i_e = max(i_f, 0.0)
    if p[P_ISAT] > 0.0:
        i_e = p[P_ISAT] * (1.0 - math.exp(-i_e / p[P_ISAT]))
    f_d = (p[P_C0] + p[P_C1] * i_e) * v + (p[P_FC0] + p[P_FC1] * i_e) * math.tanh(v / p[P_VY])
    if p[P_RHO] != 0.0:
        f_d *= 1.0 + p[P_RHO] * math.tanh(v / RHO_SWITCH)
    f_d += p[P_F0]
    f_stop = 0.0
    if x > p[P_XMAX]:
        f_stop = p[P_KSTOP] * (x - p[P_XMAX])
    elif x < p[P_XMIN]:
        f_stop = p[P_KSTOP] * (x - p[P_XMIN])
    if p[P_KB] > 0.0:
        e = abs(x) - p[P_XBS]
        if e > 0.0:
            f_stop += math.copysign(p[P_KB] * e * e * (1.0 + e / BUMP_E0), x)
    return p[P_MNOM] * p[P_G] + p[P_F0] - _spring(p, x)[0] - f_d - f_f - f_stop


@njit(cache=True)
def _from_inputs(p, x, v, i_f, dt, nsub, out):
    """Body specific force driven by a given stroke, rate and field current (per sample).

    States: Dahl force ``F_f`` and, with a top mount, the mount's deflection ``r = z_t - z_s``
    and its rate, ``r'' = S / m_t - M (1 / m_t + 1 / m_b)`` (strut top and body equations of
    the module docstring). Inputs linear between samples, RK4 substeps.
    """
    n = x.shape[0]
    mount = p[P_KTM] > 0.0
    mt = p[P_MT]
    mb = p[P_MS] - mt
    g = p[P_G]
    y = np.zeros(3)
    if mount:  # static deflection of the mount under the actual load
        y[0] = (p[P_MS] - p[P_MNOM]) * g / p[P_KTM]
    h = dt / nsub
    ks = np.zeros((4, 3))
    tmp = np.zeros(3)
    for k in range(n):
        if mount:
            out[k] = ((p[P_MNOM] - mt) * g + p[P_KTM] * y[0] + p[P_CTM] * y[1]) / mb
        else:
            out[k] = _strut(p, x[k], v[k], i_f[k], y[2]) / p[P_MS]
        if k == n - 1:
            break
        for j in range(nsub):
            for stage in range(4):
                c = (0.0, 0.5, 0.5, 1.0)[stage]
                for m in range(3):
                    tmp[m] = y[m] if stage == 0 else y[m] + c * h * ks[stage - 1, m]
                a = (j + c) / nsub
                xs = (1.0 - a) * x[k] + a * x[k + 1]
                vs = (1.0 - a) * v[k] + a * v[k + 1]
                fs = (1.0 - a) * i_f[k] + a * i_f[k + 1]
                vt = vs + (tmp[1] if mount else 0.0)
                if p[P_FC] > 0.0:
                    ks[stage, 2] = p[P_FC] / p[P_XPRE] * (vt - abs(vt) * tmp[2] / p[P_FC])
                else:
                    ks[stage, 2] = 0.0
                if mount:
                    s = _strut(p, xs, vt, fs, tmp[2])
                    mm = (p[P_MNOM] - mt) * g + p[P_KTM] * tmp[0] + p[P_CTM] * tmp[1]
                    ks[stage, 0] = tmp[1]
                    ks[stage, 1] = s / mt - mm * (1.0 / mt + 1.0 / mb)
                else:
                    ks[stage, 0] = 0.0
                    ks[stage, 1] = 0.0
            for m in range(3):
                y[m] += h / 6.0 * (ks[0, m] + 2.0 * ks[1, m] + 2.0 * ks[2, m] + ks[3, m])


@njit(cache=True)
def _field_from_coil(p, coil, dt):
    """Field current from a coil current (held per sample): the extra lag stage, the fluid."""
    n = coil.shape[0]
    out = np.empty(n)
    ix = i_f = max(coil[0], 0.0)
    for k in range(n):
        out[k] = i_f
        ic = max(coil[k], 0.0)
        if p[P_XRISE] > 0.0:
            tau = p[P_XRISE] if ic > ix else p[P_XFALL]
            ix = ic + (ix - ic) * math.exp(-dt / tau)
        else:
            ix = ic
        tau = p[P_FRISE] if ix > i_f else p[P_FFALL]
        i_f = ix + (i_f - ix) * math.exp(-dt / tau) if tau > 0.0 else ix
    return out


def body_acc_from_inputs(case, stroke, stroke_rate, coil_current=None):
    """Return the truth's body specific force [m/s^2, +g at rest] on given inputs.

    The truth model used as a predictor the way ``diagnose-vehicle`` uses its fits: the
    strut law of the truth (its own current chain, Dahl state, mount dynamics) evaluated on
    motion estimated from the measurements instead of the true motion, and, if given, on the
    measured ``coil_current`` (through the truth's own field lags) instead of its own.
    Its NRMSE against the measured body acceleration is the reference for a model fed the
    same inputs. With a top mount the given stroke is taken as the strut's (sensor) stroke and
    the rate as the body-wheel rate; the mount's own motion is integrated on top of it.
    """
    x = np.ascontiguousarray(stroke, dtype=float)
    v = np.ascontiguousarray(stroke_rate, dtype=float)
    dt = float(case.columns['time'][1] - case.columns['time'][0])
    if coil_current is None:
        i_f = np.ascontiguousarray(case.clean['field_current'], dtype=float)
    else:
        i_f = _field_from_coil(case.truth.array(),
                               np.ascontiguousarray(coil_current, dtype=float), dt)
    if not (x.shape == v.shape == i_f.shape):
        raise ValueError('body_acc_from_inputs: stroke, rate, current and the case must have '
                         'one value per sample')
    out = np.zeros(x.size)
    _from_inputs(case.truth.array(), x, v, i_f, dt, _substeps(case.truth, dt), out)
    return out


@dataclass(frozen=True)
class SensorSpec:
    """Sensor chain (SI) of a vehicle record.

    IMU white and AR(1) noise [m/s^2] and the AR time constant [s], stroke noise [m],
    coil-current noise [A]; faults: body-IMU ``bias`` [m/s^2] and ``scale`` [-] (1 = none),
    stroke lag [s], clipping ``rail`` (fraction of the peak |a|, 0 = none).
    """

    acc_white: float = 0.03
    acc_ar: float = 0.02
    acc_ar_tau: float = 0.05
    stroke_noise: float = 2e-4
    current_noise: float = 0.005
    bias: float = 0.0
    scale: float = 1.0
    stroke_lag: float = 0.0
    rail: float = 0.0
    faults: tuple = ()


def draw_sensor(rng, faults=(), clean_acc=None):
    """Draw noise levels and the faults' sizes (``rail`` is set from the signal later)."""
    kw = {'acc_white': float(rng.uniform(0.01, 0.05)),
          'acc_ar': float(rng.uniform(0.005, 0.03)),
          'acc_ar_tau': float(rng.uniform(0.02, 0.2)),
          'stroke_noise': float(rng.uniform(5e-5, 5e-4)),
          'current_noise': float(rng.uniform(0.002, 0.01))}
    for f in faults:
        if f == 'acc_bias':
            kw['bias'] = float(rng.choice((-1.0, 1.0)) * rng.uniform(0.1, 0.5))
        elif f == 'acc_scale':
            kw['scale'] = float(1.0 + rng.choice((-1.0, 1.0)) * rng.uniform(0.04, 0.15))
        elif f == 'stroke_lag':
            kw['stroke_lag'] = float(rng.uniform(0.005, 0.03))
        elif f == 'clipping':
            kw['rail'] = float(rng.uniform(0.6, 0.85))  # fraction of the peak, set later
        else:
            raise ValueError(f'unknown sensor fault {f!r}; known: {SENSOR_FAULTS}')
    return SensorSpec(faults=tuple(faults), **kw)


def _ar1(rng, n, sigma, tau, dt):
    a = math.exp(-dt / tau)
    w = rng.normal(0.0, sigma * math.sqrt(1.0 - a * a), n)
    out = np.empty(n)
    acc = rng.normal(0.0, sigma)
    for k in range(n):
        acc = a * acc + w[k]
        out[k] = acc
    return out


def _lag(x, tau, dt):
    if tau <= 0.0:
        return x.copy()
    a = 1.0 - math.exp(-dt / tau)
    out = np.empty_like(x)
    y = x[0]
    for k in range(x.size):
        y += a * (x[k] - y)
        out[k] = y
    return out


def measure(rng, clean, spec, g, dt):
    """Apply the sensor chain; returns ``(columns without time, body-IMU noise)``."""
    n = clean['body_acc'].size
    nb = rng.normal(0.0, spec.acc_white, n) + _ar1(rng, n, spec.acc_ar, spec.acc_ar_tau, dt)
    nw = rng.normal(0.0, spec.acc_white, n) + _ar1(rng, n, spec.acc_ar, spec.acc_ar_tau, dt)
    body = spec.scale * (clean['body_acc'] + g) + spec.bias + nb
    if spec.rail > 0.0:
        rail = spec.rail * float(np.max(np.abs(body - g))) + g
        body = np.clip(body, 2.0 * g - rail, rail)
    cols = {'body_acc': body, 'wheel_acc': clean['wheel_acc'] + g + nw,
            'stroke': _lag(clean['stroke'], spec.stroke_lag, dt)
            + rng.normal(0.0, spec.stroke_noise, n),
            'current_command': clean['current_command'].copy(),
            'coil_current': clean['coil_current'] + rng.normal(0.0, spec.current_noise, n)}
    return cols, nb


def _command(rng, n, dt, kind, i_max):
    """Command per sample: random levels held 0.05-0.5 s, or a constant."""
    if kind == 'constant':
        return np.full(n, float(rng.uniform(0.2, 0.8) * i_max))
    cmd = np.empty(n)
    k = 0
    while k < n:
        hold = int(rng.uniform(0.05, 0.5) / dt)
        cmd[k:k + hold] = rng.uniform(0.0, i_max)
        k += hold
    return cmd


@dataclass(frozen=True, eq=False)
class VehicleCase(Redrawable):
    """One synthetic vehicle record with its truth.

    ``columns`` (``time``, ``body_acc``, ``wheel_acc`` [m/s^2, specific force, z up],
    ``stroke`` [m, + = extension], ``current_command`` [A], optional ``coil_current`` [A] and
    ``road`` [m]), ``truth`` (:class:`VehicleTruth`), ``sensor`` (:class:`SensorSpec`),
    ``noise_rms`` (body-IMU noise RMS [m/s^2]), ``contributions`` (per hidden effect, RMS change
    of the true body acceleration without it / ``noise_rms``; per sensor fault, RMS change of
    its channel / that channel's noise RMS), ``clean`` (noise-free outputs), ``args``.
    """

    seed: int
    record: int
    columns: dict
    truth: VehicleTruth
    sensor: SensorSpec
    noise_rms: float
    contributions: dict
    clean: dict = field(repr=False)
    args: dict = field(repr=False)

    @property
    def effects(self):
        """Hidden corner and current effects of the truth."""
        return self.truth.effects

    def write_csv(self, path):
        """Write the columns as CSV with a header; return the path."""
        path = Path(path)
        names = [c for c in COLUMN_ORDER if c in self.columns]
        np.savetxt(path, np.column_stack([self.columns[c] for c in names]), delimiter=',',
                   header=','.join(names), comments='', fmt='%.10g')
        return path


def _rng(seed, *tags):
    return np.random.default_rng([int(seed), *tags])


def make_vehicle_case(seed, effects=(), sensor_faults=(), duration=60.0, rate=1000.0,
                      command='random', road_class=None, speed=None, bump=None,
                      strength=None, measured_current=True, with_road=False, record=0,
                      i_max=1.0, spread=0.0):
    """Draw a vehicle case: corner with hidden ``effects``, road, command and sensors.

    From independent streams of ``seed``: the truth and the sensor spec (the car's), and per
    ``record`` the road (ISO 8608 class B-D at 10-30 m/s unless given, plus a bump if
    ``bump`` is a height [m]), the command (``random`` levels, on-off ``skyhook`` or
    ``constant``, at most ``i_max`` [A]) and the noise. ``spread``: production spread of the
    damper and tyre (:func:`draw_truth`).
    """
    if isinstance(seed, bool) or int(seed) != seed or seed < 0:
        raise ValueError(f'make_vehicle_case: seed must be a non-negative integer, got {seed}')
    if int(record) != record or record < 0:
        raise ValueError(f'make_vehicle_case: record must be a non-negative integer, got '
                         f'{record}')
    bad = [e for e in effects if e not in EFFECTS]
    if bad or len(set(effects)) != len(tuple(effects)):
        raise ValueError(f'make_vehicle_case: unknown or repeated effects {bad or effects}; '
                         f'known: {EFFECTS}')
    if 'current_lag' in effects and 'current_lag_asymmetric' in effects:
        raise ValueError('make_vehicle_case: current_lag and current_lag_asymmetric exclude '
                         'each other')
    bad = [f for f in sensor_faults if f not in SENSOR_FAULTS]
    if bad:
        raise ValueError(f'make_vehicle_case: unknown sensor faults {bad}; known: '
                         f'{SENSOR_FAULTS}')
    if not (isinstance(i_max, (int, float)) and 0.0 < i_max <= 2.0):
        raise ValueError(f'make_vehicle_case: i_max must be in (0, 2] A, got {i_max!r}')
    if command not in COMMANDS:
        raise ValueError(f'make_vehicle_case: command must be one of {COMMANDS}')
    if not (isinstance(duration, (int, float)) and 1.0 <= duration <= 3600.0):
        raise ValueError(f'make_vehicle_case: duration must be 1 to 3600 s, got {duration!r}')
    if not (isinstance(rate, (int, float)) and 100.0 <= rate <= 10000.0):
        raise ValueError(f'make_vehicle_case: rate must be 100 to 10000 Hz, got {rate!r}')
    args = {'seed': int(seed), 'effects': tuple(effects),
            'sensor_faults': tuple(sensor_faults), 'duration': duration, 'rate': rate,
            'command': command, 'road_class': road_class, 'speed': speed, 'bump': bump,
            'strength': strength, 'measured_current': measured_current,
            'with_road': with_road, 'record': int(record), 'i_max': i_max, 'spread': spread}
    dt = 1.0 / rate
    tr = draw_truth(_rng(seed, 1), effects, strength, spread)
    spec = draw_sensor(_rng(seed, 2), sensor_faults)
    r = _rng(seed, 3, record)
    cls = road_class or str(r.choice(['B', 'C', 'C', 'D']))
    spd = float(speed) if speed is not None else float(r.uniform(10.0, 30.0))
    road = rd.iso8608(road_class=cls, speed=spd, duration=duration, dt=dt,
                      seed=int(r.integers(0, 2 ** 31)))
    if bump is not None:
        b = rd.bump(height=float(bump), length=1.0, speed=spd, t0=0.5 * duration,
                    duration=duration, dt=dt)
        road = rd.Road(road.name + '+bump', dt, road.z + b.z, road.zdot + b.zdot)
    mode = 'skyhook' if command == 'skyhook' else 'given'
    cmd = None if mode == 'skyhook' else _command(r, road.z.size, dt, command, float(i_max))
    clean = simulate_truth(tr, road, cmd, mode, i_sky=float(i_max))
    cols, noise = measure(_rng(seed, 4, record), clean, spec, tr.g, dt)
    noise_rms = float(np.sqrt(np.mean(noise ** 2)))
    contrib = {}
    for e in tr.effects:
        other = simulate_truth(tr.without(e), road, cmd, mode, i_sky=float(i_max))
        contrib[e] = float(np.sqrt(np.mean((clean['body_acc'] - other['body_acc']) ** 2))
                           / noise_rms)
    ideal = replace(spec, bias=0.0, scale=1.0, stroke_lag=0.0, rail=0.0)
    for f in spec.faults:
        one = {'acc_bias': {'bias': spec.bias}, 'acc_scale': {'scale': spec.scale},
               'stroke_lag': {'stroke_lag': spec.stroke_lag}, 'clipping': {'rail': spec.rail}}[f]
        a, _ = measure(_rng(seed, 4, record), clean, replace(ideal, **one), tr.g, dt)
        b, _ = measure(_rng(seed, 4, record), clean, ideal, tr.g, dt)
        ch, floor = ('stroke', spec.stroke_noise) if f == 'stroke_lag' else ('body_acc',
                                                                             noise_rms)
        contrib[f] = float(np.sqrt(np.mean((a[ch] - b[ch]) ** 2)) / floor)
    n = road.z.size
    columns = {'time': np.arange(n) * dt, **cols}
    if not measured_current:
        del columns['coil_current']
    if with_road:
        columns['road'] = road.z.copy()
    return VehicleCase(seed=int(seed), record=int(record), columns=columns, truth=tr,
                       sensor=spec, noise_rms=noise_rms, contributions=contrib, clean=clean,
                       args=args)


VehicleCase.make = make_vehicle_case  # what ``unseen`` draws again
