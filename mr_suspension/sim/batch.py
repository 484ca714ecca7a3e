"""Vectorised batch kernels: many corners at once, one SIMD lane per corner.

Two kernels, both laid out as struct-of-arrays (row ``r`` of corner ``c`` at ``r * W + c`` in
one flat array, ``W`` a compile-time chunk width, so LLVM vectorises the loop over corners):

* :func:`run` (``_chunk``): affine-tanh damper laws at *constant* current. Linear, smooth
  Bingham and seed 002's tanh law are all
  ``F = f0 + (c0 + c1 i) v + kp x + (fy0 + fy1 i) tanh(a v + b x)``; the whole corner step is
  branch-free arithmetic with precomputed reciprocals and fastmath (metrics equal to the
  one-corner run to 6e-14 relative over 10 s, tested to 1e-9).
* :func:`run_exact` (``_exact_chunk``): *every* control law of
  :mod:`~mr_suspension.control.laws` with its velocity estimator, the Wonder Box (rise/fall
  lag, dead time), the fluid lag, a stateless affine-tanh damper law (linear, Bingham, tanh)
  and, for the force-tracking laws, the inverse damper model. Corners are grouped by (road,
  law, damper law, inverse-model law, estimation, delay) so that every chunk is
  branch-uniform; each phase of a step is its own loop over the chunk with the branch outside
  it. It runs the one-corner operations (:func:`~mr_suspension.sim.simulator.corner_loop`)
  in the same order without fastmath, so it gives the same numbers bit for bit (tested against
  :func:`~mr_suspension.sim.simulator.simulate` to a relative 1e-9).

The driver's dead time is folded into the command delay in both: a delay and a first-order lag
commute on an input that starts from rest, so one delay line replaces two ring buffers.
"""
import math
from operator import attrgetter

from numba import get_num_threads, njit, prange
import numpy as np

from mr_suspension.control import laws
from mr_suspension.control.febc import FEBC_TAU_MEAN
from mr_suspension.control.inverse import INV_TOL
from mr_suspension.core import damper as dmp
from mr_suspension.core.driver import (prepare, Q_AFALL, Q_ARISE, Q_FFALL, Q_FRISE, Q_ITOP,
                                       Q_NDEAD)
from mr_suspension.core.fastmath import fast_tanh
from mr_suspension.core.quarter_car import BASE_FIELDS, OPTION_FIELDS

CHUNK = 128
# Rows of the per-corner parameter matrix.
(R_MS, R_MU, R_KS, R_KT, R_CT, R_XMAX, R_XMIN, R_KSTOP, R_G, R_FD0,
 R_F0, R_C0, R_C1, R_KP, R_FY0, R_FY1, R_A, R_B,
 R_ITOP, R_ARISE, R_AFALL, R_FRISE, R_FFALL, R_I, R_NDELAY, R_IMS, R_IMU) = range(27)
N_ROWS = 27
# Rows of the per-corner state in the chunk kernel.
S_ROWS = 23
(S_ZS, S_ZU, S_VS, S_VU, S_LAG, S_FL, S_Z0, S_Z1, S_Z2, S_Z3, S_Z4, S_Z5, S_Z6, S_Z7,
 S_A0, S_A1, S_A2, S_A3, S_A4, S_A5, S_A6, S_A7, S_A8) = range(S_ROWS)


