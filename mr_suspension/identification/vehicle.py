"""``diagnose-vehicle``: what the nominal corner gets wrong on a car's (or rig's) sensor data.

No load cell: the body equation gives the total strut force from the body acceleration,

    m_s a_body = S(x, v, i),   S = -(k_s x + F_d(v, i) + F_fric + F_bs + k_s3 x^3) + const,

so the strut force is fitted in units of acceleration (S/m_s): linear in ``theta`` for fixed
nonlinear parameters ``eta`` (separable least squares). The baseline is the nominal corner
(``config/``) with the spring rate and the smooth-Bingham damper refitted,
``a = b - kappa x - (c0 + c1 i) v / m_s - (fy0 + fy1 i) tanh(v / v_y) / m_s``,
``i`` the field current from the command through the nominal driver (or the measured coil
current through the nominal fluid lag). ``m_s`` scales all of it: without a known force it is
not identifiable (reported as the nominal); with a road (rig shaker displacement) the wheel
equation ``m_u a_u + m_s a_s = k_t delta + c_t delta'`` (``delta`` the tyre deflection) gives
``m_s`` and ``k_t``. Effects are judged on held-out blocks with the rig diagnose's rule
(:func:`mr_suspension.identification.diagnose.accepted`); see docs/diagnose_vehicle.md.
"""

from dataclasses import asdict, dataclass, field, fields, replace
import itertools
import json
import math
from pathlib import Path
import time

from numba import njit
import numpy as np
from scipy import optimize, signal

from mr_suspension.core.quarter_car import TOP_MOUNT_MASS_FRACTION
from mr_suspension.identification import catalogue, diagnose, engine, sensors, vehicle_data
from mr_suspension.identification.data import DataError
from mr_suspension.identification.vehicle_data import G, nan_safe

N_FOLDS = 5
BLOCKS_PER_FOLD = 4    # 24 blocks: 5 inner folds and the outer label, dealt in turn
GAP = 0.1              # [s] dropped at every block edge
SEARCH_RATE = 250.0    # [Hz] rows used by the selection (the columns run at the full rate)
MAX_CAUSES = 3
PARTLY_FACTOR = diagnose.PARTLY_FACTOR
BIAS_MIN = 0.05        # [m/s^2] accelerometer offset worth reporting (local g varies ~0.03)
ROAD_HP = 2.0          # [Hz] high-pass of the wheel equation (double integration drifts below)
ROAD_CLOSE = 0.2       # wheel-equation held-out NRMSE above which m_s is not judged
MASS_MIN = 0.05        # sprung-mass change below the wheel equation's systematic error
MATERIAL = 1.5         # a cause must change its signal by >= this x that sensor's noise ...
G_STRONG = 0.4         # ... or remove this share of the held-out MSE (noise-level, everywhere)
EDGES_MIN = 4          # current edges each way that make the current dynamics testable
SENSOR_EFFECTS = catalogue.names(catalogue.CAR, ('sensor',))  # the stroke lag: checked at load
CURRENT_EFFECTS = catalogue.names(catalogue.CAR, ('current',))
PHYSICS = catalogue.names(catalogue.CAR, ('vehicle', 'current', 'damper'))
ROAD_EFFECTS = catalogue.names(catalogue.CAR, stage='road')
ALL_EFFECTS = SENSOR_EFFECTS + PHYSICS + ROAD_EFFECTS
EXCLUSIVE = catalogue.exclusive(catalogue.CAR)
# Where each fitted effect goes (part, field names). The vehicle fields are QuarterCarParams'
# corner options (written when the class has them, else reported under ``not_written``);
# top_mount falls back to the extended damper's k_series; the current chain's to the driver.
EFFECT_PARAMS = {e.name: ('driver' if e.location == 'current' else e.location, e.params)
                 for e in catalogue.CAR}
EFFECT_TEXT = {e.name: e.enters for e in catalogue.CAR}
SEPARATING = catalogue.CAR_SEPARATING
# A baseline term the fit refits that may hold an effect: (effect, its linear coefficient).
BASELINE_TERMS = ('c0', 'fy0', 'k_s')
ALIAS_SHIFT = 0.25  # a refitted baseline term this far from its nominal value has absorbed
# something (beyond a damper's production spread of about 10-15 %)
UNTESTABLE_HOW = {e.name: e.how for e in catalogue.CAR}


@dataclass
class Nominal:
    """The nominal corner: vehicle, damper and driver parameter objects."""

    vehicle: object
    damper: object
    driver: object

    @classmethod
    def load(cls, vehicle='city_car', damper='rd1005_bingham', driver='wonder_box'):
        """Load from ``config/`` names or YAML paths (as ``simulate`` does)."""
        from mr_suspension.sim.corner import load_damper, load_driver, load_vehicle
        return cls(load_vehicle(vehicle), load_damper(damper), load_driver(driver))

    def damper_coeffs(self):
        """Nominal ``(c0, c1, fy0, fy1, v_y)`` [N s/m, N s/(m A), N, N/A, m/s]."""
        d = self.damper
        if hasattr(d, 'fc0'):
            return d.c0, d.c1, d.fc0, d.fc1, d.v_y
        if hasattr(d, 'fy0'):
            return d.c0, d.c1, d.fy0, d.fy1, d.v_y
        return 1500.0, 0.0, 100.0, 400.0, 0.02


class Prepared:
    """Signals of all records concatenated, with fold labels (inner 0..K-1, outer, -1)."""

    def __init__(self, records, nominal):
        self.records = records
        self.nominal = nominal
        self.dt = records[0].dt
        self.coil = all(r.coil_current is not None for r in records)
        self.road = all(r.road is not None for r in records)
        self.t, self.x, self.v, self.y, self.u, self.au, self.slices = [], [], [], [], [], [], []
        labels, start = [], 0
        for r in records:
            cut = r.cutoff
            self.y.append(sensors.lowpass(r.body_acc - np.mean(r.body_acc[r.mask]), r.dt, cut,
                                          order=4))
            self.au.append(sensors.lowpass(r.wheel_acc - np.mean(r.wheel_acc[r.mask]), r.dt,
                                           cut, order=4))
            self.x.append(r.stroke if r.stroke_fused is None else r.stroke_fused)
            self.v.append(r.stroke_rate)
            u = r.coil_current if self.coil else r.current_command
            self.u.append(np.clip(u, 0.0, None))
            self.t.append(r.time)
            self.slices.append(slice(start, start + r.n))
            start += r.n
            labels.append(engine.fold_labels(r, N_FOLDS, GAP, BLOCKS_PER_FOLD, True))
        self.fold = np.concatenate(labels)
        self.y_all = np.concatenate(self.y)
        veh = nominal.vehicle
        xa = np.concatenate(self.x)
        # The nominal end stops are part of the nominal corner: a known term, not fitted
        # (``F = k_stop (x - x_max)`` beyond rebound, ``(x - x_min)`` beyond bump; per nominal
        # m_s). A rougher unseen road reaches them where the fit's record did not.
        stop = np.maximum(xa - veh.stroke_max, 0.0) + np.minimum(xa - veh.stroke_min, 0.0)
        self.stop = -veh.k_stop * stop / veh.m_s
        self.coupling = np.zeros_like(self.stop)
        self.known = self.stop
        self.mount_q = {}  # top-mount rate per (K, C): see mount_fit
        self.n = start
        q = max(1, int(round(1.0 / (SEARCH_RATE * self.dt))))
        sel = np.zeros(self.n, dtype=bool)
        sel[::q] = True
        self.search_rows = sel & (self.fold >= 0)
        self.full_rows = self.fold >= 0
        self.outer = self.fold == engine.OUTER
        self.x_abs = np.abs(np.concatenate(self.x))
        self.i_max = max(float(np.max(np.concatenate(self.u))), 1e-3)
        self.v_scale = float(np.percentile(np.abs(np.concatenate(self.v)), 99)) or 1e-3
        self.imu_noise = max(math.sqrt(np.mean([vehicle_data._white(r.body_acc, r.dt) * 0.5
                                                / r.dt for r in records])), 1e-9)

    def set_coupling(self, coupling):
        """Add a known acceleration from outside the corner (a full car's other corners)."""
        coupling = np.asarray(coupling, dtype=float)
        if coupling.shape != self.stop.shape or not np.all(np.isfinite(coupling)):
            raise ValueError(f'coupling must be finite with shape {self.stop.shape}')
        self.coupling = coupling
        self.known = self.stop + coupling

    def grids(self):
        """Grids of the nonlinear parameters of each effect (scaled by the data)."""
        xq = np.percentile(self.x_abs, [50, 70, 80, 90, 95, 98, 99.5])
        return {
            'imu_timing': {'imu_timing': np.array([-2, -1.5, -1, -0.75, -0.5, -0.25, 0.25, 0.5,
                                                   0.75, 1, 1.5, 2]
                                                  ) * 1e-3},
            'strut_friction': {'v_fric': np.concatenate((np.geomspace(2e-4, 0.02, 9),
                                                         -np.geomspace(5e-5, 4e-3, 8)))},
            'bump_stop': {'x_bs': xq},
            'spring_nonlinearity': {},
            'top_mount': {'tau_tm': np.geomspace(2e-3, 0.06, 9)},  # the screen's
            'current_delay': {'dead_time': np.arange(0.002, 0.061, 0.002)},
            'current_lag': {'tau': np.geomspace(2e-3, 0.12, 12)},
            'current_lag_asymmetric': {'tau_rise': np.geomspace(5e-4, 0.12, 9),
                                       'tau_fall': np.geomspace(5e-4, 0.12, 9)},
            'current_saturation': {'i_sat': self.i_max * np.array([0.2, 0.35, 0.5, 0.8, 1.2])},
            'direction_asymmetry': {'rho': np.array([-0.45, -0.3, -0.2, -0.12, -0.06, 0.06,
                                                     0.12, 0.2, 0.3, 0.45])},
        }


def base_eta(nominal, coil):
    """Nonlinear parameters of the baseline: nominal v_y and current chain."""
    d = nominal.driver
    c0, c1, fy0, fy1, v_y = nominal.damper_coeffs()
    if coil:  # the measured coil current: no driver stage, the fluid's lag
        chain = (0.0, 0.0, 0.0, d.fluid_tau_rise, d.fluid_tau_fall)
    else:
        chain = (d.dead_time, d.tau_rise, d.tau_fall, d.fluid_tau_rise, d.fluid_tau_fall)
    return {'v_y': float(v_y), 'chain': tuple(float(c) for c in chain)}


def _field(u, dt, effects, eta):
    """Field current: driver (lag rise/fall + dead time), the effects, then the fluid's lag.

    ``current_delay`` adds a dead time, ``current_lag`` a symmetric first-order stage and
    ``current_lag_asymmetric`` a stage with its own rise/fall time constants. The stages
    switch their time constant with the direction of change, so their order matters: an extra
    lag acts on the current before the fluid follows the field (a slower driver, or eddy
    currents delaying the field behind the coil current), the fluid's lag comes last.
    """
    dead, tr, tf, ftr, ftf = eta['chain']
    if 'current_delay' in effects:
        dead = dead + eta['dead_time']
    y = engine.field_current(np.ascontiguousarray(u, dtype=float), dt, dead, tr, tf)
    if 'current_lag' in effects:
        y = engine.field_current(y, dt, 0.0, eta['tau'], eta['tau'])
    if 'current_lag_asymmetric' in effects:
        y = engine.field_current(y, dt, 0.0, eta['tau_rise'], eta['tau_fall'])
    if ftr > 0 or ftf > 0:
        y = engine.field_current(y, dt, 0.0, ftr, ftf)
    return y


