"""Vectorised batch kernel for the common case: affine-tanh damper laws at constant current.

Linear, smooth Bingham and seed 002's tanh law are all
``F = f0 + (c0 + c1 i) v + kp x + (fy0 + fy1 i) tanh(a v + b x)``; with a constant current
command the whole corner step (driver lags and dead time, damper, plant, Wk filter, metrics) is
branch-free arithmetic, so the loop over corners compiles to SIMD code. Corners are grouped by
road so each chunk shares one road sample per step.
It computes exactly what :func:`~mr_suspension.core.simulator.corner_loop` computes (the
tests compare both).
"""

from numba import njit, prange
import numpy as np

from mr_suspension.core import damper as dmp
from mr_suspension.core.driver import (Q_AFALL, Q_ARISE, Q_FFALL, Q_FRISE, Q_ITOP, Q_NDEAD)
from mr_suspension.core.fastmath import fast_tanh

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


def eligible(configs):
    """Tell whether every corner has an affine-tanh law and a constant-current controller."""
    return all(c.controller.law == 'constant' and affine_tanh(c.damper) is not None
               for c in configs)


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
    for c, cfg in enumerate(configs):
        car, _law, _dp, q, _cid, cp = cfg.arrays()
        P[R_MS:R_FD0 + 1, c] = car
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