def affine_tanh(params):
    """Return (f0, c0, c1, kp, fy0, fy1, a, b) if the law is affine-tanh, else None."""
    law = dmp.law_id_of(params)
    p = params.to_array()
    if law == dmp.LAW_LINEAR:
        return (p[1], p[0], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    if law == dmp.LAW_BINGHAM:
        return (p[0], p[1], p[2], 0.0, p[3], p[4], 1.0 / p[5], 0.0)
    if law == dmp.LAW_TANH:
        return (0.0, p[3], 0.0, p[4], 0.0, p[0], p[1], p[2])
    return None


_CAR_BASE = attrgetter(*BASE_FIELDS)
_CAR_OPTIONS = attrgetter(*OPTION_FIELDS)


def corner_arrays(configs):
    """``[cfg.arrays() for cfg in configs]``, each part computed once per distinct object.

    Corners of a batch are usually made with ``replace`` from a few vehicles, dampers, drivers
    and controllers; preparing each of them once keeps the set-up well below the run time.
    Parts shared by corners are the same array objects (read them, do not write them).
    """
    memo = {}
    out = []
    for cfg in configs:
        key = ('fd0', id(cfg.damper), cfg.dt)
        if key not in memo:
            memo[key] = cfg.damper_static_force()
        key = ('car', id(cfg.car), memo[key])
        if key not in memo:  # QuarterCarParams.to_array(f_d0), without its per-call getattr
            memo[key] = np.array(_CAR_BASE(cfg.car) + (key[2],) + _CAR_OPTIONS(cfg.car),
                                 dtype=np.float64)
        car = memo[key]
        key = ('damper', id(cfg.damper))
        if key not in memo:
            memo[key] = (dmp.law_id_of(cfg.damper), cfg.damper.to_array())
        law, dp = memo[key]
        key = ('driver', id(cfg.driver), cfg.dt)
        if key not in memo:
            memo[key] = prepare(cfg.driver, cfg.dt)
        q = memo[key]
        key = ('controller', id(cfg.controller))
        if key not in memo:
            memo[key] = (cfg.controller.law_id, cfg.controller.to_array())
        cid, cp = memo[key]
        out.append((car, law, dp, q, cid, cp))
    return out


def eligible(configs):
    """Tell whether every corner has an affine-tanh law at constant current, no model option."""
    return all(c.controller.law == 'constant' and affine_tanh(c.damper) is not None
               and not c.car.options_on for c in configs)


@njit(fastmath=True, error_model='numpy', cache=True)
def _chunk(P, road_z, road_zd, sos, acc, dt):
    nc = CHUNK  # a compile-time constant: row distances are known, so no overlap checks
    # All per-corner state lives in one flat array (row r of corner c at r * nc + c) and the
    # parameters in another, so the corner loop vectorises.
    Pf = P.ravel().copy()
    S = np.zeros(S_ROWS * nc)
    for c in range(nc):
        S[S_A7 * nc + c] = 1e300
    b00, b01, b02, a01, a02 = sos[0, 0], sos[0, 1], sos[0, 2], sos[0, 4], sos[0, 5]
    b10, b11, b12, a11, a12 = sos[1, 0], sos[1, 1], sos[1, 2], sos[1, 4], sos[1, 5]
    b20, b21, b22, a21, a22 = sos[2, 0], sos[2, 1], sos[2, 2], sos[2, 4], sos[2, 5]
    b30, b31, b32, a31, a32 = sos[3, 0], sos[3, 1], sos[3, 2], sos[3, 4], sos[3, 5]
    h = dt
    inv_h = 1.0 / dt
    n = road_z.shape[0] - 1
    for k in range(n):
        z_r = 0.5 * (road_z[k] + road_z[k + 1])
        zr_dot = 0.5 * (road_zd[k] + road_zd[k + 1])
        for c in range(nc):
            ms = Pf[R_MS * nc + c]
            mu = Pf[R_MU * nc + c]
            ims = Pf[R_IMS * nc + c]
            imu = Pf[R_IMU * nc + c]
            g = Pf[R_G * nc + c]
            k_s = Pf[R_KS * nc + c]
            k_stop = Pf[R_KSTOP * nc + c]
            x_max = Pf[R_XMAX * nc + c]
            x_min = Pf[R_XMIN * nc + c]
            zs = S[S_ZS * nc + c]
            zu = S[S_ZU * nc + c]
            vs = S[S_VS * nc + c]
            vu = S[S_VU * nc + c]
            # Constant current (clamped beforehand) behind the command delay. The driver's
            # dead time is folded into that delay: lag and delay commute on an input that
            # starts from rest, so no ring buffer is needed (same numbers, fewer loads).
            u = Pf[R_I * nc + c] if k >= Pf[R_NDELAY * nc + c] else 0.0
            y = S[S_LAG * nc + c]
            y += (Pf[R_ARISE * nc + c] if u > y else Pf[R_AFALL * nc + c]) * (u - y)
            S[S_LAG * nc + c] = y
            f = S[S_FL * nc + c]
            f += (Pf[R_FRISE * nc + c] if y > f else Pf[R_FFALL * nc + c]) * (y - f)
            S[S_FL * nc + c] = f
            # Damper force and tangent (affine-tanh law).
            x = zs - zu
            v = vs - vu
            cv = Pf[R_C0 * nc + c] + Pf[R_C1 * nc + c] * f
            fy = Pf[R_FY0 * nc + c] + Pf[R_FY1 * nc + c] * f
            a_th = Pf[R_A * nc + c]
            th = fast_tanh(a_th * v + Pf[R_B * nc + c] * x)
            f_d = Pf[R_F0 * nc + c] + cv * v + Pf[R_KP * nc + c] * x + fy * th
            c_d = cv + fy * a_th * (1.0 - th * th)
            # Plant: linearly implicit trapezoidal step (as quarter_car.plant_step).
            above = x > x_max
            below = x < x_min
            f_stop = k_stop * (x - x_max) if above else (k_stop * (x - x_min) if below else 0.0)
            k_x = k_s + (k_stop if (above or below) else 0.0)
            s_force = ms * g + Pf[R_FD0 * nc + c] - k_s * x - f_d - f_stop
            f_t_lin = (ms + mu) * g + Pf[R_KT * nc + c] * (z_r - zu) \
                + Pf[R_CT * nc + c] * (zr_dot - vu)
            contact = f_t_lin > 0.0
            kt = Pf[R_KT * nc + c] if contact else 0.0
            ct = Pf[R_CT * nc + c] if contact else 0.0
            f_t = f_t_lin if contact else 0.0
            a_s = (s_force - ms * g) * ims
            a_u = (f_t - s_force - mu * g) * imu
            jz11 = -k_x * ims
            jz12 = k_x * ims
            jz21 = k_x * imu
            jz22 = -(k_x + kt) * imu
            jv11 = -c_d * ims
            jv12 = c_d * ims
            jv21 = c_d * imu
            jv22 = -(c_d + ct) * imu
            m11 = 1.0 - 0.5 * h * jv11 - 0.25 * h * h * jz11
            m12 = -0.5 * h * jv12 - 0.25 * h * h * jz12
            m21 = -0.5 * h * jv21 - 0.25 * h * h * jz21
            m22 = 1.0 - 0.5 * h * jv22 - 0.25 * h * h * jz22
            r1 = h * (a_s + 0.5 * h * (jz11 * vs + jz12 * vu))
            r2 = h * (a_u + 0.5 * h * (jz21 * vs + jz22 * vu))
            inv_det = 1.0 / (m11 * m22 - m12 * m21)
            dv_s = (r1 * m22 - m12 * r2) * inv_det
            dv_u = (m11 * r2 - m21 * r1) * inv_det
            f_t_mid = f_t_lin - kt * h * (0.5 * vu + 0.25 * dv_u) - 0.5 * ct * dv_u
            f_t_mid = f_t_mid if (contact and f_t_mid > 0.0) else 0.0
            zs += h * (vs + 0.5 * dv_s)
            zu += h * (vu + 0.5 * dv_u)
            S[S_ZS * nc + c] = zs
            S[S_ZU * nc + c] = zu
            S[S_VS * nc + c] = vs + dv_s
            S[S_VU * nc + c] = vu + dv_u
            acc_s = dv_s * inv_h
            # Wk weighting: four biquads, direct form II transposed, unrolled so the corner
            # loop stays innermost (and vectorises).
            w1 = b00 * acc_s + S[S_Z0 * nc + c]
            S[S_Z0 * nc + c] = b01 * acc_s - a01 * w1 + S[S_Z1 * nc + c]
            S[S_Z1 * nc + c] = b02 * acc_s - a02 * w1
            w2 = b10 * w1 + S[S_Z2 * nc + c]
            S[S_Z2 * nc + c] = b11 * w1 - a11 * w2 + S[S_Z3 * nc + c]
            S[S_Z3 * nc + c] = b12 * w1 - a12 * w2
            w3 = b20 * w2 + S[S_Z4 * nc + c]
            S[S_Z4 * nc + c] = b21 * w2 - a21 * w3 + S[S_Z5 * nc + c]
            S[S_Z5 * nc + c] = b22 * w2 - a22 * w3
            w = b30 * w3 + S[S_Z6 * nc + c]
            S[S_Z6 * nc + c] = b31 * w3 - a31 * w + S[S_Z7 * nc + c]
            S[S_Z7 * nc + c] = b32 * w3 - a32 * w
            xs = zs - zu
            dft = f_t_mid - (ms + mu) * g
            S[S_A0 * nc + c] += acc_s * acc_s
            S[S_A1 * nc + c] = max(S[S_A1 * nc + c], abs(acc_s))
            S[S_A2 * nc + c] += w * w
            S[S_A3 * nc + c] += w * w * w * w
            S[S_A4 * nc + c] += xs * xs
            S[S_A5 * nc + c] = max(S[S_A5 * nc + c], abs(xs))
            S[S_A6 * nc + c] += dft * dft
            S[S_A7 * nc + c] = min(S[S_A7 * nc + c], f_t_mid)
            S[S_A8 * nc + c] += f_d * v * h
    for c in range(acc.shape[0]):
        for j in range(9):
            acc[c, j] = S[(S_A0 + j) * nc + c]


@njit(parallel=True, cache=True)
def _run_chunks(P, starts, stops, chunk_road, roads_z, roads_zd, sos, acc, dt):
    for j in prange(starts.shape[0]):
        a, b = starts[j], stops[j]
        r = chunk_road[j]
        block = np.empty((P.shape[0], CHUNK))
        for c in range(CHUNK):
            block[:, c] = P[:, min(a + c, b - 1)]  # pad with the chunk's last corner
        _chunk(block, roads_z[r], roads_zd[r], sos, acc[a:b], dt)


def run(configs, road_index, roads_z, roads_zd, dt, sos, n_metrics):
    """Run eligible corners; returns the accumulator matrix (corners x metrics)."""
    nc = len(configs)
    P = np.zeros((N_ROWS, nc))
    for c, (cfg, arrs) in enumerate(zip(configs, corner_arrays(configs))):
        car, _law, _dp, q, _cid, cp = arrs
        P[R_MS:R_FD0 + 1, c] = car[:R_FD0 + 1]  # the model options are off here
        P[R_F0:R_B + 1, c] = affine_tanh(cfg.damper)
        P[R_ITOP, c] = q[Q_ITOP]
        P[R_ARISE, c] = q[Q_ARISE]
        P[R_AFALL, c] = q[Q_AFALL]
        P[R_FRISE, c] = q[Q_FRISE]
        P[R_FFALL, c] = q[Q_FFALL]
        P[R_I, c] = min(max(cp[2], cp[0]), cp[1])
        P[R_NDELAY, c] = round(cfg.control_delay / cfg.dt) + int(q[Q_NDEAD])
        P[R_IMS, c] = 1.0 / cfg.car.m_s
        P[R_IMU, c] = 1.0 / cfg.car.m_u
    if sos.shape[0] != 4:
        raise ValueError('batch kernel expects the 4-section Wk filter')
    order = np.argsort(road_index, kind='stable')
    P = np.ascontiguousarray(P[:, order])
    key_road = road_index[order]
    starts, stops = [], []
    a = 0
    while a < nc:
        b = a
        while b < nc and b - a < CHUNK and key_road[b] == key_road[a]:
            b += 1
        starts.append(a)
        stops.append(b)
        a = b
    starts = np.array(starts, dtype=np.int64)
    stops = np.array(stops, dtype=np.int64)
    acc = np.zeros((nc, n_metrics))
    _run_chunks(P, starts, stops, key_road[starts].astype(np.int64), roads_z, roads_zd, sos,
                acc, dt)
    out = np.empty_like(acc)
    out[order] = acc
    return out


# ---------------------------------------------------------------------------------------------
# Exact feedback kernel: every control law, estimator, Wonder Box, fluid lag, affine-tanh damper.
# ---------------------------------------------------------------------------------------------

XCHUNK = 64
# Per-corner parameter rows of the exact kernel.
(X_MS, X_MU, X_KS, X_KT, X_CT, X_XMAX, X_XMIN, X_KSTOP, X_G, X_FD0,
 X_D0, X_D1, X_D2, X_D3, X_D4, X_D5,
 X_M0, X_M1, X_M2, X_M3, X_M4, X_M5, X_FSTAT,
 X_ITOP, X_ARISE, X_AFALL, X_FRISE, X_FFALL,
 X_IMIN, X_IMAX, X_CURRENT, X_CSKY, X_CGND, X_ALPHA, X_FCROSS, X_KSC, X_K0, X_K1, X_K2, X_K3,
 X_MSC, X_MUC, X_KTC, X_F1, X_F2, X_IROAD, X_FTAU, X_XBAND, X_IBODY, X_VEPS, X_AEPS,
 X_LAM, X_GAIN) = range(53)
X_ROWS = 53
# State rows (plant, last accelerations, estimator, driver, Wk filter, metrics, FEBC) and
# scratch rows of one step.
(T_ZS, T_ZU, T_VS, T_VU, T_AS, T_AU, T_EVS, T_EV, T_EXP, T_LAG, T_FL,
 T_Z0, T_Z1, T_Z2, T_Z3, T_Z4, T_Z5, T_Z6, T_Z7,
 T_A0, T_A1, T_A2, T_A3, T_A4, T_A5, T_A6, T_A7, T_A8,
 T_FMEAN, T_FSIGN, T_FTC, T_FEST,
 W_X, W_V, W_VSH, W_VH, W_VUH, W_ASH, W_FDES, W_I, W_HALF, W_FHALF, W_COIL, W_FIELD,
 W_FD, W_CD, W_FT) = range(47)
T_ROWS = 47
# Laws the exact kernel runs (the others take the generic path).
EXACT_DAMPERS = (dmp.LAW_LINEAR, dmp.LAW_BINGHAM, dmp.LAW_TANH)


def exact_eligible(cfg):
    """Tell whether a corner can take the exact kernel (stateless affine-tanh laws, no noise).

    Plant damper and, for the laws that invert it, the controller's damper model must be
    linear, smooth Bingham or seed 002's tanh law; the sensor-noise study option is not
    supported (``log``/``cos`` per sample do not vectorise), nor are the corner-level model
    options of :class:`~mr_suspension.core.quarter_car.QuarterCarParams` (generic kernel).
    """
    c = cfg.controller
    if dmp.law_id_of(cfg.damper) not in EXACT_DAMPERS or c.noise_acc > 0.0 \
            or c.noise_stroke > 0.0 or cfg.car.options_on:
        return False
    return c.law not in laws.INVERSE_LAWS or dmp.law_id_of(c.inverse_model) in EXACT_DAMPERS


@njit(cache=True)
def _est_consts(f_hp, f_cr, dt):
    """Per-sample constants of ``estimate_step``, written as there (same rounding)."""
    lam = math.exp(-2.0 * math.pi * f_hp * dt)
    gain = 1.0 - math.exp(-2.0 * math.pi * f_cr * dt)
    return lam, gain


@njit(cache=True)
def _bingham(p0, p1, p2, p3, p4, p5, v, i):
    """``damper.bingham_force`` on scalar parameters (same operations, same rounding)."""
    c = p1 + p2 * i
    fc = p3 + p4 * i
    th = fast_tanh(v / p5)
    return p0 + c * v + fc * th, c + fc * (1.0 - th * th) / p5


@njit(cache=True)
def _tanh(p0, p1, p2, p3, p4, x, v, i):
    """``damper.tanh_force`` on scalar parameters (same operations, same rounding)."""
    th = fast_tanh(p1 * v + p2 * x)
    return p0 * i * th + p3 * v + p4 * x, p0 * i * (1.0 - th * th) * p1 + p3


@njit(cache=True)
def _illinois_first(g_a, g_b, a, b):
    """First regula falsi point of ``inverse.inverse_current`` (bisection if out of range)."""
    ci = a - g_a * (b - a) / (g_b - g_a)
    return ci if (a <= ci <= b and ci == ci) else 0.5 * (a + b)


@njit(cache=True)
def _illinois_pick(g_a, g_b, g_c, a, b, ci, x, v, f_des):
    """Outcome of ``semi_active_current`` after one step: ``(current, needs more steps)``."""
    if b <= a or not (f_des * v > 0.0) or not (f_des == f_des and x == x):
        return a, False
    if g_a == 0.0:
        return a, False
    if g_b == 0.0:
        return b, False
    if (g_a > 0.0) == (g_b > 0.0):
        return (a if abs(g_a) <= abs(g_b) else b), False
    done = abs(g_c) <= 1e-9 * (1.0 + abs(f_des)) or (b - a) <= INV_TOL
    return ci, not done


@njit(error_model='numpy', cache=True)
def _drive_lane(S, Pf, ring, read, c):
    """Delayed command, Wonder Box lag and fluid lag of one lane (``driver.lag_step``).

    Both rates of a lag are loaded before the choice, so the choice is a select of two
    values (a select of two addresses would compile to a gather).
    """
    nc = XCHUNK
    u = ring[read, c]
    itop = Pf[X_ITOP * nc + c]
    t = itop if u > itop else u
    u = t if u > 0.0 else 0.0  # driver.clip_command
    a_rise = Pf[X_ARISE * nc + c]
    a_fall = Pf[X_AFALL * nc + c]
    y = S[T_LAG * nc + c]
    y += (a_rise if u > y else a_fall) * (u - y)
    S[T_LAG * nc + c] = y
    f_rise = Pf[X_FRISE * nc + c]
    f_fall = Pf[X_FFALL * nc + c]
    f = S[T_FL * nc + c]
    f += (f_rise if y > f else f_fall) * (y - f)
    S[T_FL * nc + c] = f
    S[W_COIL * nc + c] = y
    S[W_FIELD * nc + c] = f
    return f


@njit(error_model='numpy', cache=True)
def _exact_chunk(cid, dlaw, ilaw, est, m, P, delay, cps, road_z, road_zd, sos, dt, acc, rec,
                 out):
    """Run ``m`` corners (lanes) of one branch-uniform group; the same step as ``corner_loop``.

    Each phase of a step is its own loop over the lanes with the law branch outside it, so
    every loop is straight-line arithmetic on rows of flat arrays (row r of lane c at
    r * XCHUNK + c) and compiles to SIMD code. The rare data-dependent work (a second regula
    falsi iteration of the inverse model, FEBC's smoothing ``exp`` at a zero crossing) is
    flagged and redone per lane by the scalar one-corner functions.
    """
    nc = XCHUNK
    Pf = P.ravel().copy()
    S = np.zeros(T_ROWS * nc)
    for c in range(m):
        S[T_A7 * nc + c] = 1e300
    lmax = delay + 1
    ring = np.zeros((lmax, nc))
    fs = np.zeros(laws.N_CTRL_STATE)
    b00, b01, b02, a01, a02 = sos[0, 0], sos[0, 1], sos[0, 2], sos[0, 4], sos[0, 5]
    b10, b11, b12, a11, a12 = sos[1, 0], sos[1, 1], sos[1, 2], sos[1, 4], sos[1, 5]
    b20, b21, b22, a21, a22 = sos[2, 0], sos[2, 1], sos[2, 2], sos[2, 4], sos[2, 5]
    b30, b31, b32, a31, a32 = sos[3, 0], sos[3, 1], sos[3, 2], sos[3, 4], sos[3, 5]
    h = dt
    n = road_z.shape[0] - 1
    two_pi = 2.0 * math.pi
    for k in range(n):
        z_r = 0.5 * (road_z[k] + road_z[k + 1])
        zr_dot = 0.5 * (road_zd[k] + road_zd[k + 1])
        # 1. Measurements and velocity estimates (estimation.estimate_step), resolution. The
        # estimate feeds nothing but the law, so the laws that read no velocity skip it.
        if est == 0 and cid != laws.CTRL_CONSTANT and cid != laws.CTRL_FEBC:
            for c in range(m):
                x = S[T_ZS * nc + c] - S[T_ZU * nc + c]
                a_s = S[T_AS * nc + c]
                vs_hat = Pf[X_LAM * nc + c] * S[T_EVS * nc + c] + dt * a_s
                dx = (x - S[T_EXP * nc + c]) / dt
                pred = S[T_EV * nc + c] + dt * (a_s - S[T_AU * nc + c])
                v_hat = pred + Pf[X_GAIN * nc + c] * (dx - pred)
                S[T_EVS * nc + c] = vs_hat
                S[T_EXP * nc + c] = x
                S[T_EV * nc + c] = v_hat
                v_u = vs_hat - v_hat
                veps = Pf[X_VEPS * nc + c]
                S[W_X * nc + c] = x
                S[W_V * nc + c] = S[T_VS * nc + c] - S[T_VU * nc + c]
                S[W_VSH * nc + c] = 0.0 if abs(vs_hat) < veps else vs_hat
                S[W_VH * nc + c] = 0.0 if abs(v_hat) < veps else v_hat
                S[W_VUH * nc + c] = 0.0 if abs(v_u) < veps else v_u
                S[W_ASH * nc + c] = 0.0 if abs(a_s) < Pf[X_AEPS * nc + c] else a_s
        else:
            for c in range(m):
                vs = S[T_VS * nc + c]
                vu = S[T_VU * nc + c]
                v = vs - vu
                a_s = S[T_AS * nc + c]
                veps = Pf[X_VEPS * nc + c]
                S[W_X * nc + c] = S[T_ZS * nc + c] - S[T_ZU * nc + c]
                S[W_V * nc + c] = v
                S[W_VSH * nc + c] = 0.0 if abs(vs) < veps else vs
                S[W_VH * nc + c] = 0.0 if abs(v) < veps else v
                S[W_VUH * nc + c] = 0.0 if abs(vu) < veps else vu
                S[W_ASH * nc + c] = 0.0 if abs(a_s) < Pf[X_AEPS * nc + c] else a_s
        # 2. The law: a current, or a desired force for the inverse model.
        inverse = False
        if cid == laws.CTRL_CONSTANT:
            for c in range(m):
                S[W_I * nc + c] = Pf[X_CURRENT * nc + c]
        elif cid == laws.CTRL_SKYHOOK_ONOFF:
            for c in range(m):
                on = S[W_VSH * nc + c] * S[W_VH * nc + c] > 0.0
                i_max = Pf[X_IMAX * nc + c]
                i_min = Pf[X_IMIN * nc + c]
                S[W_I * nc + c] = i_max if on else i_min
        elif cid == laws.CTRL_ADD:
            for c in range(m):
                on = S[W_ASH * nc + c] * S[W_VH * nc + c] > 0.0
                i_max = Pf[X_IMAX * nc + c]
                i_min = Pf[X_IMIN * nc + c]
                S[W_I * nc + c] = i_max if on else i_min
        elif cid == laws.CTRL_SH_ADD:
            for c in range(m):
                a = 1.0 / (two_pi * Pf[X_FCROSS * nc + c])
                v_s = S[W_VSH * nc + c]
                v = S[W_VH * nc + c]
                a_s = S[W_ASH * nc + c]
                on_add = a_s * v > 0.0
                on_sh = v_s * v > 0.0
                on = on_add if v_s * v_s - a * a * a_s * a_s <= 0.0 else on_sh
                i_max = Pf[X_IMAX * nc + c]
                i_min = Pf[X_IMIN * nc + c]
                S[W_I * nc + c] = i_max if on else i_min
        elif cid == laws.CTRL_SKYHOOK:
            inverse = True
            for c in range(m):
                S[W_FDES * nc + c] = Pf[X_CSKY * nc + c] * S[W_VSH * nc + c]
        elif cid == laws.CTRL_GROUNDHOOK:
            inverse = True
            for c in range(m):
                S[W_FDES * nc + c] = -Pf[X_CGND * nc + c] * S[W_VUH * nc + c]
        elif cid == laws.CTRL_HYBRID:
            inverse = True
            for c in range(m):
                v = S[W_VH * nc + c]
                f_sky = Pf[X_CSKY * nc + c] * S[W_VSH * nc + c]
                f_sky = 0.0 if f_sky * v <= 0.0 else f_sky
                f_gnd = -Pf[X_CGND * nc + c] * S[W_VUH * nc + c]
                f_gnd = 0.0 if f_gnd * v <= 0.0 else f_gnd
                al = Pf[X_ALPHA * nc + c]
                S[W_FDES * nc + c] = al * f_sky + (1.0 - al) * f_gnd
        elif cid == laws.CTRL_PDD:
            inverse = True
            for c in range(m):
                S[W_FDES * nc + c] = -Pf[X_KSC * nc + c] * S[W_X * nc + c]
        elif cid == laws.CTRL_CLIPPED_OPTIMAL:
            inverse = True
            for c in range(m):
                a_s = S[W_ASH * nc + c]
                d_tyre = -(Pf[X_MSC * nc + c] * a_s + Pf[X_MUC * nc + c] * S[T_AU * nc + c]) \
                    / Pf[X_KTC * nc + c]
                S[W_FDES * nc + c] = -(Pf[X_K0 * nc + c] * S[W_X * nc + c]
                                       + Pf[X_K1 * nc + c] * S[W_VSH * nc + c]
                                       + Pf[X_K2 * nc + c] * d_tyre
                                       + Pf[X_K3 * nc + c] * S[W_VUH * nc + c])
        elif cid == laws.CTRL_FEBC:
            # febc.febc_step; the smoothing exp at a zero crossing is done per lane below.
            nfix = 0
            for c in range(m):
                x = S[W_X * nc + c]
                mean = S[T_FMEAN * nc + c]
                mean += dt / FEBC_TAU_MEAN * (x - mean)
                S[T_FMEAN * nc + c] = mean
                y = x - mean
                tc = S[T_FTC * nc + c] + dt
                sign = S[T_FSIGN * nc + c]
                band = Pf[X_XBAND * nc + c]
                new = sign
                new = 1.0 if y > band else new
                new = -1.0 if y < -band else new  # band >= 0: exclusive
                cross = new != sign
                upd = cross & (sign != 0.0)
                fest = S[T_FEST * nc + c]
                f = 0.5 / tc
                fix = upd & (fest > 0.0)
                S[W_HALF * nc + c] = tc
                S[W_FHALF * nc + c] = f
                S[W_FDES * nc + c] = 1.0 if fix else 0.0
                nfix += 1 if fix else 0
                fest = f if upd & (fest <= 0.0) else fest
                S[T_FEST * nc + c] = fest
                tc = 0.0 if cross else tc
                S[T_FTC * nc + c] = tc
                S[T_FSIGN * nc + c] = new
                f_cap = 0.5 / tc
                f_est = f_cap if (tc > 0.0) & (fest > f_cap) else fest
                i_road = Pf[X_IROAD * nc + c]
                i_mid = Pf[X_IMIN * nc + c]
                i_body = Pf[X_IBODY * nc + c]
                i = i_road
                i = i_mid if f_est < Pf[X_F2 * nc + c] else i
                i = i_body if f_est < Pf[X_F1 * nc + c] else i
                S[W_I * nc + c] = i
            if nfix > 0:
                for c in range(m):
                    if S[W_FDES * nc + c] != 0.0:
                        fest = S[T_FEST * nc + c]
                        half = S[W_HALF * nc + c]
                        fest += (1.0 - math.exp(-half / Pf[X_FTAU * nc + c])) \
                            * (S[W_FHALF * nc + c] - fest)
                        S[T_FEST * nc + c] = fest
                        i = Pf[X_IROAD * nc + c]
                        if fest < Pf[X_F2 * nc + c]:
                            i = Pf[X_IMIN * nc + c]
                        if fest < Pf[X_F1 * nc + c]:
                            i = Pf[X_IBODY * nc + c]
                        S[W_I * nc + c] = i
        # 3. Inverse model (inverse.semi_active_current): the first Illinois step is exact for
        # an affine law; lanes that need more iterations are redone by the scalar function.
        if inverse:
            nfix = 0
            if ilaw == dmp.LAW_BINGHAM:
                for c in range(m):
                    x = S[W_X * nc + c]
                    v = S[W_VH * nc + c]
                    f_des = S[W_FDES * nc + c]
                    a = Pf[X_IMIN * nc + c]
                    b = Pf[X_IMAX * nc + c]
                    fstat = Pf[X_FSTAT * nc + c]
                    p0 = Pf[X_M0 * nc + c]
                    p1 = Pf[X_M1 * nc + c]
                    p2 = Pf[X_M2 * nc + c]
                    p3 = Pf[X_M3 * nc + c]
                    p4 = Pf[X_M4 * nc + c]
                    p5 = Pf[X_M5 * nc + c]
                    g_a = _bingham(p0, p1, p2, p3, p4, p5, v, a)[0] - fstat - f_des
                    g_b = _bingham(p0, p1, p2, p3, p4, p5, v, b)[0] - fstat - f_des
                    ci = _illinois_first(g_a, g_b, a, b)
                    g_c = _bingham(p0, p1, p2, p3, p4, p5, v, ci)[0] - fstat - f_des
                    i, fix = _illinois_pick(g_a, g_b, g_c, a, b, ci, x, v, f_des)
                    S[W_I * nc + c] = i
                    S[W_HALF * nc + c] = 1.0 if fix else 0.0
                    nfix += 1 if fix else 0
            elif ilaw == dmp.LAW_TANH:
                for c in range(m):
                    x = S[W_X * nc + c]
                    v = S[W_VH * nc + c]
                    f_des = S[W_FDES * nc + c]
                    a = Pf[X_IMIN * nc + c]
                    b = Pf[X_IMAX * nc + c]
                    fstat = Pf[X_FSTAT * nc + c]
                    p0 = Pf[X_M0 * nc + c]
                    p1 = Pf[X_M1 * nc + c]
                    p2 = Pf[X_M2 * nc + c]
                    p3 = Pf[X_M3 * nc + c]
                    p4 = Pf[X_M4 * nc + c]
                    g_a = _tanh(p0, p1, p2, p3, p4, x, v, a)[0] - fstat - f_des
                    g_b = _tanh(p0, p1, p2, p3, p4, x, v, b)[0] - fstat - f_des
                    ci = _illinois_first(g_a, g_b, a, b)
                    g_c = _tanh(p0, p1, p2, p3, p4, x, v, ci)[0] - fstat - f_des
                    i, fix = _illinois_pick(g_a, g_b, g_c, a, b, ci, x, v, f_des)
                    S[W_I * nc + c] = i
                    S[W_HALF * nc + c] = 1.0 if fix else 0.0
                    nfix += 1 if fix else 0
            else:
                for c in range(m):
                    x = S[W_X * nc + c]
                    v = S[W_VH * nc + c]
                    f_des = S[W_FDES * nc + c]
                    a = Pf[X_IMIN * nc + c]
                    b = Pf[X_IMAX * nc + c]
                    g_a = Pf[X_M0 * nc + c] * v + Pf[X_M1 * nc + c] - Pf[X_FSTAT * nc + c] \
                        - f_des
                    i, fix = _illinois_pick(g_a, g_a, g_a, a, b, a, x, v, f_des)
                    S[W_I * nc + c] = i
                    S[W_HALF * nc + c] = 1.0 if fix else 0.0
                    nfix += 1 if fix else 0
            if nfix > 0:
                for c in range(m):
                    if S[W_HALF * nc + c] != 0.0:
                        S[W_I * nc + c] = laws.inverse_command(
                            cps[c], fs, S[W_X * nc + c], S[W_VH * nc + c],
                            S[W_FDES * nc + c], dt)
        # 4. Command clamp (laws.clamp_current), command delay plus the driver's dead time as
        # one delay line (exact: lag and delay commute on an input at rest), driver lag, fluid.
        slot = k % lmax
        for c in range(m):
            i = S[W_I * nc + c]
            i_min = Pf[X_IMIN * nc + c]
            i_max = Pf[X_IMAX * nc + c]
            i = i_max if i > i_max else i
            i = i_min if i < i_min else i
            i = i if i == i else i_min
            S[W_I * nc + c] = i
            ring[slot, c] = i
        read = (k - delay) % lmax
        # 5. Damper force and tangent at the field current.
        if dlaw == dmp.LAW_BINGHAM:
            for c in range(m):
                f = _drive_lane(S, Pf, ring, read, c)
                f_d, c_d = _bingham(Pf[X_D0 * nc + c], Pf[X_D1 * nc + c], Pf[X_D2 * nc + c],
                                    Pf[X_D3 * nc + c], Pf[X_D4 * nc + c], Pf[X_D5 * nc + c],
                                    S[W_V * nc + c], f)
                S[W_FD * nc + c] = f_d
                S[W_CD * nc + c] = c_d
        elif dlaw == dmp.LAW_TANH:
            for c in range(m):
                f = _drive_lane(S, Pf, ring, read, c)
                f_d, c_d = _tanh(Pf[X_D0 * nc + c], Pf[X_D1 * nc + c], Pf[X_D2 * nc + c],
                                 Pf[X_D3 * nc + c], Pf[X_D4 * nc + c], S[W_X * nc + c],
                                 S[W_V * nc + c], f)
                S[W_FD * nc + c] = f_d
                S[W_CD * nc + c] = c_d
        else:
            for c in range(m):
                _drive_lane(S, Pf, ring, read, c)
                S[W_FD * nc + c] = Pf[X_D0 * nc + c] * S[W_V * nc + c] + Pf[X_D1 * nc + c]
                S[W_CD * nc + c] = Pf[X_D0 * nc + c]
        # 6. Plant (quarter_car.plant_step, same operations), Wk filter, metrics.
        for c in range(m):
            f_d = S[W_FD * nc + c]
            c_d = S[W_CD * nc + c]
            v = S[W_V * nc + c]
            ms = Pf[X_MS * nc + c]
            mu = Pf[X_MU * nc + c]
            g = Pf[X_G * nc + c]
            k_s = Pf[X_KS * nc + c]
            k_stop = Pf[X_KSTOP * nc + c]
            x_max = Pf[X_XMAX * nc + c]
            x_min = Pf[X_XMIN * nc + c]
            zs = S[T_ZS * nc + c]
            zu = S[T_ZU * nc + c]
            vs = S[T_VS * nc + c]
            vu = S[T_VU * nc + c]
            x = zs - zu
            above = x > x_max
            below = x < x_min
            f_stop = k_stop * (x - x_max) if above else (k_stop * (x - x_min) if below else 0.0)
            k_x = k_s + k_stop if (above or below) else k_s
            s_force = ms * g + Pf[X_FD0 * nc + c] - k_s * x - f_d - f_stop
            f_t_lin = (ms + mu) * g + Pf[X_KT * nc + c] * (z_r - zu) \
                + Pf[X_CT * nc + c] * (zr_dot - vu)
            contact = f_t_lin > 0.0
            kt = Pf[X_KT * nc + c] if contact else 0.0
            ct = Pf[X_CT * nc + c] if contact else 0.0
            f_t = f_t_lin if contact else 0.0
            a_s = (s_force - ms * g) / ms
            a_u = (f_t - s_force - mu * g) / mu
            jz12 = k_x / ms
            jz11 = -jz12  # = -k_x / ms exactly: rounding is symmetric
            jz21 = k_x / mu
            jz22 = -(k_x + kt) / mu
            jv12 = c_d / ms
            jv11 = -jv12
            jv21 = c_d / mu
            jv22 = -(c_d + ct) / mu
            m11 = 1.0 - 0.5 * h * jv11 - 0.25 * h * h * jz11
            m12 = -0.5 * h * jv12 - 0.25 * h * h * jz12
            m21 = -0.5 * h * jv21 - 0.25 * h * h * jz21
            m22 = 1.0 - 0.5 * h * jv22 - 0.25 * h * h * jz22
            r1 = h * (a_s + 0.5 * h * (jz11 * vs + jz12 * vu))
            r2 = h * (a_u + 0.5 * h * (jz21 * vs + jz22 * vu))
            det = m11 * m22 - m12 * m21
            dv_s = (r1 * m22 - m12 * r2) / det
            dv_u = (m11 * r2 - m21 * r1) / det
            f_t_mid = f_t_lin - kt * h * (0.5 * vu + 0.25 * dv_u) - 0.5 * ct * dv_u
            f_t_mid = f_t_mid if (kt > 0.0 and not f_t_mid < 0.0) else 0.0
            zs += h * (vs + 0.5 * dv_s)
            zu += h * (vu + 0.5 * dv_u)
            S[T_ZS * nc + c] = zs
            S[T_ZU * nc + c] = zu
            S[T_VS * nc + c] = vs + dv_s
            S[T_VU * nc + c] = vu + dv_u
            acc_s = dv_s / h
            S[T_AS * nc + c] = acc_s
            S[T_AU * nc + c] = dv_u / h
            S[W_FT * nc + c] = f_t_mid
            w1 = b00 * acc_s + S[T_Z0 * nc + c]
            S[T_Z0 * nc + c] = b01 * acc_s - a01 * w1 + S[T_Z1 * nc + c]
            S[T_Z1 * nc + c] = b02 * acc_s - a02 * w1
            w2 = b10 * w1 + S[T_Z2 * nc + c]
            S[T_Z2 * nc + c] = b11 * w1 - a11 * w2 + S[T_Z3 * nc + c]
            S[T_Z3 * nc + c] = b12 * w1 - a12 * w2
            w3 = b20 * w2 + S[T_Z4 * nc + c]
            S[T_Z4 * nc + c] = b21 * w2 - a21 * w3 + S[T_Z5 * nc + c]
            S[T_Z5 * nc + c] = b22 * w2 - a22 * w3
            w = b30 * w3 + S[T_Z6 * nc + c]
            S[T_Z6 * nc + c] = b31 * w3 - a31 * w + S[T_Z7 * nc + c]
            S[T_Z7 * nc + c] = b32 * w3 - a32 * w
            xs = zs - zu
            dft = f_t_mid - (ms + mu) * g
            S[T_A0 * nc + c] += acc_s * acc_s
            S[T_A1 * nc + c] = max(S[T_A1 * nc + c], abs(acc_s))
            S[T_A2 * nc + c] += w * w
            S[T_A3 * nc + c] += w * w * w * w
            S[T_A4 * nc + c] += xs * xs
            S[T_A5 * nc + c] = max(S[T_A5 * nc + c], abs(xs))
            S[T_A6 * nc + c] += dft * dft
            S[T_A7 * nc + c] = min(S[T_A7 * nc + c], f_t_mid)
            S[T_A8 * nc + c] += f_d * v * h
        if rec:
            for c in range(m):
                out[c, k, 0] = S[T_ZS * nc + c]
                out[c, k, 1] = S[T_ZU * nc + c]
                out[c, k, 2] = S[T_VS * nc + c]
                out[c, k, 3] = S[T_VU * nc + c]
                out[c, k, 4] = S[T_AS * nc + c]
                out[c, k, 5] = S[T_AU * nc + c]
                out[c, k, 6] = S[T_ZS * nc + c] - S[T_ZU * nc + c]
                out[c, k, 7] = S[T_VS * nc + c] - S[T_VU * nc + c]
                out[c, k, 8] = S[W_FD * nc + c]
                out[c, k, 9] = S[W_FT * nc + c]
                out[c, k, 10] = S[W_I * nc + c]
                out[c, k, 11] = S[W_COIL * nc + c]
                out[c, k, 12] = S[W_FIELD * nc + c]
                out[c, k, 13] = road_z[k + 1]
    for c in range(m):
        for j in range(9):
            acc[c, j] = S[(T_A0 + j) * nc + c]


@njit(parallel=True, cache=True)
def _run_exact(keys, starts, stops, P, cps, roads_z, roads_zd, sos, dt, acc, rec, out):
    for j in prange(starts.shape[0]):
        a, b = starts[j], stops[j]
        block = np.zeros((X_ROWS, XCHUNK))
        for c in range(b - a):
            block[:, c] = P[:, a + c]
        r = keys[j, 0]
        _exact_chunk(keys[j, 1], keys[j, 2], keys[j, 3], keys[j, 4], b - a, block,
                     keys[j, 5], cps[a:b], roads_z[r], roads_zd[r], sos, dt, acc[a:b], rec,
                     out[a:b] if rec else out)


_CTRL_ROWS = ((X_IMIN, laws.P_IMIN), (X_IMAX, laws.P_IMAX), (X_CURRENT, laws.P_CURRENT),
              (X_CSKY, laws.P_CSKY), (X_CGND, laws.P_CGND), (X_ALPHA, laws.P_ALPHA),
              (X_FCROSS, laws.P_FCROSS), (X_KSC, laws.P_KS), (X_K0, laws.P_K0),
              (X_K1, laws.P_K1), (X_K2, laws.P_K2), (X_K3, laws.P_K3), (X_MSC, laws.P_MS),
              (X_MUC, laws.P_MU), (X_KTC, laws.P_KT), (X_F1, laws.P_F1), (X_F2, laws.P_F2),
              (X_IROAD, laws.P_IROAD), (X_FTAU, laws.P_FTAU), (X_XBAND, laws.P_XBAND),
              (X_IBODY, laws.P_IBODY), (X_VEPS, laws.P_VEPS), (X_AEPS, laws.P_AEPS))


def _columns(part, arrs, rows, fill):
    """Matrix (len(arrs) x rows) of ``fill(arrays)`` computed once per distinct part object."""
    memo = {}
    out = np.empty((len(arrs), rows))
    for c, a in enumerate(arrs):
        key = id(a[part])
        if key not in memo:
            memo[key] = fill(a)
        out[c] = memo[key]
    return out


def _exact_matrix(configs, arrs, dt):
    """Parameter matrix (``X_ROWS`` x corners) and the branch key of every corner."""
    nc = len(configs)
    P = np.zeros((X_ROWS, nc))
    P[X_MS:X_FD0 + 1] = np.array([a[0][:X_FD0 + 1] for a in arrs]).T

    def damper(a):
        col = np.zeros(6)
        col[:a[2].size] = a[2]
        return col

    def driver(a):
        q = a[3]
        return [q[Q_ITOP], q[Q_ARISE], q[Q_AFALL], q[Q_FRISE], q[Q_FFALL], q[Q_NDEAD]]

    def ctrl(a):
        cp = a[5]
        col = np.zeros(X_ROWS)
        n = min(int(cp[laws.P_DN]), 6)
        col[X_M0:X_M0 + n] = cp[laws.P_DP:laws.P_DP + n]
        col[X_FSTAT] = cp[laws.P_FSTAT]
        for row, slot in _CTRL_ROWS:
            col[row] = cp[slot]
        col[X_LAM], col[X_GAIN] = _est_consts(cp[laws.P_FHP], cp[laws.P_FCR], dt)
        return col

    P[X_D0:X_D5 + 1] = _columns(2, arrs, 6, damper).T
    drv = _columns(3, arrs, 6, driver)
    P[X_ITOP:X_FFALL + 1] = drv[:, :5].T
    ctl = _columns(5, arrs, X_ROWS, ctrl).T
    P[X_M0:X_FSTAT + 1] = ctl[X_M0:X_FSTAT + 1]
    P[X_IMIN:] = ctl[X_IMIN:]
    delay = np.rint(np.array([c.control_delay / c.dt for c in configs])).astype(np.int64) \
        + drv[:, 5].astype(np.int64)
    keys = np.array([(a[4], a[1], int(a[5][laws.P_DLAW]), int(a[5][laws.P_EST])) for a in arrs],
                    dtype=np.int64).reshape(nc, 4)
    return P, np.column_stack([keys, delay])


def run_exact(configs, road_index, roads_z, roads_zd, dt, sos, n_metrics, record=False):
    """Run corners that :func:`exact_eligible` accepts; returns ``(acc, histories or None)``.

    Corners are grouped by (road, control law, damper law, inverse-model law, estimation) so
    each chunk is branch-uniform, and split so that every thread gets work.
    """
    if sos.shape[0] != 4:
        raise ValueError('batch kernel expects the 4-section Wk filter')
    nc = len(configs)
    arrs = corner_arrays(configs)
    P, keys = _exact_matrix(configs, arrs, dt)
    full = np.column_stack([np.asarray(road_index, dtype=np.int64), keys])
    order = np.lexsort(full.T[::-1])
    full = full[order]
    P = np.ascontiguousarray(P[:, order])
    cps = [arrs[c][5] for c in order]
    cp_mat = np.zeros((nc, max(cp.size for cp in cps)))
    for j, cp in enumerate(cps):
        cp_mat[j, :cp.size] = cp
    # Group boundaries, then chunks of at most XCHUNK lanes; small groups are split so that
    # all threads have work (at least 8 lanes a chunk, one SIMD register of doubles).
    bounds = [0] + [j for j in range(1, nc) if (full[j] != full[j - 1]).any()] + [nc]
    n_groups = len(bounds) - 1
    threads = get_num_threads()
    starts, stops = [], []
    for a, b in zip(bounds[:-1], bounds[1:]):
        size = b - a
        pieces = max(-(-size // XCHUNK), min(-(-threads // n_groups), -(-size // 8)))
        step = -(-size // pieces)
        for s in range(a, b, step):
            starts.append(s)
            stops.append(min(s + step, b))
    starts = np.array(starts, dtype=np.int64)
    stops = np.array(stops, dtype=np.int64)
    steps = roads_z.shape[1] - 1
    acc = np.zeros((nc, n_metrics))
    out = np.zeros((nc, steps, 14)) if record else np.zeros((1, 1, 14))
    _run_exact(full[starts], starts, stops, P, cp_mat, roads_z, roads_zd, sos, dt, acc,
               record, out)
    res = np.empty_like(acc)
    res[order] = acc
    if not record:
        return res, None
    hist = np.empty_like(out)
    hist[order] = out
    return res, hist