def driver_coil(cmd, dt, dead, tau_rise, tau_fall):
    """Coil current of the driver model from the command.

    Lag (rise/fall), then a fractional dead time (a held command: + half a sample).
    """
    y = engine.field_current(np.clip(cmd, 0.0, None), dt, 0.0, tau_rise, tau_fall)
    k = np.arange(y.size)
    return np.interp(k - dead / dt, k, y)


def driver_check(P):
    """With a measured coil current: command -> coil against the nominal driver.

    The coil current predicted by the driver's lag (rise/fall) and dead time from the command
    is scored per inner fold; ``current_delay`` (dead time + k samples, k = 2..60 ms) and then
    ``current_lag``/``current_lag_asymmetric`` (rise/fall x 0.5..4) are judged by the selection
    rule. Returns ``(causes, steps, fitted (dead, rise, fall))``.
    """
    d = P.nominal.driver
    cmd = [r.current_command for r in P.records]
    coil = np.concatenate([r.coil_current for r in P.records])
    rows = P.full_rows

    noise = math.sqrt(np.mean([vehicle_data._white(r.coil_current, r.dt) * 0.5 / r.dt
                               for r in P.records]))

    def predict_coil(dead, tr, tf):
        return np.concatenate([driver_coil(c, P.dt, dead, tr, tf) for c in cmd])

    def sse(dead, tr, tf):
        e2 = (coil - predict_coil(dead, tr, tf)) ** 2
        return np.array([e2[rows & (P.fold == f)].sum() for f in range(N_FOLDS)])

    def material(old, new):
        return float(np.std(predict_coil(*new) - predict_coil(*old))) >= MATERIAL * noise

    # Fine timing first (not a cause): the dead time within +-1 ms of the nominal, as the
    # command's hold and the stamps place it; the causes are judged against that.
    fine = d.dead_time + np.arange(-4, 5) * 0.25e-3
    fine = fine[fine >= 0.0]
    d0 = float(fine[int(np.argmin([sse(x, d.tau_rise, d.tau_fall).sum() for x in fine]))])
    nom = sse(d0, d.tau_rise, d.tau_fall)
    deads = d0 + np.arange(2, 61) * 1e-3
    errs = [sse(x, d.tau_rise, d.tau_fall) for x in deads]
    j = int(np.argmin([e.sum() for e in errs]))
    causes, steps = [], []
    dead, cur = d0, nom
    pooled, t, _ = diagnose.fold_stats(errs[j], nom)
    ok = diagnose.accepted(errs[j], nom) and material(
        (d0, d.tau_rise, d.tau_fall), (deads[j], d.tau_rise, d.tau_fall))
    steps.append({'stage': 'driver (command -> coil)', 'effect': 'current_delay',
                  'gain_mse': round(pooled, 4), 't': round(t, 2), 'accepted': bool(ok),
                  'eta': {'dead_time': float(deads[j])}})
    if ok:
        causes.append('current_delay')
        dead, cur = float(deads[j]), errs[j]
    mult = np.array([0.5, 0.75, 1.5, 2.0, 3.0, 4.0])
    best = None
    for a in np.concatenate(([1.0], mult)):
        for b in np.concatenate(([1.0], mult)):
            if a == b == 1.0:
                continue
            e = sse(dead, d.tau_rise * a, d.tau_fall * b)
            if best is None or e.sum() < best[0].sum():
                best = (e, a, b)
    rise, fall = d.tau_rise, d.tau_fall
    if best is not None:
        e, a, b = best
        pooled, t, _ = diagnose.fold_stats(e, cur)
        ok = diagnose.accepted(e, cur) and material(
            (dead, d.tau_rise, d.tau_fall), (dead, d.tau_rise * a, d.tau_fall * b))
        name = 'current_lag' if abs(math.log(a / b)) < 0.5 else 'current_lag_asymmetric'
        steps.append({'stage': 'driver (command -> coil)', 'effect': name,
                      'gain_mse': round(pooled, 4), 't': round(t, 2), 'accepted': bool(ok),
                      'eta': {'tau_rise': d.tau_rise * a, 'tau_fall': d.tau_fall * b}})
        if ok:
            causes.append(name)
            rise, fall = d.tau_rise * a, d.tau_fall * b
    return causes, steps, (dead, rise, fall)


@njit(cache=True, nogil=True)
def dahl(x, x_pre):
    """Dahl friction state ``z`` (``F = f_fric z``): ``dz/dx = (1 - z sgn(dx)) / x_pre``.

    Stepped exactly for each stroke increment: ``z = s + (z - s) exp(-|dx| / x_pre)``,
    ``s = sgn(dx)``; starts at 0.
    """
    z = np.empty_like(x)
    zk = 0.0
    z[0] = 0.0
    for k in range(1, x.size):
        dx = x[k] - x[k - 1]
        if dx != 0.0:
            sg = 1.0 if dx > 0.0 else -1.0
            zk = sg + (zk - sg) * math.exp(-abs(dx) / x_pre)
        z[k] = zk
    return z


def _shift(t, s, lag):
    return np.interp(t + lag, t, s)


def columns(P, effects, eta):
    """Regressors ``X`` (n x p, already negated: ``a = X theta``) and their names."""
    blocks = []
    names = None
    mount = 'top_mount' in effects and 'k_tm_s' in eta
    lag = 'top_mount' in effects and not mount  # the linear screen (see mount_search)
    for k, sl in enumerate(P.slices):
        x, v, i = _motion(P, k, effects, eta)
        if mount:  # the damper's rate is the strut's: body-wheel rate + the mount's rate
            v = v + P.mount_q[_mount_key(eta)][sl]
        tv = np.tanh(v / eta['v_y'])
        iy = _saturated(i, effects, eta)
        damp = [v, iy * v, tv, iy * tv]
        dn = ['c0', 'c1', 'fy0', 'fy1']
        if 'direction_asymmetry' in effects:
            a = 1.0 + eta['rho'] * tv
            damp = [d * a for d in damp]
        if 'strut_friction' in effects:
            # v_fric > 0: velocity friction tanh(v / v_fric); < 0: Dahl, x_pre = -v_fric
            vf = eta['v_fric']
            damp.append(np.tanh(v / vf) if vf > 0 else dahl(x, -vf))
            dn.append('f_fric')
        if lag:
            al = 1.0 - math.exp(-P.dt / eta['tau_tm'])
            damp = [signal.lfilter([al], [1.0, al - 1.0], d, zi=[(1.0 - al) * d[0]])[0]
                    for d in damp]
        cols = [np.ones_like(x), x] + damp
        cn = ['offset', 'k_s'] + dn
        if 'spring_nonlinearity' in effects:
            cols.append(x ** 3)
            cn.append('k_s3')
        if 'bump_stop' in effects:
            cols.append(np.maximum(np.abs(x) - eta['x_bs'], 0.0) ** 2 * np.sign(x))
            cn.append('k_bs')
        blk = np.column_stack(cols)
        blk[:, 1:] *= -1.0
        if mount:  # everything the strut carries reaches the body through the mount
            blk[:, 1:] = _mount_filter(np.ascontiguousarray(blk[:, 1:]), eta['k_tm_s'],
                                       eta['c_tm_s'], TOP_MOUNT_MASS_FRACTION, P.dt, MOUNT_SUB)
        blocks.append(blk)
        names = cn
    return np.concatenate(blocks), names


def _saturated(i, effects, eta):
    """Return the field current damping and yield force see: ``i_sat tanh(i / i_sat)`` or ``i``."""
    return eta['i_sat'] * np.tanh(i / eta['i_sat']) if 'current_saturation' in effects else i


def _motion(P, k, effects, eta):
    """Stroke, body-wheel rate and field current of record ``k`` at the IMU's instants."""
    x, v, t = P.x[k], P.v[k], P.t[k]
    i = _field(P.u[k], P.dt, effects, eta)
    if 'imu_timing' in effects:  # the motion and current at the IMU sample's time
        lag = eta['imu_timing']
        x, v, i = _shift(t, x, lag), _shift(t, v, lag), _shift(t, i, lag)
    return x, v, i


# -- the top mount: a strut-top mass on a Kelvin-Voigt mount ----------------------------------
#
# The core's top mount (``core.quarter_car``): a strut-top node of mass m_t = mu m_s carries
# the strut force S and reaches the body through k_tm, c_tm. Per unit m_s, with the mount's
# deflection r = z_t - z_s and M = K r + C r' (K = k_tm / m_s, C = c_tm / m_s):
#
#     r'' = s / mu - nu M,   nu = 1 / (mu (1 - mu)),   a_body = M / (1 - mu),
#
# and the damper sees the strut's rate v + r' (v: the body-wheel rate the IMUs give). Given
# r'(t) the body acceleration is linear in theta (the mount is a linear filter of s), so the
# fit alternates: the mount's rate from the nonlinear strut law (:func:`_mount_rate`), then
# theta by least squares on the regressors at v + r', filtered by the mount.
MOUNT_SUB = 2     # backward-Euler substeps per sample (mount resonance up to ~150 Hz)


def _mount_key(eta):
    return (round(eta['k_tm_s'], 9), round(eta['c_tm_s'], 9))


@njit(cache=True, nogil=True, fastmath=True, error_model='numpy')
def _mount_filter(X, K, C, mu, dt, nsub):
    """Body acceleration from each column of strut force ``X`` through the mount.

    Backward Euler on ``nsub`` substeps, the input linear within a sample, starting at the
    static deflection (a constant passes unchanged).
    """
    n, p = X.shape
    out = np.empty_like(X)
    nu = 1.0 / (mu * (1.0 - mu))
    h = dt / nsub
    den = 1.0 + h * nu * (K * h + C)
    for j in range(p):
        r = X[0, j] / (mu * nu * K)
        q = 0.0
        for k in range(n):
            out[k, j] = (K * r + C * q) / (1.0 - mu)
            if k == n - 1:
                break
            for m in range(nsub):
                a = (m + 1.0) / nsub
                s = (1.0 - a) * X[k, j] + a * X[k + 1, j]
                q = (q + h * (s / mu - nu * K * r)) / den
                r += h * q
    return out


@njit(cache=True, nogil=True, error_model='numpy')
def _mount_rate(sx, cv, fy, v, vy, rho, ff, vf, K, C, mu, dt, nsub):
    """Mount rate ``r'`` per sample under the nonlinear strut law (per unit m_s).

    ``s(w) = sx - A(w) (cv w + fy tanh(w / vy)) - ff tanh(w / vf)``, ``A = 1 + rho tanh(w /
    vy)``, at the strut rate ``w = v + r'``; backward Euler with a Newton solve per substep
    (the steep yield branch makes the strut-top equation stiff).
    """
    n = v.size
    out = np.empty(n)
    nu = 1.0 / (mu * (1.0 - mu))
    h = dt / nsub
    r = sx[0] / (mu * nu * K)
    q = 0.0
    for k in range(n):
        out[k] = q
        if k == n - 1:
            break
        for m in range(nsub):
            a = (m + 1.0) / nsub
            s0 = (1.0 - a) * sx[k] + a * sx[k + 1]
            c = (1.0 - a) * cv[k] + a * cv[k + 1]
            f = (1.0 - a) * fy[k] + a * fy[k + 1]
            vv = (1.0 - a) * v[k] + a * v[k + 1]
            qn = q
            for _ in range(12):
                w = vv + qn
                t = math.tanh(w / vy)
                am = 1.0 + rho * t
                da = rho * (1.0 - t * t) / vy
                sv = am * (c * w + f * t)
                dsv = am * (c + f * (1.0 - t * t) / vy) + da * (c * w + f * t)
                if ff != 0.0:
                    tf = math.tanh(w / vf)
                    sv += ff * tf
                    dsv += ff * (1.0 - tf * tf) / vf
                g = qn - q - h * ((s0 - sv) / mu - nu * (K * (r + h * qn) + C * qn))
                # A fitted law may feed energy in where it extrapolates (dsv < 0): a chord
                # step with the dissipative part only keeps the iteration defined.
                dg = 1.0 + h * (max(dsv, 0.0) / mu + nu * (K * h + C))
                d = g / dg
                qn -= d
                if abs(d) < 1e-12 + 1e-9 * abs(qn):
                    break
            q = qn
            r += h * q
    return out


def mount_rates(P, fit, eta=None):
    """Mount rate ``r'`` (all records) of ``fit``'s strut law with the mount of ``eta``."""
    eta = dict(fit.eta if eta is None else eta)
    th = dict(zip(fit.names, fit.theta))
    static = [e for e in fit.effects if e != 'top_mount']
    X, names = columns(P, static, eta)
    vel = {'c0', 'c1', 'fy0', 'fy1'}
    ff, vf = 0.0, 1.0
    if 'strut_friction' in fit.effects and eta['v_fric'] > 0:
        vel.add('f_fric')
        ff, vf = th.get('f_fric', 0.0), eta['v_fric']
    idx = [j for j, n in enumerate(names) if n not in vel]
    sx_all = X[:, idx] @ np.array([th.get(names[j], 0.0) for j in idx]) + P.stop
    rho = eta['rho'] if 'direction_asymmetry' in fit.effects else 0.0
    out = []
    for k, sl in enumerate(P.slices):
        _, v, i = _motion(P, k, fit.effects, eta)
        iy = _saturated(i, fit.effects, eta)
        cv = th.get('c0', 0.0) + th.get('c1', 0.0) * iy
        fy = th.get('fy0', 0.0) + th.get('fy1', 0.0) * iy
        with np.errstate(all='ignore'):
            q = _mount_rate(np.ascontiguousarray(sx_all[sl]), np.ascontiguousarray(cv),
                            np.ascontiguousarray(fy), np.ascontiguousarray(v), eta['v_y'],
                            rho, ff, vf, eta['k_tm_s'], eta['c_tm_s'], TOP_MOUNT_MASS_FRACTION,
                            P.dt, MOUNT_SUB)
        out.append(q)
    q = np.concatenate(out)
    return q if np.all(np.isfinite(q)) else None


def mount_fit(P, parent, K, C, rows, start=None, iters=10, tol=5e-3):
    """Child ``parent + top_mount`` at ``(K, C)``: alternate the mount rate and theta.

    The first mount rate comes from ``start``'s theta (default: the parent's), then each
    fit's own, until the training error changes by less than ``tol`` (relative).
    """
    eta = {k: v for k, v in parent.eta.items() if k != 'tau_tm'}
    eta.update(k_tm_s=float(K), c_tm_s=float(C))
    effects = parent.effects + ('top_mount',)
    src = start if start is not None else parent
    fit, last = None, np.inf
    for _ in range(iters):
        q = mount_rates(P, src, eta)
        if q is None:
            return fit
        P.mount_q[_mount_key(eta)] = q
        with np.errstate(all='ignore'):  # a trial far from the mount can overflow: inf SSE
            f = evaluate(P, effects, eta, rows)
        f.mount_q = q
        e = float(f.cvr.train.sum())
        if not np.isfinite(e):
            return fit
        fit, src = f, f
        if abs(last - e) <= tol * e:
            break
        last = e
    return fit


def mount_search(P, parent, rows):
    """Fit ``top_mount`` on ``parent``: a linear screen, then the two-mass mount.

    The screen is the mount's linearisation (the damper force lagged by ``tau = c / k_tm``,
    a grid of ``tau``; linear in theta, cheap). Only when the screen passes the selection rule
    is the mount of the core fitted: ``K`` on a grid about ``K0 = c_eq / tau`` (``C`` = 1
    /s), ``K0`` from the parent, then outward, each point alternating mount rate and theta
    from its inner neighbour's solution, then
    Nelder-Mead in ``log K, log C`` on the training error. Fold k's held-out error is that of
    the grid point with the least training error of fold k, as in :func:`search`.
    """
    screen = _grid_search(P, parent, 'top_mount', rows)
    if not diagnose.accepted(screen.test, parent.test):
        return screen
    th = dict(zip(screen.names, screen.theta))
    K0 = _c_eq(P, th) / screen.eta['tau_tm']  # Maxwell: tau = c_eq / K
    first = mount_fit(P, parent, K0, 1.0, rows)
    fits = [] if first is None else [first]
    for side in ((2.0, 4.0), (0.5, 0.25)):  # outward from K0, each warm-started inward
        prev = first
        for m in side:
            f = mount_fit(P, parent, K0 * m, 1.0, rows, start=prev)
            if f is not None:
                fits.append(f)
                prev = f
    if not fits:
        return screen
    return mount_polish(P, _fold_picks(fits), parent, rows)


def mount_polish(P, fit, parent, rows):
    """Nelder-Mead on ``log K, log C`` (training error), keeping the grid's fold picks."""
    K0, C0 = fit.eta['k_tm_s'], fit.eta['c_tm_s']
    found = [fit, float(fit.cvr.train.sum())]

    def cost(z):
        if np.max(np.abs(z)) > 3.0:
            return np.inf
        f = mount_fit(P, parent, K0 * math.exp(z[0]), C0 * math.exp(z[1]), rows,
                      start=found[0])
        if f is None:
            return np.inf
        e = float(f.cvr.train.sum())
        if e < found[1]:
            found[:] = [f, e]
        return e

    optimize.minimize(cost, np.zeros(2), method='Nelder-Mead',
                      options={'initial_simplex': np.array([[0, 0], [0.3, 0], [0, 0.7]]),
                               'maxfev': 20, 'xatol': 0.02, 'fatol': 1e-4 * found[1]})
    best = found[0]
    if best is not fit:  # the fold picks stay the grid's (no held-out sample chose them)
        best.cvr = CV(fit.cvr.test, best.cvr.train, best.cvr.theta)
    P.mount_q[_mount_key(best.eta)] = best.mount_q  # a later trial may share the key
    return best


def mount_refresh(P, fit, rows=None):
    """Recompute the mount rate from ``fit``'s own theta (after other effects joined).

    With ``rows`` the new rate is kept only if it does not raise the training error there
    (the alternation may stop short of its fixed point; its last rate then fits better).
    """
    if 'top_mount' not in fit.effects:
        return fit
    q = mount_rates(P, fit)
    key = _mount_key(fit.eta)
    old = P.mount_q.get(key)
    if q is not None:
        P.mount_q[key] = q
        if rows is not None and old is not None:
            new = evaluate(P, fit.effects, fit.eta, rows)
            if not new.cvr.train.sum() <= fit.cvr.train.sum():
                P.mount_q[key] = old
    elif old is None:  # diverged (a law that feeds energy in): the body-wheel rate
        P.mount_q[key] = np.zeros(P.n)
    return fit


@dataclass
class CV:
    """Per-fold held-out and training SSE, and the all-inner-data solution."""

    test: np.ndarray
    train: np.ndarray
    theta: np.ndarray


def cv(X, y, fold, rows):
    """Blocked K-fold cross-validation of ``y ~ X theta`` on ``rows`` (inner folds only)."""
    if not np.all(np.isfinite(X[rows])):
        return CV(np.full(N_FOLDS, np.inf), np.full(N_FOLDS, np.inf), np.zeros(X.shape[1]))
    Xr, yr, fr = X[rows], y[rows], fold[rows]
    p = X.shape[1]
    gk, hk, ek = np.empty((N_FOLDS, p, p)), np.empty((N_FOLDS, p)), np.empty(N_FOLDS)
    for f in range(N_FOLDS):
        m = fr == f
        gk[f], hk[f], ek[f] = Xr[m].T @ Xr[m], Xr[m].T @ yr[m], yr[m] @ yr[m]
    gt, ht, et = gk.sum(0), hk.sum(0), ek.sum()
    test, train = np.empty(N_FOLDS), np.empty(N_FOLDS)
    for f in range(N_FOLDS):
        g, h, e = gt - gk[f], ht - hk[f], et - ek[f]
        th = engine.solve_normal(g, h)
        train[f] = e - 2 * th @ h + th @ g @ th
        test[f] = ek[f] - 2 * th @ hk[f] + th @ gk[f] @ th
    return CV(test, train, engine.solve_normal(gt, ht))


@dataclass
class Fit:
    """One model: effects, nonlinear ``eta``, linear ``theta`` (acceleration units), CV."""

    effects: tuple
    eta: dict
    theta: np.ndarray
    names: list
    cvr: CV
    mount_q: np.ndarray = field(default=None, repr=False)  # the mount rate it was fitted on

    @property
    def test(self):
        """Per-fold held-out SSE."""
        return self.cvr.test


def evaluate(P, effects, eta, rows):
    """Cross-validate one model at fixed ``eta``."""
    X, names = columns(P, effects, eta)
    r = cv(X, P.y_all - P.known, P.fold, rows)
    return Fit(tuple(effects), dict(eta), r.theta, names, r)


def search(P, parent, effect, rows, grid=None):
    """Child ``parent + effect``: :func:`mount_search` or :func:`_grid_search`."""
    if effect == 'top_mount':
        return mount_search(P, parent, rows)
    return _grid_search(P, parent, effect, rows, grid)


def _grid_search(P, parent, effect, rows, grid=None):
    """Child ``parent + effect``: grid over its nonlinear parameters, parent's ``eta`` kept.

    Fold ``k``'s held-out error is that of the grid point with the least *training* error
    of fold ``k`` (no held-out sample chooses its own prediction); the child's ``eta`` is the
    point with the least training error over all inner folds.
    """
    effects = parent.effects + (effect,)
    g = (grid or P.grids()).get(effect, {})
    keys = list(g)
    pts = list(itertools.product(*[g[k] for k in keys])) or [()]
    fits = []
    for pt in pts:
        eta = dict(parent.eta, **dict(zip(keys, (float(v) for v in pt))))
        fits.append(evaluate(P, effects, eta, rows))
    return _fold_picks(fits)


def _fold_picks(fits):
    """Best of ``fits`` (training error) with fold k's held-out error from fold k's own pick."""
    train = np.array([f.cvr.train for f in fits])
    test = np.array([f.cvr.test for f in fits])
    pick = np.argmin(train, axis=0)
    best = fits[int(np.argmin(train.sum(1)))]
    best.cvr = CV(test[pick, np.arange(N_FOLDS)], train[pick, np.arange(N_FOLDS)],
                  best.cvr.theta)
    return best


def refine(P, fit, rows, names=('v_y',)):
    """One coordinate sweep of ``v_y`` (and given parameters) around the fit's values."""
    for key in names:
        if key not in fit.eta:
            continue
        v0 = fit.eta[key]
        if key == 'rho':
            cand = v0 + np.linspace(-0.05, 0.05, 5)
        elif key == 'imu_timing':
            cand = v0 + np.linspace(-1.5e-3, 1.5e-3, 7)
        else:
            cand = v0 * np.geomspace(0.5, 2.0, 9)
        best, err = fit, fit.cvr.train.sum()
        for c in cand:
            f = evaluate(P, fit.effects, dict(fit.eta, **{key: float(c)}), rows)
            if f.cvr.train.sum() < err:
                best, err = f, f.cvr.train.sum()
        fit = best
    return fit


FIXED_ETA = ('chain', 'k_tm_s', 'c_tm_s')  # not polished here (the mount has its own search)
LINEAR_ETA = {'rho': 0.05, 'imu_timing': 5e-4}  # searched on a linear scale (step), others log


def polish(P, fit, rows):
    """Polish all nonlinear parameters of ``fit`` jointly.

    Variable projection (``theta`` by least squares inside): Nelder-Mead on the training error
    of ``rows``, log scale for the positive time constants and levels (sign kept), linear for
    ``rho`` and the IMU timing. Ends the
    coordinate sweeps of :func:`refine`, which leave a shape mismatch (a truth's stop or
    saturation that is not the catalogue's) half fitted.
    """
    keys = [k for k in fit.eta if k not in FIXED_ETA]
    if not keys:
        return fit
    sign = {k: math.copysign(1.0, fit.eta[k]) for k in keys}
    best = [fit, float(fit.cvr.train.sum())]

    def eta_of(z):
        eta = dict(fit.eta)
        for k, v in zip(keys, z):
            eta[k] = float(fit.eta[k] + v * LINEAR_ETA[k]) if k in LINEAR_ETA \
                else float(sign[k] * abs(fit.eta[k]) * math.exp(v))
        return eta

    def cost(z):
        if np.max(np.abs(z)) > 4.0:  # beyond e^4 (or 4 steps): outside any grid, refuse
            return np.inf
        f = evaluate(P, fit.effects, eta_of(z), rows)
        e = float(f.cvr.train.sum())
        if e < best[1]:
            best[:] = [f, e]
        return e

    d = len(keys)
    simplex = np.vstack([np.zeros(d), 0.3 * np.eye(d)])
    optimize.minimize(cost, np.zeros(d), method='Nelder-Mead',
                      options={'initial_simplex': simplex, 'maxfev': 25 * (d + 1),
                               'xatol': 0.01, 'fatol': 1e-5 * best[1]})
    return best[0]


def predict(P, fit, rows=None):
    """Predicted body acceleration (gravity removed) at every sample."""
    X, _ = columns(P, fit.effects, fit.eta)
    return X @ fit.theta + P.known


# -- the road path: sprung mass and tyre from the wheel equation -----------------------------

def _road_filters(dt, f_hp=ROAD_HP):
    """Causal ``H(s)`` (4th-order Butterworth high-pass) and ``H(s)/s^2`` as bilinear SOS."""
    z, p, k = signal.butter(4, 2 * np.pi * f_hp, 'high', analog=True, output='zpk')
    fs = 1.0 / dt
    sos_h = signal.zpk2sos(*signal.bilinear_zpk(z, p, k, fs))
    sos_i = signal.zpk2sos(*signal.bilinear_zpk(z[:-2], p, k, fs))
    return sos_h, sos_i


def wheel_equation(P):
    """Target and regressors of ``m_u a_u + m_s a_s = k_t delta + c_t delta' + b``.

    Both sides go through the same causal high-pass ``H``; the wheel displacement is
    ``H/s^2`` of its acceleration, so the relation stays exact without a drifting integral.
    """
    ys, xs = [], []
    mu = P.nominal.vehicle.m_u
    for k, r in enumerate(P.records):
        sh, si = _road_filters(r.dt)
        au = r.wheel_acc - np.mean(r.wheel_acc)
        a_s = r.body_acc - np.mean(r.body_acc)
        delta = signal.sosfilt(sh, r.road - r.road[0]) - signal.sosfilt(si, au)
        ys.append(mu * signal.sosfilt(sh, au))
        xs.append(np.column_stack([np.ones(r.n), -signal.sosfilt(sh, a_s), delta,
                                   np.gradient(delta, r.dt)]))
    return np.concatenate(ys), np.concatenate(xs)


def road_fits(P):
    """Baseline (m_s nominal) and ``sprung_mass`` (m_s free) wheel-equation fits."""
    yw, Xw = wheel_equation(P)
    ms0 = P.nominal.vehicle.m_s
    base = cv(Xw[:, [0, 2, 3]], yw - ms0 * Xw[:, 1], P.fold, P.full_rows)
    free = cv(Xw, yw, P.fold, P.full_rows)
    out = {'base': base, 'free': free, 'm_s': float(free.theta[1]),
           'k_t_base': float(base.theta[1]), 'k_t': float(free.theta[2]),
           'c_t': float(free.theta[3])}
    for key, r, X, y in (('base', base, Xw[:, [0, 2, 3]], yw - ms0 * Xw[:, 1]),
                         ('free', free, Xw, yw)):
        e = y[P.outer] - X[P.outer] @ r.theta
        out[f'{key}_outer_nrmse'] = float(np.sqrt(np.mean(e ** 2)) / np.std(yw[P.outer]))
    return out


@njit(cache=True, nogil=True)
def _corner_kernel(p, zr, zrd, i_f, dt, nsub):
    """Quarter car with the fitted strut force, from the road; per sample (a_s, x, F_t dyn).

    ``p``: m_s, m_u, k_t, c_t, k_s, c0, c1, fy0, fy1, v_y, f_fric, v_fric (< 0: Dahl with
    x_pre = -v_fric), k_s3, k_bs, x_bs, tau_tm (0: none), rho, i_sat (0: none). Semi-implicit
    Euler on ``nsub`` substeps; Dahl stepped exactly; the top mount lags the damper force.
    """
    n = zr.size
    out = np.empty((n, 3))
    zs = zu = vs = vu = zf = ftm = 0.0
    h = dt / nsub
    ms, mu, kt, ct, ks = p[0], p[1], p[2], p[3], p[4]
    a_s = ft = x = 0.0
    for k in range(n):
        i = i_f[k]
        iy = p[17] * math.tanh(i / p[17]) if p[17] > 0.0 else i
        for _ in range(nsub):
            x = zs - zu
            v = vs - vu
            tv = math.tanh(v / p[9])
            fd = ((p[5] + p[6] * iy) * v + (p[7] + p[8] * iy) * tv) * (1.0 + p[16] * tv)
            if p[11] > 0.0:
                fd += p[10] * math.tanh(v / p[11])
            elif p[11] < 0.0:
                dx = v * h
                if dx != 0.0:
                    sg = 1.0 if dx > 0.0 else -1.0
                    zf = sg + (zf - sg) * math.exp(-abs(dx) / -p[11])
                fd += p[10] * zf
            if p[15] > 0.0:
                ftm += (1.0 - math.exp(-h / p[15])) * (fd - ftm)
                fd = ftm
            fs = ks * x + p[12] * x * x * x
            if p[13] > 0.0 and abs(x) > p[14]:
                fs += p[13] * (abs(x) - p[14]) ** 2 * (1.0 if x > 0.0 else -1.0)
            s_f = -(fs + fd)
            ft = kt * (zr[k] - zu) + ct * (zrd[k] - vu)
            a_s = s_f / ms
            vs += h * a_s
            vu += h * (ft - s_f) / mu
            zs += h * vs
            zu += h * vu
        out[k, 0] = a_s
        out[k, 1] = zs - zu
        out[k, 2] = ft
    return out


def _c_eq(P, th):
    """Equivalent damping (per unit m_s) at the mean current and a typical rate."""
    u = float(np.mean(np.concatenate(P.u)))
    return max(th['c0'] + th['c1'] * u + (th['fy0'] + th['fy1'] * u) / max(P.v_scale, 1e-3),
               1e-3)


def simulate_corner(P, fit, road, m_s):
    """Simulate the fitted corner from each record's road; returns per-record outputs."""
    th = dict(zip(fit.names, fit.theta))
    e, eta = fit.effects, fit.eta
    p = np.zeros(18)
    p[0], p[1], p[2], p[3] = m_s, P.nominal.vehicle.m_u, road['k_t'], max(road['c_t'], 0.0)
    p[4] = th['k_s'] * m_s
    p[5], p[6], p[7], p[8] = (th[k] * m_s for k in ('c0', 'c1', 'fy0', 'fy1'))
    p[9] = eta['v_y']
    if 'strut_friction' in e:
        p[10], p[11] = th['f_fric'] * m_s, eta['v_fric']
    if 'spring_nonlinearity' in e:
        p[12] = th['k_s3'] * m_s
    if 'bump_stop' in e:
        p[13], p[14] = th['k_bs'] * m_s, eta['x_bs']
    if 'top_mount' in e:  # the road path lags the damper force by c_eq / k_tm instead
        p[15] = _c_eq(P, th) / eta['k_tm_s']
    if 'direction_asymmetry' in e:
        p[16] = eta['rho']
    if 'current_saturation' in e:
        p[17] = eta['i_sat']
    outs = []
    for k, r in enumerate(P.records):
        i_f = _field(P.u[k], P.dt, e, eta)
        zr = r.road - r.road[0]
        outs.append(_corner_kernel(p, zr, np.gradient(zr, r.dt), i_f, r.dt, 20))
    return outs


def corner_heldout(P, fits, road):
    """Full-corner simulation from the road, scored on the outer blocks (rig data).

    Stroke and body acceleration NRMSE against the measured ones, and the RMS of the dynamic
    tyre load, measured as ``m_s a_s + m_u a_u`` (both IMUs) against the simulated one.
    """
    out = {}
    o = P.outer
    meas_x = np.concatenate([r.stroke - r.stroke.mean() for r in P.records])
    for label, fit, m_s in fits:
        sims = simulate_corner(P, fit, road, m_s)
        a = np.concatenate([s[:, 0] for s in sims])
        x = np.concatenate([s[:, 1] for s in sims])
        ft = np.concatenate([s[:, 2] for s in sims])
        # measured with the best-known sprung mass (the extended fit's), for every model
        meas_ft = fits[-1][2] * P.y_all + P.nominal.vehicle.m_u * np.concatenate(P.au)
        x = x - x[o].mean()
        out[label] = {
            'stroke_nrmse': float(np.sqrt(np.mean((x[o] - meas_x[o]) ** 2)) / np.std(meas_x[o])),
            'body_acc_nrmse': float(np.sqrt(np.mean((a[o] - P.y_all[o]) ** 2))
                                    / np.std(P.y_all[o])),
            'tyre_load_rms': float(np.std(ft[o])), 'tyre_load_rms_measured':
                float(np.std(meas_ft[o])),
            'working_space_rms': float(np.std(x[o])),
            'working_space_rms_measured': float(np.std(meas_x[o]))}
    return out


# -- checks, floor, testability ---------------------------------------------------------------

def accel_offset(P):
    """Mean specific force minus g over the record: bias (or a scale error of g)."""
    out = []
    for r in P.records:
        raw = r.body_acc[r.mask]
        nb = 24
        means = np.array([b.mean() for b in np.array_split(raw, nb)])
        bias = float(raw.mean())
        se = float(np.std(means, ddof=1) / math.sqrt(nb))
        if abs(bias) > max(BIAS_MIN, 3 * se):
            out.append({'finding': 'accelerometer_bias', 'location': 'sensor',
                        'channel': 'body_acc', 'action': 'corrected', 'record': r.name,
                        'detail': f'body IMU reads {G + bias:.3f} m/s^2 on average (g = {G}): '
                                  f'offset {bias:+.3f} m/s^2 (or a scale error of '
                                  f'{100 * bias / G:+.1f} %; a flip test separates them); '
                                  'removed', 'bias': bias, 'standard_error': se})
    return out


def noise_floor(P, fit):
    """Noise floor (NRMSE) from the data: body-IMU noise and the stroke noise through the model.

    Both sensors' white levels come from their spectra above 0.3 fs. The IMU's counts over the
    fitted band; the stroke's is propagated by adding white noise of that level to the stroke,
    deriving the rate again and taking the RMS change of the fitted model's prediction
    (the steep yield branch multiplies stroke-rate noise by ``fy / v_y``).
    """
    rng = np.random.default_rng(0)
    acc2, inp2, var = 0.0, 0.0, 0.0
    for k, r in enumerate(P.records):
        fs = 1.0 / r.dt
        nper = min(r.n // 4, int(2 * fs))
        f, p = signal.welch(r.body_acc, fs, nperseg=nper)
        acc2 += float(np.median(p[f >= 0.3 * fs])) * min(r.cutoff, 0.5 * fs) * r.n
        sx = math.sqrt(vehicle_data._white(r.stroke, r.dt) * 0.5 * fs)
        a_rel = r.body_acc - r.wheel_acc
        sa = math.sqrt(vehicle_data._white(a_rel, r.dt) * 0.5 * fs)
        var += float(np.var(P.y[k])) * r.n
        if sx > 0:
            xn = r.stroke + sx * rng.standard_normal(r.n)
            an = a_rel + sa * rng.standard_normal(r.n)
            if r.crossover is None:
                vn = np.gradient(sensors.lowpass(xn, r.dt, r.cutoff, order=4), r.dt)
            else:
                xn, vn = vehicle_data.fuse(xn, an, r.dt, r.crossover, r.cutoff, r.stroke_tau)
            Q = _Swapped(P, k, xn, vn)
            d = columns(Q, fit.effects, fit.eta)[0] @ fit.theta \
                - columns(Q.orig, fit.effects, fit.eta)[0] @ fit.theta
            inp2 += float(np.mean(d ** 2)) * r.n
    if var <= 0:
        return {'nrmse': None}
    return {'nrmse': math.sqrt((acc2 + inp2) / var), 'imu_nrmse': math.sqrt(acc2 / var),
            'stroke_nrmse': math.sqrt(inp2 / var),
            'method': 'white levels above 0.3 fs: body IMU over the fitted band, stroke noise '
                      'propagated through the fitted model'}


class _Swapped:
    """One record of ``P`` with its stroke and rate replaced (for the noise propagation)."""

    def __init__(self, P, k, x, v):
        sl = P.slices[k]
        self.orig = _Swapped.__new__(_Swapped)
        for obj, xx, vv in ((self, x, v), (self.orig, P.x[k], P.v[k])):
            obj.x, obj.v, obj.t, obj.u = [xx], [vv], [P.t[k]], [P.u[k]]
            obj.slices, obj.dt = [slice(0, sl.stop - sl.start)], P.dt
            obj.mount_q = {key: q[sl] for key, q in P.mount_q.items()}


def testability(P):
    """Effects the data cannot test, with the manoeuvre that would make them testable."""
    out = {}
    u = np.concatenate(P.u)
    span = float(np.percentile(u, 99) - np.percentile(u, 1))
    if span < 0.05:
        for e in CURRENT_EFFECTS + ('current_saturation',):
            out[e] = 'the current hardly changes'
    else:
        du = np.diff(u[::max(1, int(round(0.02 / P.dt)))])  # 20 ms: a lagged current's edge
        rise, fall = du > 0.2 * span, du < -0.2 * span
        up = int(np.sum(rise[1:] & ~rise[:-1]) + rise[0])
        dn = int(np.sum(fall[1:] & ~fall[:-1]) + fall[0])
        if min(up, dn) < EDGES_MIN:
            for e in CURRENT_EFFECTS:
                out[e] = f'{up} current steps up and {dn} down (need {EDGES_MIN} each way)'
        levels = np.unique(np.round(u / (0.1 * span)))
        if levels.size < 3:
            out['current_saturation'] = 'fewer than three current levels'
    if not P.road:
        out['sprung_mass'] = 'no road: the strut force scale and the sprung mass are one product'
    if float(np.percentile(P.x_abs, 99.5)) < 0.01:
        out['bump_stop'] = 'strokes below 1 cm'
        out['spring_nonlinearity'] = 'strokes below 1 cm'
    return {e: {'why': why, 'how': UNTESTABLE_HOW.get(e, '')} for e, why in out.items()}


# -- selection ---------------------------------------------------------------------------------

# Coefficients whose sign the physics fixes: a friction or a stop with a negative coefficient
# feeds energy in; such a child only fits another effect's leftovers (seen next to a soft
# top mount: f_fric = -40 to -80 N).
PHYSICAL_SIGN = {'strut_friction': 'f_fric', 'bump_stop': 'k_bs'}


def physical(fit, effect):
    """Whether ``effect``'s sign-fixed coefficient in ``fit`` is positive (dissipative)."""
    name = PHYSICAL_SIGN.get(effect)
    if name is None or name not in fit.names:
        return True
    return float(fit.theta[fit.names.index(name)]) > 0.0


CURRENT_TIMES = {'current_delay': ('dead_time',), 'current_lag': ('tau',),
                 'current_lag_asymmetric': ('tau_rise', 'tau_fall')}


def resolved(fit, effect, dt):
    """Whether ``effect``'s time constants in ``fit`` reach one sample step ``dt``.

    A current delay or lag shorter than a sample moves the field current by less than the
    sampling itself (the current is known only at the samples): not a finding at that rate.
    """
    names = CURRENT_TIMES.get(effect)
    if names is None:
        return True
    return max(abs(fit.eta[n]) for n in names) >= dt * (1.0 - 1e-9)


def _without(P, fit, e, rows):
    effects = tuple(x for x in fit.effects if x != e)
    return evaluate(P, effects, fit.eta, rows)


@dataclass
class VehicleResult:
    """Result of one corner: causes, verdict, fits, figures and the fitted corner."""

    verdict: str
    causes: list
    sensor: list
    ambiguous: list
    untestable: dict
    base: Fit
    final: Fit
    steps: list
    heldout: dict
    noise: dict
    road: dict
    corner: dict
    findings: list
    notes: dict = field(default_factory=dict)


def _step(effect, child, parent, stage):
    pooled, t, _ = diagnose.fold_stats(child.test, parent.test)
    return {'stage': stage, 'effect': effect, 'gain_mse': round(pooled, 4), 't': round(t, 2),
            'accepted': bool(diagnose.accepted(child.test, parent.test)),
            'eta': {k: v for k, v in child.eta.items() if k != 'chain'}}


@dataclass(frozen=True)
class _CarContext:
    """What every stage of the car's selection reads: the prepared data and the candidates."""

    P: object
    effects: tuple
    untestable: dict
    tick: object

    @property
    def rows(self):
        """The rows the selection fits on (the search rate)."""
        return self.P.search_rows


def _car_baseline(s, c):
    """Fit the nominal corner (its baseline terms refined)."""
    P, rows = c.P, c.rows
    base = refine(P, evaluate(P, (), base_eta(P.nominal, P.coil), rows), rows)
    c.tick('baseline')
    return replace(s, base=base, final=base)


def _car_sensors(s, c):
    """Judge the IMU timing first, like the rig's fine timing (fold t >= T_FINE)."""
    P, rows = c.P, c.rows
    parent, steps = s.final, list(s.steps)
    for e in SENSOR_EFFECTS:
        if e in c.effects:
            child = search(P, parent, e, rows)
            steps.append(_step(e, child, parent, 'sensor'))
            c.tick(e)
            size = float(np.std(predict(P, child)[rows] - predict(P, parent)[rows]))
            steps[-1]['contribution_over_noise'] = size / P.imu_noise
            # Not judged by materiality: a half-sample offset is small per sample yet
            # everywhere. At the grid's edge (2 ms) it is a physical lag (top mount, current),
            # not timing.
            edge = abs(child.eta.get(e, 0.0)) >= 0.002 - 1e-9
            if steps[-1]['accepted'] and steps[-1]['t'] >= diagnose.T_FINE and not edge:
                parent = child
            else:
                steps[-1]['accepted'] = False
    return replace(s, final=parent, steps=tuple(steps))


def _car_forward(s, c):
    """Forward selection up to MAX_CAUSES physical causes (physical, resolved, material)."""
    P, rows, effects = c.P, c.rows, c.effects
    parent, steps, ambiguous = s.final, list(s.steps), list(s.ambiguous)
    while len([e for e in parent.effects if e in PHYSICS]) < MAX_CAUSES:
        cands = [e for e in PHYSICS if e in effects and e not in parent.effects
                 and e not in c.untestable and diagnose.compatible(parent.effects, e, EXCLUSIVE)]
        if not cands:
            break
        kids = {}
        for e in cands:
            kids[e] = search(P, parent, e, rows)
            steps.append(_step(e, kids[e], parent, f'forward {len(parent.effects)}'))
            c.tick(e)
        acc = [e for e in cands if diagnose.accepted(kids[e].test, parent.test)]
        for e in [e for e in acc if not physical(kids[e], e)]:
            acc.remove(e)
            steps.append({'stage': 'physical', 'effect': e, 'gain_mse': 0.0, 't': 0.0,
                          'accepted': False, 'why': f'{PHYSICAL_SIGN[e]} < 0 feeds energy in'})
        for e in [e for e in acc if not resolved(kids[e], e, P.dt)]:
            acc.remove(e)
            steps.append({'stage': 'resolution', 'effect': e, 'gain_mse': 0.0, 't': 0.0,
                          'accepted': False, 'why': 'time constants below one sample'})
        pred_parent = predict(P, parent)[rows]
        contrib = {}
        strong = {}
        for e in acc:
            contrib[e] = float(np.std(predict(P, kids[e])[rows] - pred_parent))
            gain = diagnose.fold_stats(kids[e].test, parent.test)[0]
            strong[e] = contrib[e] >= MATERIAL * P.imu_noise or gain >= G_STRONG
            steps.append({'stage': 'materiality', 'effect': e, 'gain_mse': round(gain, 4),
                          't': 0.0, 'accepted': bool(strong[e]),
                          'contribution_over_noise': contrib[e] / P.imu_noise})
        acc = [e for e in acc if strong[e]]
        if not acc:
            break
        acc.sort(key=lambda e: kids[e].test.sum())
        best = acc[0]
        cb = predict(P, kids[best])[rows] - pred_parent
        for other in acc[1:]:
            co = predict(P, kids[other])[rows] - pred_parent
            if abs(diagnose.corr(cb, co)) >= diagnose.CORR_AMBIG and not diagnose.accepted(
                    kids[best].test, kids[other].test):
                ambiguous.append((best, other))
        parent = refine(P, kids[best], rows, ('v_y',))
        parent.cvr = evaluate(P, parent.effects, parent.eta, rows).cvr
    return replace(s, final=parent, steps=tuple(steps), ambiguous=ambiguous)


def _car_backward(s, c):
    """Drop a cause whose removal the rule does not reject, or that turned unphysical."""
    P, rows = c.P, c.rows
    parent, steps = s.final, list(s.steps)
    changed = True
    while changed and parent.effects:
        changed = False
        for e in parent.effects:
            red = _without(P, parent, e, rows)
            ok = diagnose.accepted(parent.test, red.test) and physical(parent, e)
            steps.append(dict(_step(e, parent, red, 'backward'), kept=bool(ok)))
            if not ok:
                parent = red
                changed = True
                break
    return replace(s, final=parent, steps=tuple(steps))


def _car_nested_lag(s, c):
    """Name the asymmetric lag only where it pays over the symmetric one (either way round)."""
    P, rows, effects = c.P, c.rows, c.effects
    parent, steps = s.final, list(s.steps)
    if 'current_lag' in parent.effects and 'current_lag_asymmetric' in effects:
        red = _without(P, parent, 'current_lag', rows)
        up = search(P, red, 'current_lag_asymmetric', rows)
        steps.append(_step('current_lag->current_lag_asymmetric', up, parent, 'upgrade'))
        if diagnose.accepted(up.test, parent.test) and resolved(up, 'current_lag_asymmetric',
                                                                P.dt):
            parent = up
    elif 'current_lag_asymmetric' in parent.effects and 'current_lag' in effects:
        red = _without(P, parent, 'current_lag_asymmetric', rows)
        down = search(P, red, 'current_lag', rows)
        steps.append(_step('current_lag_asymmetric->current_lag', parent, down, 'nested'))
        if not diagnose.accepted(parent.test, down.test) and resolved(down, 'current_lag',
                                                                      P.dt):
            parent = down
    return replace(s, final=parent, steps=tuple(steps))


def _car_polish(s, c):
    """Polish every nonlinear parameter (a coordinate sweep, then a joint Nelder-Mead)."""
    P, rows, parent = c.P, c.rows, s.final
    keys = [k for k in parent.eta if k not in FIXED_ETA]
    parent = refine(P, parent, P.full_rows, ['v_y'] + [k for k in keys if k != 'v_y'])
    parent = polish(P, parent, P.full_rows)
    mount_refresh(P, parent, P.full_rows)
    parent.cvr = evaluate(P, parent.effects, parent.eta, rows).cvr
    ambiguous = [p for p in s.ambiguous if p[0] in parent.effects]
    return replace(s, final=parent, ambiguous=ambiguous)


# The car's selection, stage by stage over the rig's state (``diagnose.Selection``).
CAR_STAGES = (_car_baseline, _car_sensors, _car_forward, _car_backward, _car_nested_lag,
              _car_polish)


def select(P, effects, untestable, progress=None):
    """Forward selection with backward check on the inner folds (the rig's rule).

    Runs :data:`CAR_STAGES` over a ``diagnose.Selection``; returns ``(baseline, final fit,
    steps, ambiguous pairs)``.
    """
    c = _CarContext(P, tuple(effects), untestable, progress or (lambda label: None))
    s = diagnose.Selection(ds=P)
    for stage in CAR_STAGES:
        s = stage(s, c)
    return s.base, s.final, list(s.steps), list(s.ambiguous)


def baseline_aliases(P, final, effects, rows):
    """Pairs ``(effect, baseline term)`` that draw one signal, the term moved off nominal.

    A catalogue effect that is not named may still be in the data, held by a baseline term
    the fit refits: strut friction ``f_fric tanh(v / v_fric)`` is the current-free yield
    force ``fy0 tanh(v / v_y)`` when ``v_fric`` is near ``v_y``. For every effect not named
    (and testable), its best child of ``final`` gives its regressor; where that regressor
    correlates with a baseline term's by ``diagnose.CORR_AMBIG`` or more on the inner rows
    and that term's refitted value lies more than ``ALIAS_SHIFT`` from its nominal, the
    data cannot say which of the two moved: the pair is ambiguous.
    """
    th = dict(zip(final.names, final.theta))
    m_s = P.nominal.vehicle.m_s
    c0, _, fy0, _, _ = P.nominal.damper_coeffs()
    nominal = {'c0': c0, 'fy0': fy0, 'k_s': P.nominal.vehicle.k_s}
    moved = [t for t in BASELINE_TERMS if t in th and nominal[t]
             and abs(th[t] * m_s / nominal[t] - 1.0) > ALIAS_SHIFT]
    out = []
    if not moved:
        return out
    for e in effects:
        if e in final.effects or e not in PHYSICS:
            continue
        kid = search(P, final, e, rows)
        x, names = columns(P, kid.effects, kid.eta)
        own = [k for k, n in enumerate(names) if n not in final.names]
        if len(own) != 1:
            continue
        col = x[rows, own[0]]
        for t in moved:
            r = diagnose.corr(col, x[rows, names.index(t)])
            if abs(r) >= diagnose.CORR_AMBIG:
                out.append((e, t))
    return out


def _drop_losses(P, final, rows):
    out = {}
    for e in final.effects:
        red = _without(P, final, e, rows)
        out[e] = float(red.test.sum() / final.test.sum() - 1.0)
    return out


def outer_nrmse(P, fit):
    """Refit ``theta`` on all inner rows at full rate, score on the outer blocks."""
    X, _ = columns(P, fit.effects, fit.eta)
    r = cv(X, P.y_all - P.known, P.fold, P.full_rows)
    fit = replace(fit, theta=r.theta, cvr=r)
    pred = X @ fit.theta + P.known
    e = P.y_all - pred
    o = P.outer
    return fit, float(np.sqrt(np.mean(e[o] ** 2)) / np.std(P.y_all[o])), pred


def ride_metrics(P, a_pred):
    """Wk-weighted RMS of measured and predicted body acceleration on the outer blocks."""
    from mr_suspension.core.metrics import wk_filter
    out = {}
    meas_w, pred_w = [], []
    for k, sl in enumerate(P.slices):
        meas_w.append(wk_filter(P.y[k], P.dt))
        pred_w.append(wk_filter(a_pred[sl], P.dt))
    mw, pw = np.concatenate(meas_w)[P.outer], np.concatenate(pred_w)[P.outer]
    out['wk_rms_measured'] = float(np.sqrt(np.mean(mw ** 2)))
    out['wk_rms_predicted'] = float(np.sqrt(np.mean(pw ** 2)))
    out['wk_rms_error_pct'] = 100.0 * (out['wk_rms_predicted'] / out['wk_rms_measured'] - 1.0)
    x = np.concatenate(P.x)[P.outer]
    out['working_space_rms_measured'] = float(np.sqrt(np.mean((x - x.mean()) ** 2)))
    return out


def corner_params(P, final, road):
    """Fitted corner in SI units: vehicle, damper, driver fields and what cannot be written."""
    th = dict(zip(final.names, final.theta))
    veh = P.nominal.vehicle
    m_s = road['m_s'] if road and 'sprung_mass' in final.effects else veh.m_s
    c = {'m_s': m_s, 'k_s': th['k_s'] * m_s}
    if road:
        c['k_t'] = road['k_t']
    c['c0'], c['c1'] = th['c0'] * m_s, th['c1'] * m_s
    c['fy0'], c['fy1'] = th['fy0'] * m_s, th['fy1'] * m_s
    c['v_y'] = final.eta['v_y']
    e = final.effects
    if 'strut_friction' in e:
        c['f_fric'], c['v_fric'] = th['f_fric'] * m_s, final.eta['v_fric']
        if c['v_fric'] < 0:  # Dahl: the tanh law's v_fric at the data's stroke frequency
            x_all, v_all = np.concatenate(P.x), np.concatenate(P.v)
            c['friction_shape'], c['x_pre'] = 'dahl', -c['v_fric']
            c['v_fric'] = c['x_pre'] * float(np.std(v_all) / max(np.std(x_all), 1e-9))
        else:
            c['friction_shape'] = 'tanh'
    if 'bump_stop' in e:
        c['k_bs'], c['x_bs'] = th['k_bs'] * m_s, final.eta['x_bs']
    if 'spring_nonlinearity' in e:
        c['k_s3'] = th['k_s3'] * m_s
    if 'top_mount' in e:
        c['k_tm'], c['c_tm'] = final.eta['k_tm_s'] * m_s, final.eta['c_tm_s'] * m_s
        c['mount_mass_fraction'] = TOP_MOUNT_MASS_FRACTION
    if 'current_saturation' in e:
        c['i_sat'] = final.eta['i_sat']
    if 'direction_asymmetry' in e:
        c['rho'] = final.eta['rho']
    if 'imu_timing' in e:
        c['imu_timing'] = final.eta['imu_timing']
    dead, tr, tf, ftr, ftf = final.eta['chain']
    if P.coil:  # the driver's own dynamics are the nominal's or those fitted command -> coil
        dr = P.nominal.driver
        dead, tr, tf = P.driver_fit if P.driver_fit else (dr.dead_time, dr.tau_rise,
                                                          dr.tau_fall)
    if 'current_delay' in e:
        dead += final.eta['dead_time']
    # An extra series lag is lumped into the fluid stage (time constants add: same delay).
    if 'current_lag' in e:
        ftr, ftf = ftr + final.eta['tau'], ftf + final.eta['tau']
    if 'current_lag_asymmetric' in e:
        ftr, ftf = ftr + final.eta['tau_rise'], ftf + final.eta['tau_fall']
    c['chain'] = {'dead_time': dead, 'tau_rise': tr, 'tau_fall': tf, 'fluid_tau_rise': ftr,
                  'fluid_tau_fall': ftf, 'input': 'coil_current' if P.coil else 'command'}
    return c


def run(records, nominal=None, effects=ALL_EFFECTS, progress=None, prepared=None):
    """Diagnose a corner from its records (or from ``prepared`` data with a coupling).

    Returns ``(VehicleResult, Prepared, predictions)``: the typed result, the prepared
    data it was fitted on and the outer-block predictions of baseline and extended model.
    """
    bad = [e for e in effects if e not in ALL_EFFECTS]
    if bad:
        raise DataError(f'unknown effect(s) {bad}; known: {", ".join(ALL_EFFECTS)}')
    if prepared is None:
        P = Prepared(records, nominal or Nominal.load())
    else:
        P = prepared
    records, nominal = P.records, P.nominal
    findings = [f for r in records for f in r.findings] + accel_offset(P)
    untestable = testability(P)
    untestable = {e: v for e, v in untestable.items() if e in effects}
    P.driver_fit = None
    driver_causes, driver_steps = [], []
    if P.coil:
        driver_causes, driver_steps, P.driver_fit = driver_check(P)
        driver_causes = [e for e in driver_causes if e in effects]
    base, final, steps, ambiguous = select(P, effects, untestable, progress)
    steps = driver_steps + steps
    full = P.full_rows
    drop = _drop_losses(P, evaluate(P, final.effects, final.eta, full), full)
    base_o, base_n, base_pred = outer_nrmse(P, base)
    final_o, fin_n, fin_pred = outer_nrmse(P, final)
    noise = noise_floor(P, final_o)
    road = None
    causes = sorted([e for e in final.effects if e in PHYSICS], key=lambda e: -drop.get(e, 0))
    causes += [e for e in driver_causes if e not in causes]
    sensor = [e for e in final.effects if e in SENSOR_EFFECTS]
    if P.road and 'sprung_mass' in effects:
        road = road_fits(P)
        if road['free_outer_nrmse'] > ROAD_CLOSE or road['m_s'] <= 0:
            untestable['sprung_mass'] = {
                'why': f'the wheel equation does not close (held-out NRMSE '
                       f'{road["free_outer_nrmse"]:.2f} > {ROAD_CLOSE}): wheel IMU, road and '
                       'stroke misaligned or the tyre not linear', 'how': UNTESTABLE_HOW[
                           'sprung_mass']}
            road = None
    if road is not None:
        ms_change = road['m_s'] / nominal.vehicle.m_s - 1.0
        ok = diagnose.accepted(road['free'].test, road['base'].test) \
            and abs(ms_change) >= MASS_MIN
        pooled, t, _ = diagnose.fold_stats(road['free'].test, road['base'].test)
        steps.append({'stage': 'wheel equation', 'effect': 'sprung_mass',
                      'gain_mse': round(pooled, 4), 't': round(t, 2), 'accepted': bool(ok),
                      'm_s_change': ms_change})
        if ok:
            causes.insert(0, 'sprung_mass') if pooled > max(drop.values(), default=0) \
                else causes.append('sprung_mass')
            final_o = replace(final_o, effects=final_o.effects + ('sprung_mass',))
            drop['sprung_mass'] = float(pooled / max(1e-12, 1 - pooled))
    if road is not None:
        m_fit = road['m_s'] if 'sprung_mass' in causes else nominal.vehicle.m_s
        heldout_corner = corner_heldout(P, [('baseline', base_o, nominal.vehicle.m_s),
                                            ('extended', final_o, m_fit)], road)
    else:
        heldout_corner = None
    untested = [e for e in effects if e not in untestable]
    ambiguous = list(ambiguous) + baseline_aliases(P, final, untested, P.search_rows)
    verdict = 'ambiguous' if ambiguous else ('none' if not causes else 'named')
    floor = noise['nrmse']
    heldout = {'source': 'outer blocks (untouched by fit and selection)',
               'baseline_nrmse': base_n, 'extended_nrmse': fin_n,
               'gain': 1.0 - (fin_n / base_n) ** 2 if base_n > 0 else 0.0,
               'extended_over_floor': fin_n / floor if floor else None,
               'baseline_ride': ride_metrics(P, base_pred),
               'extended_ride': ride_metrics(P, fin_pred),
               'corner_from_road': heldout_corner}
    if floor and fin_n / floor > PARTLY_FACTOR and verdict != 'ambiguous':
        verdict = 'partly_explained'
    corner = corner_params(P, final_o, road)
    notes = {'input': 'measured coil current through the nominal fluid lag' if P.coil else
             'current command through the nominal driver (driver and fluid lumped)',
             'sprung_mass': ('from the wheel equation (road given)' if road else
                             'not identifiable without a force scale: nominal m_s kept, the '
                             'strut force is fitted per unit sprung mass'),
             'drop_loss': drop, 'driver_causes': driver_causes}
    if road is None:
        notes['accelerometer_scale'] = ('untestable: a scale error of the body IMU is the '
                                        'same as a different sprung mass; a flip test (+-1 g) '
                                        'or a rig run with a road separates it')
        c_nom = np.array(nominal.damper_coeffs()[:4])
        c_fit = np.array([corner['c0'], corner['c1'], corner['fy0'], corner['fy1']])
        if np.dot(c_fit, c_fit) > 0:
            scale = float(np.dot(c_fit, c_nom) / np.dot(c_fit, c_fit))
            notes['m_s_if_nominal_damper'] = corner['m_s'] * scale
    return VehicleResult(verdict=verdict, causes=causes, sensor=sensor, ambiguous=ambiguous,
                         untestable=untestable, base=base_o, final=final_o, steps=steps,
                         heldout=heldout, noise=noise, road=road, corner=corner,
                         findings=findings, notes=notes), P, (base_pred, fin_pred)


# -- outputs ------------------------------------------------------------------------------------

def _quarter_fields():
    from mr_suspension.core.quarter_car import QuarterCarParams
    return {f.name for f in fields(QuarterCarParams)}


def corner_files(res, nominal):
    """``(vehicle, damper, driver)`` mappings for YAML, and the fields not written."""
    c = res.corner
    veh = asdict(nominal.vehicle)
    have = _quarter_fields()
    not_written = {}
    veh['m_s'], veh['k_s'] = float(c['m_s']), float(max(c['k_s'], 500.0))
    if 'k_t' in c:
        veh['k_t'] = float(max(c['k_t'], 5e3))
    d = {'law': 'extended', 'f0': 0.0, 'c0': float(c['c0']), 'c1': float(c['c1']),
         'fy0': float(c['fy0']), 'fy1': float(c['fy1']), 'v_y': float(c['v_y']),
         'i_sat': float(c.get('i_sat', 0.0)), 'x_h': 0.0, 'k_series': 0.0, 'k_gas1': 0.0,
         'k_gas2': 0.0, 'kappa': 0.0, 'tau_thermal': 600.0, 'rho': float(c.get('rho', 0.0))}
    for e in res.final.effects:
        part, names = EFFECT_PARAMS[e]
        if part != 'vehicle' or e == 'sprung_mass':
            continue
        for n in names:
            if n in have:
                veh[n] = float(c[n])
            elif e == 'top_mount':
                d['k_series'] = float(c['k_tm'])
                not_written[n] = f'{c[n]:.6g} (damper k_series = k_tm used instead)'
            else:
                not_written[n] = float(c[n])
    drv = asdict(nominal.driver)
    ch = c['chain']
    for k in ('dead_time', 'tau_rise', 'tau_fall', 'fluid_tau_rise', 'fluid_tau_fall'):
        drv[k] = float(ch[k])
    return veh, d, drv, not_written


def write_yaml(path, data, comment):
    """Write a mapping as YAML with a description line (as ``config/`` files have)."""
    import yaml
    body = {'description': comment}
    body.update(data)
    Path(path).write_text(yaml.safe_dump(body, sort_keys=False), encoding='utf-8')


def report_dict(res, P, elapsed):
    """Return the JSON report as a dict."""
    def fnum(x):
        return nan_safe(x) if isinstance(x, (int, float)) else x
    return {
        'tool': 'mr-suspension diagnose-vehicle',
        'records': [{'name': r.name, 'samples': r.n, 'duration_s': r.duration,
                     'rate_hz': 1.0 / r.dt, 'stroke_rate_cutoff_hz': r.cutoff,
                     'coil_current': r.coil_current is not None, 'road': r.road is not None}
                    for r in P.records],
        'verdict': res.verdict,
        'causes': [{'effect': e, 'location': 'driver' if e in res.notes.get('driver_causes', ())
                    else _location(e, P.coil), 'text': EFFECT_TEXT[e],
                    'loss_when_dropped': res.notes['drop_loss'].get(e),
                    'parameters': {n: res.corner.get(n) for n in EFFECT_PARAMS[e][1]
                                   if n in res.corner or e not in CURRENT_EFFECTS}
                    if e not in CURRENT_EFFECTS else res.corner['chain']}
                   for e in res.causes],
        'sensor': res.findings + [{'finding': e, 'location': 'sensor', 'channel': 'body_acc',
                                   'action': 'corrected', 'detail': 'a body IMU sample '
                                   'stamped t belongs to the motion and current at t '
                                   f'{1e3 * res.corner["imu_timing"]:+.2f} ms (a step mean is '
                                   '-0.5 sample); the model evaluates them there',
                                   'shift_s': -res.corner['imu_timing']} for e in res.sensor],
        'ambiguous': [{'effects': list(p),
                       'separate_by': SEPARATING.get(frozenset(p), 'a rig run')}
                      for p in res.ambiguous],
        'untestable': res.untestable,
        'heldout': {k: (fnum(v) if not isinstance(v, dict) else v)
                    for k, v in res.heldout.items()},
        'noise_floor': res.noise,
        'road': None if not res.road else {k: v for k, v in res.road.items()
                                           if not isinstance(v, CV)},
        'baseline': {'model': 'a = b - k_s/m_s x - (c0 + c1 i) v/m_s - (fy0 + fy1 i) '
                              'tanh(v/v_y)/m_s', 'theta_per_m_s': dict(
                                  zip(res.base.names, map(float, res.base.theta))),
                     'eta': dict(res.base.eta)},
        'extended': {'effects': list(res.final.effects), 'theta_per_m_s': dict(
            zip(res.final.names, map(float, res.final.theta))), 'eta': dict(res.final.eta)},
        'corner': res.corner,
        'steps': res.steps,
        'notes': res.notes,
        'elapsed_s': elapsed,
    }


def _location(e, coil):
    return catalogue.where(catalogue.by_name(catalogue.CAR)[e], coil)


def markdown(rep, figures, files):
    """Return the Markdown report text."""
    h = rep['heldout']
    lines = ['# diagnose-vehicle report', '',
             f'**Verdict: {rep["verdict"]}**; causes: '
             + (', '.join(f'`{c["effect"]}` ({c["location"]})' for c in rep['causes']) or 'none'),
             '', '## Held-out (outer blocks)', '',
             '| model | body acc NRMSE | Wk RMS predicted / measured [m/s^2] |', '|---|---|---|',
             f'| baseline | {h["baseline_nrmse"]:.4f} | '
             f'{h["baseline_ride"]["wk_rms_predicted"]:.3f} / '
             f'{h["baseline_ride"]["wk_rms_measured"]:.3f} |',
             f'| extended | {h["extended_nrmse"]:.4f} | '
             f'{h["extended_ride"]["wk_rms_predicted"]:.3f} / '
             f'{h["extended_ride"]["wk_rms_measured"]:.3f} |', '',
             f'Noise floor (IMU and stroke noise through the model): NRMSE '
             f'{rep["noise_floor"]["nrmse"]:.4f}; measured working space (RMS stroke) '
             f'{h["extended_ride"]["working_space_rms_measured"] * 1e3:.2f} mm.', '']
    if h.get('corner_from_road'):
        c = h['corner_from_road']
        lines += ['Full corner simulated from the road (outer blocks):', '',
                  '| model | stroke NRMSE | body acc NRMSE | dyn. tyre load RMS sim / meas [N] '
                  '| working space RMS sim / meas [mm] |', '|---|---|---|---|---|']
        lines += [f'| {k} | {v["stroke_nrmse"]:.4f} | {v["body_acc_nrmse"]:.4f} | '
                  f'{v["tyre_load_rms"]:.0f} / {v["tyre_load_rms_measured"]:.0f} | '
                  f'{1e3 * v["working_space_rms"]:.2f} / '
                  f'{1e3 * v["working_space_rms_measured"]:.2f} |' for k, v in c.items()]
        lines.append('')
    if rep['road']:
        r = rep['road']
        lines += [f'Wheel equation (road given): m_s = {r["m_s"]:.1f} kg, k_t = '
                  f'{r["k_t"]:.0f} N/m; held-out NRMSE nominal m_s {r["base_outer_nrmse"]:.4f}'
                  f' -> fitted {r["free_outer_nrmse"]:.4f}', '']
    lines += ['## Causes', '']
    for c in rep['causes']:
        params = ', '.join(f'{k} = {v:.4g}' for k, v in c['parameters'].items()
                           if isinstance(v, (int, float)))
        lines.append(f'- `{c["effect"]}` ({c["location"]}): {c["text"]}; {params}')
    if not rep['causes']:
        lines.append('- none')
    lines += ['', '## Sensor findings', '']
    lines += [f'- `{f["finding"]}` ({f.get("channel", "")}, {f.get("action", "")}): '
              f'{f.get("detail", "")}' for f in rep['sensor']] or ['- none']
    if rep['ambiguous']:
        lines += ['', '## Ambiguous', '']
        lines += [f'- {" / ".join(a["effects"])}: separate by {a["separate_by"]}'
                  for a in rep['ambiguous']]
    lines += ['', '## Untestable with these data', '']
    lines += [f'- `{e}`: {v["why"]}; make it testable: {v["how"]}'
              for e, v in rep['untestable'].items()] or ['- none']
    lines += ['', '## Steps (inner folds)', '', '| stage | effect | gain | t | accepted |',
              '|---|---|---|---|---|']
    lines += [f'| {s["stage"]} | {s["effect"]} | {s["gain_mse"]:.3f} | {s["t"]} | '
              f'{s.get("kept", s["accepted"])} |' for s in rep['steps']]
    lines += ['', '## Fitted corner', '', 'Run it: `mr-suspension simulate --vehicle '
              f'{files[0]} --damper {files[1]} --driver {files[2]}`', '']
    for k, v in rep['notes'].items():
        if isinstance(v, str):
            lines.append(f'- {k}: {v}')
    if figures:
        lines += ['', '## Figures', ''] + [f'![{f}]({f})' for f in figures]
    return '\n'.join(lines) + '\n'


def plots(res, P, preds, out):
    """Figures: measured vs baseline vs extended, strut force vs stroke rate, residual map."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    names = []
    base_pred, fin_pred = preds
    sl = P.slices[0]
    o = np.nonzero(P.outer[sl])[0]
    start = o[0] if o.size else 0
    w = slice(start, min(start + int(3.0 / P.dt), sl.stop - sl.start))
    t = P.t[0][w]
    fig, ax = plt.subplots(figsize=(9, 4))
    ax.plot(t, P.y[0][w], 'k', lw=1, label='measured')
    ax.plot(t, base_pred[sl][w], 'C0', lw=1, label='baseline')
    ax.plot(t, fin_pred[sl][w], 'C3', lw=1, label='extended')
    ax.set_xlabel('time [s] (outer block)')
    ax.set_ylabel('body acceleration [m/s^2]')
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / 'body_acc.png', dpi=90)
    plt.close(fig)
    names.append('body_acc.png')
    m_s = res.corner['m_s']
    fig, ax = plt.subplots(figsize=(6, 4.5))
    v = np.concatenate(P.v)
    k_s = res.corner['k_s']
    x = np.concatenate(P.x)
    strut = m_s * P.y_all + k_s * x  # strut force on the body minus the linear spring
    step = max(1, P.n // 20000)
    ax.plot(v[::step], -strut[::step], '.', ms=1, color='0.5', label='measured (- m_s a - k_s x)')
    ax.plot(v[::step], -(m_s * fin_pred + k_s * x)[::step], '.', ms=1, color='C3',
            label='extended model')
    ax.set_xlabel('stroke rate [m/s]')
    ax.set_ylabel('strut force without the spring [N]')
    ax.legend(markerscale=8)
    fig.tight_layout()
    fig.savefig(out / 'strut_force.png', dpi=90)
    plt.close(fig)
    names.append('strut_force.png')
    u = np.concatenate(P.u)
    r = P.y_all - fin_pred
    vb = np.quantile(np.abs(v), np.linspace(0, 1, 9))
    ib = np.quantile(u, np.linspace(0, 1, 6))
    grid = np.full((5, 8), np.nan)
    for a in range(5):
        for b in range(8):
            m = (u >= ib[a]) & (u <= ib[a + 1]) & (np.abs(v) >= vb[b]) & (np.abs(v) <= vb[b + 1])
            if m.sum() > 20:
                grid[a, b] = np.sqrt(np.mean(r[m] ** 2))
    fig, ax = plt.subplots(figsize=(6, 3.5))
    im = ax.imshow(grid, origin='lower', aspect='auto')
    ax.set_xlabel('|stroke rate| octile')
    ax.set_ylabel('current quintile')
    fig.colorbar(im, label='residual RMS [m/s^2]')
    fig.tight_layout()
    fig.savefig(out / 'residual_map.png', dpi=90)
    plt.close(fig)
    names.append('residual_map.png')
    return names


def write(res, P, preds, out_dir, nominal, elapsed=None, make_plots=True):
    """Write report.json, report.md, figures and vehicle/damper/driver YAML into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    veh, dmp, drv, not_written = corner_files(res, nominal)
    res.notes['not_written'] = not_written
    src = 'fitted by mr-suspension diagnose-vehicle'
    write_yaml(out / 'vehicle.yaml', veh, f'Corner {src} (nominal where not identifiable)')
    write_yaml(out / 'damper.yaml', dmp, f'Extended damper law {src}')
    write_yaml(out / 'driver.yaml', drv, f'Driver and fluid current dynamics {src}')
    files = [str(out / n) for n in ('vehicle.yaml', 'damper.yaml', 'driver.yaml')]
    rep = report_dict(res, P, elapsed)
    rep['files'] = files
    figures = plots(res, P, preds, out) if make_plots else []
    (out / 'report.json').write_text(json.dumps(_jsonable(rep), indent=1), encoding='utf-8')
    (out / 'report.md').write_text(markdown(rep, figures, files), encoding='utf-8')
    return rep


def _jsonable(o):
    if isinstance(o, dict):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if isinstance(o, np.ndarray):
        return _jsonable(o.tolist())
    if isinstance(o, (np.floating, float)):
        return nan_safe(float(o))
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.bool_,)):
        return bool(o)
    return o


def diagnose_vehicle(paths, out_dir, nominal=None, effects=ALL_EFFECTS, namespace=None,
                     road_topic=None, make_plots=True, progress=None):
    """Load, diagnose and write; returns ``(report dict, VehicleResult)``."""
    from mr_suspension.identification import vehicle_data
    t0 = time.time()
    records = vehicle_data.load(paths, namespace, road_topic)
    nominal = nominal or Nominal.load()
    res, P, preds = run(records, nominal, effects, progress)
    rep = write(res, P, preds, out_dir, nominal, time.time() - t0, make_plots)
    return rep, res


def predict_records(res, records, nominal):
    """Body acceleration of ``records`` (unseen) by the baseline and extended fits.

    Returns ``(measured, baseline, extended)`` (gravity and mean removed, low-passed as fitted)
    and the NRMSE of each model over the whole records.
    """
    P = Prepared(records, nominal)
    out = [_predict_unseen(P, fit) for fit in (res.base, res.final)]
    nrmse = [_nrmse(P.y_all, p) for p in out]
    return (P.y_all, out[0], out[1]), {'baseline_nrmse': nrmse[0], 'extended_nrmse': nrmse[1]}


def _predict_unseen(P, fit):
    mount_refresh(P, fit)
    return predict(P, fit)


def _nrmse(y, p):
    """RMS of the error with its mean removed (the fit's offset) over the std of ``y``."""
    e = y - p
    return float(np.sqrt(np.mean((e - np.mean(e)) ** 2)) / np.std(y))


class VehicleDiagnosis:
    """Estimator of one corner, as :class:`~mr_suspension.identification.diagnose.Diagnosis`.

    ``fit(records)`` diagnoses a corner's records (:func:`run`) and returns the
    :class:`VehicleResult`; ``predict(records)`` gives the body acceleration [m/s^2] of records
    the fit never saw (gravity and mean removed, low-passed as fitted); ``score(records)`` its
    NRMSE against the measured one.
    """

    def __init__(self, nominal=None, effects=ALL_EFFECTS, progress=None):
        bad = [e for e in effects if e not in ALL_EFFECTS]
        if bad:
            raise ValueError(f'unknown effect(s) {bad}; known: {", ".join(ALL_EFFECTS)}')
        self.nominal = nominal
        self.effects = tuple(effects)
        self.progress = progress
        self.result_ = None

    def fit(self, records):
        """Diagnose ``records`` (``vehicle_data.VehicleRecord``); return the ``VehicleResult``."""
        self.nominal = self.nominal or Nominal.load()
        self.result_ = run(list(records), self.nominal, self.effects, self.progress)[0]
        return self.result_

    def _fits(self, model):
        if self.result_ is None:
            raise RuntimeError('VehicleDiagnosis: call fit(records) first')
        if model not in ('extended', 'baseline'):
            raise ValueError(f"model must be 'extended' or 'baseline', got {model!r}")
        return self.result_.final if model == 'extended' else self.result_.base

    def predict(self, records, model='extended'):
        """Body acceleration [m/s^2] of ``records`` by the extended (or baseline) model.

        One array over the records in order, gravity and mean removed, low-passed as fitted.
        """
        fit = self._fits(model)
        return _predict_unseen(Prepared(list(records), self.nominal), fit)

    def score(self, records, model='extended'):
        """NRMSE of the body acceleration on ``records`` (error mean removed, over its std)."""
        fit = self._fits(model)
        P = Prepared(list(records), self.nominal)
        return _nrmse(P.y_all, _predict_unseen(P, fit))
