"""Vectorised batch kernel of the full car: many cars at once, one SIMD lane per car.

Struct-of-arrays like the quarter car's :mod:`~mr_suspension.sim.batch`: a chunk holds ``W``
cars; the corner phases (measurements and velocity estimation, the control law, the inverse
damper model, command delay, Wonder Box and fluid lag, damper force, strut and tyre forces)
run over ``L = 4 W`` corner lanes (corner ``i`` of car ``c`` at lane ``i W + c``, row ``r`` of
a lane at ``r L + lane`` in one flat array), the body phase (solve, body update, ISO 2631
filters) over the ``W`` car lanes. Cars are grouped by (road, control law or modal law, damper
and inverse-model laws, estimation, delays, body kind) so that every chunk is branch-uniform
and each phase is straight-line arithmetic over the lanes.

The step is :func:`~mr_suspension.core.full_car.full_car_step`'s linearly implicit
trapezoidal rule in generalised coordinates ``q = (r, z_u)``, ``r = (z, theta, phi)``:

    (M + dt/2 C + dt^2/4 K) dv = dt (Q - dt/2 K v),

solved with its structure rather than as a dense 7 x 7 system. Ordered ``[r; z_u]`` the
matrix is ``[[A_rr, A_rw], [A_wr, A_ww]]``; a wheel couples only to the body (strut ``i``:
``-e_i T_i``, ``e_i = dt/2 c_i + dt^2/4 k_i``) and, through the anti-roll bar of its axle
(``e_a = dt^2/4 k_arb``, ``d_a = T_L - T_R``), to the other wheel of the axle, so ``A_ww`` is
block diagonal with one 2 x 2 block per axle. Eliminating the wheels (block Gaussian
elimination, Golub & Van Loan, *Matrix Computations*, 4th ed., section 3.2.10) leaves the
3 x 3 Schur complement for the body,

    (A_rr - A_rw A_ww^-1 A_wr) dr = b_r - A_rw A_ww^-1 b_w,   dz_u' = A_ww^-1 (b_w - A_wr dr),

solved by ``L D L^T`` (symmetric positive definite, no pivoting needed); the uncoupled body
(four independent masses) leaves a diagonal Schur complement, one 2 x 2 system per corner.

Bit for bit: ``full_car_step`` itself solves this way (generic loops), and every phase here
runs the one-car simulator's operations in the same order (the quarter car's exact damper and
inverse-model helpers, divisions where it divides, no fastmath besides the rational ``tanh``
the damper laws share), dropping only exact no-ops (products with ``T_i0 = 1``, the zero
components of ``d_a``). So the metrics equal :func:`~mr_suspension.sim.full_car_sim.simulate`'s
exactly (tested to a relative 1e-9). That matters: the laws that invert the damper model make
the closed loop chaotic, and a 1e-15 relative change of the road moves ``simulate``'s
metrics by up to 1e-2 within seconds, so agreement "to round-off" would not be agreement.

Covered: every corner law of :data:`~mr_suspension.control.laws.LAW_IDS` and the modal
sky-hook (:mod:`~mr_suspension.control.modal`), each corner's velocity estimation, Wonder Box
(rise/fall lag, dead time folded into the command delay as in :mod:`~mr_suspension.sim.batch`)
and fluid lag, and the stateless affine-tanh damper laws (linear, smooth Bingham, seed 002's
tanh) as plant and inverse model, without sensor noise or corner model options
(:func:`eligible`); anything else takes :func:`~mr_suspension.sim.full_car_sim.full_car_loop`.
"""

import math

from numba import get_num_threads, njit, prange
import numpy as np

from mr_suspension.control import laws
from mr_suspension.control.febc import FEBC_TAU_MEAN
from mr_suspension.control.inverse import INV_TOL
from mr_suspension.control.modal import G_FHP, G_HEAVE, G_ROLL, modal_map
from mr_suspension.core import damper as dmp
from mr_suspension.core.driver import (prepare, Q_AFALL, Q_ARISE, Q_FFALL, Q_FRISE, Q_ITOP,
                                       Q_NDEAD)
from mr_suspension.core.full_car import N_CORNERS
from mr_suspension.core.quarter_car import BASE_FIELDS
from mr_suspension.sim import batch
from mr_suspension.sim.batch import _bingham, _est_consts, _tanh

W = 16  # cars per chunk
L = N_CORNERS * W  # corner lanes per chunk
MODAL = -1  # law key of the modal sky-hook
N_BODY_ACC = 8
N_CORNER_ACC = 5
N_ACC = N_BODY_ACC + N_CORNERS * N_CORNER_ACC

# Corner parameter rows (stride L): corner of the car, plant damper, inverse model, driver,
# controller, body map row T_i, modal distribution row times the modal gains G_ij c_j,
# uncoupled body mass, static tyre load, dt^2/4 k_arb of the axle's anti-roll bar.
(PC_MS, PC_MU, PC_KS, PC_KT, PC_CT, PC_XMAX, PC_XMIN, PC_KSTOP, PC_G, PC_FD0,
 PC_D0, PC_D1, PC_D2, PC_D3, PC_D4, PC_D5,
 PC_M0, PC_M1, PC_M2, PC_M3, PC_M4, PC_M5, PC_FSTAT,
 PC_ITOP, PC_ARISE, PC_AFALL, PC_FRISE, PC_FFALL,
 PC_IMIN, PC_IMAX, PC_CURRENT, PC_CSKY, PC_CGND, PC_ALPHA, PC_SHA, PC_KSC, PC_K0, PC_K1,
 PC_K2, PC_K3, PC_MSC, PC_MUC, PC_KTC, PC_F1, PC_F2, PC_IROAD, PC_FTAU, PC_XBAND, PC_IBODY,
 PC_VEPS, PC_AEPS, PC_LAM, PC_GAIN,
 PC_T0, PC_T1, PC_T2, PC_G0, PC_G1, PC_G2, PC_MB, PC_FT0, PC_EA) = range(62)
PC_ROWS = 62
# Car parameter rows (stride W): generalised body masses, seat, modal leak, the anti-roll
# bars' directions d_a = T_L - T_R, rates and dt^2/4 rates.
(PB_M0, PB_M1, PB_M2, PB_SX, PB_SY, PB_MLAM,
 PB_DF0, PB_DF1, PB_DF2, PB_DR0, PB_DR1, PB_DR2, PB_KF, PB_KR, PB_EF, PB_ER) = range(16)
PB_ROWS = 16
# Corner state rows (stride L): body point and wheel (height, velocity, last acceleration),
# estimator, driver and fluid lags, FEBC, metrics; then the scratch of one step.
(SC_ZS, SC_ZU, SC_VS, SC_VU, SC_AS, SC_AU, SC_EVS, SC_EV, SC_EXP, SC_LAG, SC_FL,
 SC_FMEAN, SC_FSIGN, SC_FTC, SC_FEST,
 SC_X2, SC_XMAX, SC_DF2, SC_FTMIN, SC_EN,
 WC_X, WC_V, WC_VSH, WC_VH, WC_VUH, WC_ASH, WC_FDES, WC_I, WC_HALF, WC_FHALF,
 WC_FD, WC_CD, WC_ZR, WC_ZRD, WC_E, WC_WD, WC_PHI, WC_RW, WC_FTL, WC_KT, WC_CT,
 WC_DVU) = range(42)
SC_ROWS = 42
# Car state rows (stride W): body coordinates, rates, accelerations, modal heave velocity,
# Wk (CG, seat) and We (pitch, roll) filter states, body metrics.
(SB_R0, SB_R1, SB_R2, SB_V0, SB_V1, SB_V2, SB_A0, SB_A1, SB_A2, SB_MV,
 SB_K0, SB_K1, SB_K2, SB_K3, SB_K4, SB_K5, SB_K6, SB_K7,
 SB_S0, SB_S1, SB_S2, SB_S3, SB_S4, SB_S5, SB_S6, SB_S7,
 SB_P0, SB_P1, SB_P2, SB_P3, SB_P4, SB_P5,
 SB_Q0, SB_Q1, SB_Q2, SB_Q3, SB_Q4, SB_Q5,
 SB_ACC) = range(39)
SB_ROWS = SB_ACC + N_BODY_ACC


def eligible(config):
    """Tell whether a :class:`~mr_suspension.sim.full_car_sim.FullCarConfig` takes the kernel.

    Its corners must be what the quarter car's exact kernel takes
    (:func:`batch.exact_eligible`): linear, Bingham or tanh dampers, which
    :meth:`~mr_suspension.control.laws.ControllerParams.with_plant` also makes the inverse
    models; no sensor noise; no corner model option. The modal law must be the sky-hook.
    """
    if config.modal is not None and config.modal.law != 'modal_skyhook':
        return False  # the full car's clipped-optimal law runs on the reference loop
    ctrl = config.controller
    if ctrl.noise_acc > 0.0 or ctrl.noise_stroke > 0.0:
        return False
    if any(config.car.corner(i).options_on for i in range(N_CORNERS)):
        return False
    return all(dmp.law_id_of(d) in batch.EXACT_DAMPERS for d in config.damper)


def _corner_config(cfg, i, memo):
    """``cfg.corner(i)`` memoised on the objects it is made of (controllers are costly)."""
    car = cfg.car.corner(i)
    key = ('corner', id(cfg.controller), id(car), id(cfg.damper[i]), id(cfg.driver[i]),
           cfg.dt, cfg.control_delay)
    if key not in memo:
        memo[key] = cfg.corner(i)
    return memo[key]


def _corner_column(corner, memo):
    """Parameter column (``PC_ROWS``), controller array and branch keys of one corner."""
    key = ('column', id(corner))
    if key in memo:
        return memo[key]
    dt = corner.dt
    damper = corner.damper
    fd0 = corner.damper_static_force()
    car = corner.car
    col = np.zeros(PC_ROWS)
    col[PC_MS:PC_G + 1] = [getattr(car, f) for f in BASE_FIELDS]
    col[PC_FD0] = fd0
    dp = damper.to_array()
    dlaw = dmp.law_id_of(damper)
    col[PC_D0:PC_D0 + dp.size] = dp
    q = prepare(corner.driver, dt)
    col[PC_ITOP] = q[Q_ITOP]
    col[PC_ARISE] = q[Q_ARISE]
    col[PC_AFALL] = q[Q_AFALL]
    col[PC_FRISE] = q[Q_FRISE]
    col[PC_FFALL] = q[Q_FFALL]
    ctrl = corner.controller
    cp = ctrl.to_array()
    n = min(int(cp[laws.P_DN]), 6)
    col[PC_M0:PC_M0 + n] = cp[laws.P_DP:laws.P_DP + n]
    ilaw = int(cp[laws.P_DLAW])
    col[PC_FSTAT] = cp[laws.P_FSTAT]
    for row, slot in ((PC_IMIN, laws.P_IMIN), (PC_IMAX, laws.P_IMAX),
                      (PC_CURRENT, laws.P_CURRENT), (PC_CSKY, laws.P_CSKY),
                      (PC_CGND, laws.P_CGND), (PC_ALPHA, laws.P_ALPHA), (PC_KSC, laws.P_KS),
                      (PC_K0, laws.P_K0), (PC_K1, laws.P_K1), (PC_K2, laws.P_K2),
                      (PC_K3, laws.P_K3), (PC_MSC, laws.P_MS), (PC_MUC, laws.P_MU),
                      (PC_F1, laws.P_F1), (PC_F2, laws.P_F2), (PC_IROAD, laws.P_IROAD),
                      (PC_FTAU, laws.P_FTAU), (PC_XBAND, laws.P_XBAND),
                      (PC_IBODY, laws.P_IBODY), (PC_VEPS, laws.P_VEPS),
                      (PC_AEPS, laws.P_AEPS)):
        col[row] = cp[slot]
    col[PC_SHA] = 1.0 / (2.0 * math.pi * cp[laws.P_FCROSS])  # as controller_step's sh_add
    col[PC_KTC] = cp[laws.P_KT]
    col[PC_LAM], col[PC_GAIN] = _est_consts(cp[laws.P_FHP], cp[laws.P_FCR], dt)
    col[PC_FT0] = (car.m_s + car.m_u) * car.g
    delay = int(round(corner.control_delay / dt)) + int(q[Q_NDEAD])
    out = (col, cp, (dlaw, ilaw, int(cp[laws.P_EST]), delay, ctrl.law_id))
    memo[key] = out
    return out


def _car_columns(cfg, memo):
    """Corner matrix (``PC_ROWS`` x 4), car column (``PB_ROWS``), controller arrays, key."""
    key = ('car', id(cfg))
    if key in memo:
        return memo[key]
    pc = np.zeros((PC_ROWS, N_CORNERS))
    cps = []
    keys = []
    for i in range(N_CORNERS):
        col, cp, k = _corner_column(_corner_config(cfg, i, memo), memo)
        pc[:, i] = col
        cps.append(cp)
        keys.append(k)
    bkey = ('body', id(cfg.car), cfg.coupled, id(cfg.modal), cfg.dt)
    if bkey not in memo:
        car = cfg.car
        t, mb, arb = car.body(cfg.coupled)
        body = np.zeros((PC_ROWS, N_CORNERS))
        pb = np.zeros(PB_ROWS)
        h = cfg.dt
        if cfg.coupled:
            d = np.stack([t[0, :3] - t[1, :3], t[2, :3] - t[3, :3]])
            if not (np.all(t[:, 0] == 1.0) and np.all(d[:, :2] == 0.0)):
                raise ValueError('full_car_batch: the body map must be T_i = (1, -x_i, y_i) '
                                 'with both wheels of an axle at the same x')
            body[PC_T0:PC_T2 + 1] = t[:, :3].T
            pb[PB_M0:PB_M2 + 1] = mb[:3]
            pb[PB_DF0:PB_DF2 + 1] = t[0, :3] - t[1, :3]
            pb[PB_DR0:PB_DR2 + 1] = t[2, :3] - t[3, :3]
            pb[PB_KF], pb[PB_KR] = arb[1], arb[2]
            pb[PB_EF], pb[PB_ER] = 0.25 * h * h * arb[1], 0.25 * h * h * arb[2]
            body[PC_EA] = 0.25 * h * h * np.array([arb[1], arb[1], arb[2], arb[2]])
            if cfg.modal is not None:
                mp = cfg.modal.to_array(car)
                # modal_step: F_des,i = G_i0 c_heave v_z + G_i1 c_pitch w_p + G_i2 c_roll w_r.
                body[PC_G0:PC_G2 + 1] = (modal_map(t)[:, :3] * mp[G_HEAVE:G_ROLL + 1]).T
                pb[PB_MLAM] = _est_consts(mp[G_FHP], 1.0, h)[0]  # exp(-2 pi f_hp dt)
        else:
            body[PC_MB] = mb[:N_CORNERS]
        pb[PB_SX], pb[PB_SY] = car.seat_x, car.seat_y
        memo[bkey] = (body, pb)
    body, pb = memo[bkey]
    for row in (PC_T0, PC_T1, PC_T2, PC_G0, PC_G1, PC_G2, PC_MB, PC_EA):
        pc[row] = body[row]
    law = MODAL if cfg.modal is not None else keys[0][4]
    car_key = ((law, 1 if cfg.coupled else 0, keys[0][2])
               + tuple(k[0] for k in keys) + tuple(k[1] for k in keys)
               + tuple(k[3] for k in keys))
    out = (pc, pb, cps, car_key)
    memo[key] = out
    return out


# ---------------------------------------------------------------------------------------------
# Phases over the corner lanes [lo, hi) of a chunk (one law each, so loops are branch-free).
# ---------------------------------------------------------------------------------------------

@njit(error_model='numpy', cache=True)
def _first(g_a, g_b, a, b):
    """First regula falsi point of ``inverse.inverse_current`` (bisection if out of range).

    ``batch._illinois_first`` written with selects only, so the lane loop vectorises.
    """
    ci = a - g_a * (b - a) / (g_b - g_a)
    ok = (a <= ci) & (ci <= b) & (ci == ci)
    return ci if ok else 0.5 * (a + b)


@njit(error_model='numpy', cache=True)
def _pick(g_a, g_b, g_c, a, b, ci, x, v, f_des):
    """``batch._illinois_pick`` with selects: ``(current, needs more steps)`` after one step.

    In ``inverse.semi_active_current``'s order: passivity clip or no request -> ``i_min``;
    an end with ``g = 0``; not bracketed -> the nearer end; else the regula falsi point,
    final if ``|g| <= 1e-9 (1 + |F_des|)`` or the interval is below ``INV_TOL``.
    """
    done = (abs(g_c) <= 1e-9 * (1.0 + abs(f_des))) | ((b - a) <= INV_TOL)
    same = (g_a > 0.0) == (g_b > 0.0)
    near = a if abs(g_a) <= abs(g_b) else b
    i = near if same else ci
    fix = not (done | same)
    i = b if g_b == 0.0 else i
    fix = fix & (g_b != 0.0)
    i = a if g_a == 0.0 else i
    fix = fix & (g_a != 0.0)
    clip = (b <= a) | (not (f_des * v > 0.0)) | (not ((f_des == f_des) & (x == x)))
    i = a if clip else i
    fix = fix & (not clip)
    return i, fix


@njit(error_model='numpy', cache=True)
def _inverse_phase(ilaw, S, Pf, cps, fs, lo, hi, dt):
    """Passivity-clipped inverse model (``inverse.semi_active_current``) into ``WC_I``.

    The first regula falsi step is exact for an affine law; lanes that need more steps are
    redone by the scalar function (:func:`~mr_suspension.control.laws.inverse_command`).
    """
    nfix = 0
    if ilaw == dmp.LAW_BINGHAM:
        for c in range(lo, hi):
            x = S[WC_X * L + c]
            v = S[WC_VH * L + c]
            f_des = S[WC_FDES * L + c]
            a = Pf[PC_IMIN * L + c]
            b = Pf[PC_IMAX * L + c]
            fstat = Pf[PC_FSTAT * L + c]
            p0 = Pf[PC_M0 * L + c]
            p1 = Pf[PC_M1 * L + c]
            p2 = Pf[PC_M2 * L + c]
            p3 = Pf[PC_M3 * L + c]
            p4 = Pf[PC_M4 * L + c]
            p5 = Pf[PC_M5 * L + c]
            g_a = _bingham(p0, p1, p2, p3, p4, p5, v, a)[0] - fstat - f_des
            g_b = _bingham(p0, p1, p2, p3, p4, p5, v, b)[0] - fstat - f_des
            ci = _first(g_a, g_b, a, b)
            g_c = _bingham(p0, p1, p2, p3, p4, p5, v, ci)[0] - fstat - f_des
            i, fix = _pick(g_a, g_b, g_c, a, b, ci, x, v, f_des)
            S[WC_I * L + c] = i
            S[WC_HALF * L + c] = 1.0 if fix else 0.0
            nfix += 1 if fix else 0
    elif ilaw == dmp.LAW_TANH:
        for c in range(lo, hi):
            x = S[WC_X * L + c]
            v = S[WC_VH * L + c]
            f_des = S[WC_FDES * L + c]
            a = Pf[PC_IMIN * L + c]
            b = Pf[PC_IMAX * L + c]
            fstat = Pf[PC_FSTAT * L + c]
            p0 = Pf[PC_M0 * L + c]
            p1 = Pf[PC_M1 * L + c]
            p2 = Pf[PC_M2 * L + c]
            p3 = Pf[PC_M3 * L + c]
            p4 = Pf[PC_M4 * L + c]
            g_a = _tanh(p0, p1, p2, p3, p4, x, v, a)[0] - fstat - f_des
            g_b = _tanh(p0, p1, p2, p3, p4, x, v, b)[0] - fstat - f_des
            ci = _first(g_a, g_b, a, b)
            g_c = _tanh(p0, p1, p2, p3, p4, x, v, ci)[0] - fstat - f_des
            i, fix = _pick(g_a, g_b, g_c, a, b, ci, x, v, f_des)
            S[WC_I * L + c] = i
            S[WC_HALF * L + c] = 1.0 if fix else 0.0
            nfix += 1 if fix else 0
    else:
        for c in range(lo, hi):
            x = S[WC_X * L + c]
            v = S[WC_VH * L + c]
            f_des = S[WC_FDES * L + c]
            a = Pf[PC_IMIN * L + c]
            b = Pf[PC_IMAX * L + c]
            g_a = Pf[PC_M0 * L + c] * v + Pf[PC_M1 * L + c] - Pf[PC_FSTAT * L + c] - f_des
            i, fix = _pick(g_a, g_a, g_a, a, b, a, x, v, f_des)
            S[WC_I * L + c] = i
            S[WC_HALF * L + c] = 1.0 if fix else 0.0
            nfix += 1 if fix else 0
    if nfix > 0:
        for c in range(lo, hi):
            if S[WC_HALF * L + c] != 0.0:
                S[WC_I * L + c] = laws.inverse_command(cps[c], fs, S[WC_X * L + c],
                                                       S[WC_VH * L + c], S[WC_FDES * L + c],
                                                       dt)


@njit(error_model='numpy', cache=True)
def _drive_lane(S, Pf, ring, read, c):
    """Delayed command, Wonder Box lag and fluid lag of one lane; returns the field current.

    ``driver.clip_command`` and ``driver.lag_step`` (the dead time is folded into the delay
    line: a delay and a lag commute on an input at rest).
    """
    u = ring[read, c]
    itop = Pf[PC_ITOP * L + c]
    t = itop if u > itop else u
    u = t if u > 0.0 else 0.0
    a_rise = Pf[PC_ARISE * L + c]
    a_fall = Pf[PC_AFALL * L + c]
    y = S[SC_LAG * L + c]
    y += (a_rise if u > y else a_fall) * (u - y)
    S[SC_LAG * L + c] = y
    f_rise = Pf[PC_FRISE * L + c]
    f_fall = Pf[PC_FFALL * L + c]
    f = S[SC_FL * L + c]
    f += (f_rise if y > f else f_fall) * (y - f)
    S[SC_FL * L + c] = f
    return f


@njit(error_model='numpy', cache=True)
def _damper_phase(dlaw, S, Pf, ring, read, lo, hi):
    """Driver and fluid (:func:`_drive_lane`), then the damper force and tangent of the lanes."""
    if dlaw == dmp.LAW_BINGHAM:
        for c in range(lo, hi):
            f = _drive_lane(S, Pf, ring, read, c)
            f_d, c_d = _bingham(Pf[PC_D0 * L + c], Pf[PC_D1 * L + c], Pf[PC_D2 * L + c],
                                Pf[PC_D3 * L + c], Pf[PC_D4 * L + c], Pf[PC_D5 * L + c],
                                S[WC_V * L + c], f)
            S[WC_FD * L + c] = f_d
            S[WC_CD * L + c] = c_d
    elif dlaw == dmp.LAW_TANH:
        for c in range(lo, hi):
            f = _drive_lane(S, Pf, ring, read, c)
            f_d, c_d = _tanh(Pf[PC_D0 * L + c], Pf[PC_D1 * L + c], Pf[PC_D2 * L + c],
                             Pf[PC_D3 * L + c], Pf[PC_D4 * L + c], S[WC_X * L + c],
                             S[WC_V * L + c], f)
            S[WC_FD * L + c] = f_d
            S[WC_CD * L + c] = c_d
    else:
        for c in range(lo, hi):
            _drive_lane(S, Pf, ring, read, c)
            S[WC_FD * L + c] = Pf[PC_D0 * L + c] * S[WC_V * L + c] + Pf[PC_D1 * L + c]
            S[WC_CD * L + c] = Pf[PC_D0 * L + c]


@njit(error_model='numpy', cache=True)
def _measure_phase(estimate, S, Pf, dt):
    """Measurements, velocity estimates (``estimation.estimate_step``) and resolution."""
    if estimate:
        for c in range(L):
            x = S[SC_ZS * L + c] - S[SC_ZU * L + c]
            a_s = S[SC_AS * L + c]
            vs_hat = Pf[PC_LAM * L + c] * S[SC_EVS * L + c] + dt * a_s
            dx = (x - S[SC_EXP * L + c]) / dt
            pred = S[SC_EV * L + c] + dt * (a_s - S[SC_AU * L + c])
            v_hat = pred + Pf[PC_GAIN * L + c] * (dx - pred)
            S[SC_EVS * L + c] = vs_hat
            S[SC_EXP * L + c] = x
            S[SC_EV * L + c] = v_hat
            v_u = vs_hat - v_hat
            veps = Pf[PC_VEPS * L + c]
            S[WC_X * L + c] = x
            S[WC_V * L + c] = S[SC_VS * L + c] - S[SC_VU * L + c]
            S[WC_VSH * L + c] = 0.0 if abs(vs_hat) < veps else vs_hat
            S[WC_VH * L + c] = 0.0 if abs(v_hat) < veps else v_hat
            S[WC_VUH * L + c] = 0.0 if abs(v_u) < veps else v_u
            S[WC_ASH * L + c] = 0.0 if abs(a_s) < Pf[PC_AEPS * L + c] else a_s
    else:
        for c in range(L):
            vs = S[SC_VS * L + c]
            vu = S[SC_VU * L + c]
            v = vs - vu
            a_s = S[SC_AS * L + c]
            veps = Pf[PC_VEPS * L + c]
            S[WC_X * L + c] = S[SC_ZS * L + c] - S[SC_ZU * L + c]
            S[WC_V * L + c] = v
            S[WC_VSH * L + c] = 0.0 if abs(vs) < veps else vs
            S[WC_VH * L + c] = 0.0 if abs(v) < veps else v
            S[WC_VUH * L + c] = 0.0 if abs(vu) < veps else vu
            S[WC_ASH * L + c] = 0.0 if abs(a_s) < Pf[PC_AEPS * L + c] else a_s


@njit(error_model='numpy', cache=True)
def _law_phase(cid, S, Pf, dt):
    """Run the corner law: a current into ``WC_I``, or a desired force into ``WC_FDES``.

    Returns whether the inverse model must turn the force into a current. Same formulas as
    :func:`~mr_suspension.control.laws.controller_step` (FEBC: ``febc.febc_step``, its
    smoothing ``exp`` at a zero crossing done per lane).
    """
    two = L
    if cid == laws.CTRL_CONSTANT:
        for c in range(two):
            S[WC_I * L + c] = Pf[PC_CURRENT * L + c]
        return False
    if cid == laws.CTRL_SKYHOOK_ONOFF:
        for c in range(two):
            on = S[WC_VSH * L + c] * S[WC_VH * L + c] > 0.0
            S[WC_I * L + c] = Pf[PC_IMAX * L + c] if on else Pf[PC_IMIN * L + c]
        return False
    if cid == laws.CTRL_ADD:
        for c in range(two):
            on = S[WC_ASH * L + c] * S[WC_VH * L + c] > 0.0
            S[WC_I * L + c] = Pf[PC_IMAX * L + c] if on else Pf[PC_IMIN * L + c]
        return False
    if cid == laws.CTRL_SH_ADD:
        for c in range(two):
            a = Pf[PC_SHA * L + c]
            v_s = S[WC_VSH * L + c]
            v = S[WC_VH * L + c]
            a_s = S[WC_ASH * L + c]
            on_add = a_s * v > 0.0
            on_sh = v_s * v > 0.0
            on = on_add if v_s * v_s - a * a * a_s * a_s <= 0.0 else on_sh
            S[WC_I * L + c] = Pf[PC_IMAX * L + c] if on else Pf[PC_IMIN * L + c]
        return False
    if cid == laws.CTRL_SKYHOOK:
        for c in range(two):
            S[WC_FDES * L + c] = Pf[PC_CSKY * L + c] * S[WC_VSH * L + c]
        return True
    if cid == laws.CTRL_GROUNDHOOK:
        for c in range(two):
            S[WC_FDES * L + c] = -Pf[PC_CGND * L + c] * S[WC_VUH * L + c]
        return True
    if cid == laws.CTRL_HYBRID:
        for c in range(two):
            v = S[WC_VH * L + c]
            f_sky = Pf[PC_CSKY * L + c] * S[WC_VSH * L + c]
            f_sky = 0.0 if f_sky * v <= 0.0 else f_sky
            f_gnd = -Pf[PC_CGND * L + c] * S[WC_VUH * L + c]
            f_gnd = 0.0 if f_gnd * v <= 0.0 else f_gnd
            al = Pf[PC_ALPHA * L + c]
            S[WC_FDES * L + c] = al * f_sky + (1.0 - al) * f_gnd
        return True
    if cid == laws.CTRL_PDD:
        for c in range(two):
            S[WC_FDES * L + c] = -Pf[PC_KSC * L + c] * S[WC_X * L + c]
        return True
    if cid == laws.CTRL_CLIPPED_OPTIMAL:
        for c in range(two):
            a_s = S[WC_ASH * L + c]
            d_tyre = -(Pf[PC_MSC * L + c] * a_s + Pf[PC_MUC * L + c] * S[SC_AU * L + c]) \
                / Pf[PC_KTC * L + c]
            S[WC_FDES * L + c] = -(Pf[PC_K0 * L + c] * S[WC_X * L + c]
                                   + Pf[PC_K1 * L + c] * S[WC_VSH * L + c]
                                   + Pf[PC_K2 * L + c] * d_tyre
                                   + Pf[PC_K3 * L + c] * S[WC_VUH * L + c])
        return True
    if cid == laws.CTRL_FEBC:
        nfix = 0
        for c in range(two):
            x = S[WC_X * L + c]
            mean = S[SC_FMEAN * L + c]
            mean += dt / FEBC_TAU_MEAN * (x - mean)
            S[SC_FMEAN * L + c] = mean
            y = x - mean
            tc = S[SC_FTC * L + c] + dt
            sign = S[SC_FSIGN * L + c]
            band = Pf[PC_XBAND * L + c]
            new = sign
            new = 1.0 if y > band else new
            new = -1.0 if y < -band else new
            cross = new != sign
            upd = cross & (sign != 0.0)
            fest = S[SC_FEST * L + c]
            f = 0.5 / tc
            fix = upd & (fest > 0.0)
            S[WC_HALF * L + c] = tc
            S[WC_FHALF * L + c] = f
            S[WC_FDES * L + c] = 1.0 if fix else 0.0
            nfix += 1 if fix else 0
            fest = f if upd & (fest <= 0.0) else fest
            S[SC_FEST * L + c] = fest
            tc = 0.0 if cross else tc
            S[SC_FTC * L + c] = tc
            S[SC_FSIGN * L + c] = new
            f_cap = 0.5 / tc
            f_est = f_cap if (tc > 0.0) & (fest > f_cap) else fest
            i = Pf[PC_IROAD * L + c]
            i = Pf[PC_IMIN * L + c] if f_est < Pf[PC_F2 * L + c] else i
            i = Pf[PC_IBODY * L + c] if f_est < Pf[PC_F1 * L + c] else i
            S[WC_I * L + c] = i
        if nfix > 0:
            for c in range(two):
                if S[WC_FDES * L + c] != 0.0:
                    fest = S[SC_FEST * L + c]
                    half = S[WC_HALF * L + c]
                    fest += (1.0 - math.exp(-half / Pf[PC_FTAU * L + c])) \
                        * (S[WC_FHALF * L + c] - fest)
                    S[SC_FEST * L + c] = fest
                    i = Pf[PC_IROAD * L + c]
                    if fest < Pf[PC_F2 * L + c]:
                        i = Pf[PC_IMIN * L + c]
                    if fest < Pf[PC_F1 * L + c]:
                        i = Pf[PC_IBODY * L + c]
                    S[WC_I * L + c] = i
        return False
    for c in range(two):
        S[WC_I * L + c] = Pf[PC_IMIN * L + c]
    return False


@njit(error_model='numpy', cache=True)
def _strut_lane(S, Pf, c, f_d, c_d, h):
    """Strut, end-stop and tyre forces of one lane and its corner's share of the matrix.

    Per corner (``full_car.full_car_step``, same operations): ``e = dt/2 c + dt^2/4 k``,
    the wheel's diagonal ``w = e + e_a + m_u + dt/2 c_t + dt^2/4 k_t``, the strut's
    generalised force with its ``-dt/2 K v`` share, ``phi = S - m_s g - dt/2 k v``, and the
    wheel's ``f_t - S - m_u g + dt/2 (k v - k_t v_u)`` (the anti-roll bar is added per axle).
    """
    hh = 0.5 * h
    qh = 0.25 * h * h
    ms = Pf[PC_MS * L + c]
    mu = Pf[PC_MU * L + c]
    g = Pf[PC_G * L + c]
    k_s = Pf[PC_KS * L + c]
    k_stop = Pf[PC_KSTOP * L + c]
    x_max = Pf[PC_XMAX * L + c]
    x_min = Pf[PC_XMIN * L + c]
    x = S[WC_X * L + c]
    v = S[WC_V * L + c]
    vu = S[SC_VU * L + c]
    zu = S[SC_ZU * L + c]
    above = x > x_max
    below = x < x_min
    f_stop = k_stop * (x - x_max) if above else (k_stop * (x - x_min) if below else 0.0)
    k_x = k_s + k_stop if (above or below) else k_s
    sf = ms * g + Pf[PC_FD0 * L + c] - k_s * x - f_d - f_stop
    kt0 = Pf[PC_KT * L + c]
    ct0 = Pf[PC_CT * L + c]
    f_lin = (ms + mu) * g + kt0 * (S[WC_ZR * L + c] - zu) + ct0 * (S[WC_ZRD * L + c] - vu)
    contact = f_lin > 0.0
    kt = kt0 if contact else 0.0
    ct = ct0 if contact else 0.0
    f_t = f_lin if contact else 0.0
    e = hh * c_d + qh * k_x
    hk = hh * (k_x * v)
    S[WC_E * L + c] = e
    S[WC_WD * L + c] = e + Pf[PC_EA * L + c] + (mu + hh * ct + qh * kt)
    S[WC_PHI * L + c] = sf - ms * g - hk
    S[WC_RW * L + c] = f_t - sf - mu * g + hk - hh * (kt * vu)
    S[WC_FTL * L + c] = f_lin
    S[WC_KT * L + c] = kt
    S[WC_CT * L + c] = ct


@njit(error_model='numpy', cache=True)
def _struts_phase(S, Pf, h):
    """:func:`_strut_lane` over the lanes."""
    for c in range(L):
        _strut_lane(S, Pf, c, S[WC_FD * L + c], S[WC_CD * L + c], h)


@njit(error_model='numpy', cache=True)
def _axle(wl, wr, ea, ul0, ul1, ul2, ur0, ur1, ur2, rl, rr):
    """``A_ww^-1 A_wr`` rows and ``A_ww^-1 b_w`` of one axle's 2 x 2 wheel block.

    ``[[wl, -ea], [-ea, wr]]^-1 = [[wr, ea], [ea, wl]] / (wl wr - ea^2)``.
    """
    idet = 1.0 / (wl * wr - ea * ea)
    gl0 = (wr * ul0 + ea * ur0) * idet
    gl1 = (wr * ul1 + ea * ur1) * idet
    gl2 = (wr * ul2 + ea * ur2) * idet
    gr0 = (ea * ul0 + wl * ur0) * idet
    gr1 = (ea * ul1 + wl * ur1) * idet
    gr2 = (ea * ul2 + wl * ur2) * idet
    yl = (wr * rl + ea * rr) * idet
    yr = (ea * rl + wl * rr) * idet
    return gl0, gl1, gl2, gr0, gr1, gr2, yl, yr


@njit(error_model='numpy', cache=True)
def _body_phase(S, Pf, B, Pb, h):
    """Coupled body: wheel elimination, 3 x 3 Schur complement, update (module doc).

    ``full_car.full_car_step`` unrolled for ``nb = 3``, the same operations in the same
    order, less the exact no-ops of the rigid body's map ``T_i = (1, -x_i, y_i)``: products
    with ``T_i0 = 1`` and the terms of the anti-roll bars' ``d_a = (0, 0, t_a)`` that are
    ``0`` (adding or multiplying them changes no bit). Writes the wheels' velocity increments
    (``WC_DVU``) and the new body points above the corners (``SC_ZS``, ``SC_VS``, ``SC_AS``:
    ``T_i r`` and its rates).
    """
    hh = 0.5 * h
    ih = 1.0 / h
    for c in range(W):
        c1 = W + c
        c2 = 2 * W + c
        c3 = 3 * W + c
        e0 = S[WC_E * L + c]
        e1 = S[WC_E * L + c1]
        e2 = S[WC_E * L + c2]
        e3 = S[WC_E * L + c3]
        t01 = Pf[PC_T1 * L + c]
        t02 = Pf[PC_T2 * L + c]
        t11 = Pf[PC_T1 * L + c1]
        t12 = Pf[PC_T2 * L + c1]
        t21 = Pf[PC_T1 * L + c2]
        t22 = Pf[PC_T2 * L + c2]
        t31 = Pf[PC_T1 * L + c3]
        t32 = Pf[PC_T2 * L + c3]
        df2 = Pb[PB_DF2 * W + c]
        dr2 = Pb[PB_DR2 * W + c]
        ef = Pb[PB_EF * W + c]
        er = Pb[PB_ER * W + c]
        kf = Pb[PB_KF * W + c]
        kr = Pb[PB_KR * W + c]
        # Anti-roll bars: -k (x_L - x_R) - dt/2 k (v_L - v_R) along d = T_L - T_R.
        psi_f = -(kf * (S[WC_X * L + c] - S[WC_X * L + c1])
                  + hh * (kf * (S[WC_V * L + c] - S[WC_V * L + c1])))
        psi_r = -(kr * (S[WC_X * L + c2] - S[WC_X * L + c3])
                  + hh * (kr * (S[WC_V * L + c2] - S[WC_V * L + c3])))
        # Body-wheel columns u_i = -e_i T_i -+ e_a d_a, wheel right-hand sides, elimination.
        r0 = h * (S[WC_RW * L + c] - psi_f)
        r1 = h * (S[WC_RW * L + c1] + psi_f)
        r2 = h * (S[WC_RW * L + c2] - psi_r)
        r3 = h * (S[WC_RW * L + c3] + psi_r)
        u00 = -e0
        u01 = -(e0 * t01)
        u02 = -(e0 * t02 + ef * df2)
        u10 = -e1
        u11 = -(e1 * t11)
        u12 = ef * df2 - e1 * t12
        u20 = -e2
        u21 = -(e2 * t21)
        u22 = -(e2 * t22 + er * dr2)
        u30 = -e3
        u31 = -(e3 * t31)
        u32 = er * dr2 - e3 * t32
        g00, g01, g02, g10, g11, g12, y0, y1 = _axle(
            S[WC_WD * L + c], S[WC_WD * L + c1], ef, u00, u01, u02, u10, u11, u12, r0, r1)
        g20, g21, g22, g30, g31, g32, y2, y3 = _axle(
            S[WC_WD * L + c2], S[WC_WD * L + c3], er, u20, u21, u22, u30, u31, u32, r2, r3)
        # Schur complement (lower triangle): A_rr - A_rw A_ww^-1 A_wr, with
        # A_rr = sum_i e_i T_i T_i^T + sum_a e_a d_a d_a^T + M.
        s00 = (e0 + e1 + e2 + e3 + Pb[PB_M0 * W + c]) \
            - (u00 * g00 + u10 * g10 + u20 * g20 + u30 * g30)
        s10 = (e0 * t01 + e1 * t11 + e2 * t21 + e3 * t31) \
            - (u01 * g00 + u11 * g10 + u21 * g20 + u31 * g30)
        s11 = (e0 * t01 * t01 + e1 * t11 * t11 + e2 * t21 * t21 + e3 * t31 * t31
               + Pb[PB_M1 * W + c]) \
            - (u01 * g01 + u11 * g11 + u21 * g21 + u31 * g31)
        s20 = (e0 * t02 + e1 * t12 + e2 * t22 + e3 * t32) \
            - (u02 * g00 + u12 * g10 + u22 * g20 + u32 * g30)
        s21 = (e0 * t02 * t01 + e1 * t12 * t11 + e2 * t22 * t21 + e3 * t32 * t31) \
            - (u02 * g01 + u12 * g11 + u22 * g21 + u32 * g31)
        s22 = (e0 * t02 * t02 + e1 * t12 * t12 + e2 * t22 * t22 + e3 * t32 * t32
               + ef * df2 * df2 + er * dr2 * dr2 + Pb[PB_M2 * W + c]) \
            - (u02 * g02 + u12 * g12 + u22 * g22 + u32 * g32)
        p0 = S[WC_PHI * L + c]
        p1 = S[WC_PHI * L + c1]
        p2 = S[WC_PHI * L + c2]
        p3 = S[WC_PHI * L + c3]
        b0 = h * (p0 + p1 + p2 + p3) - (u00 * y0 + u10 * y1 + u20 * y2 + u30 * y3)
        b1 = h * (t01 * p0 + t11 * p1 + t21 * p2 + t31 * p3) \
            - (u01 * y0 + u11 * y1 + u21 * y2 + u31 * y3)
        b2 = h * (t02 * p0 + t12 * p1 + t22 * p2 + t32 * p3 + df2 * psi_f + dr2 * psi_r) \
            - (u02 * y0 + u12 * y1 + u22 * y2 + u32 * y3)
        # L D L^T (c_jk = l_jk d_k), forward, diagonal and back substitution.
        i0 = 1.0 / s00
        l10 = s10 * i0
        i1 = 1.0 / (s11 - s10 * l10)
        l20 = s20 * i0
        c21 = s21 - s20 * l10
        l21 = c21 * i1
        i2 = 1.0 / (s22 - s20 * l20 - c21 * l21)
        b1 -= l10 * b0
        b2 = b2 - l20 * b0 - l21 * b1
        x2 = b2 * i2
        x1 = b1 * i1 - l21 * x2
        x0 = b0 * i0 - l10 * x1 - l20 * x2
        # Wheels: dz_u' = A_ww^-1 b_w - (A_ww^-1 A_wr) dr.
        S[WC_DVU * L + c] = y0 - (g00 * x0 + g01 * x1 + g02 * x2)
        S[WC_DVU * L + c1] = y1 - (g10 * x0 + g11 * x1 + g12 * x2)
        S[WC_DVU * L + c2] = y2 - (g20 * x0 + g21 * x1 + g22 * x2)
        S[WC_DVU * L + c3] = y3 - (g30 * x0 + g31 * x1 + g32 * x2)
        v0 = B[SB_V0 * W + c]
        v1 = B[SB_V1 * W + c]
        v2 = B[SB_V2 * W + c]
        q0 = B[SB_R0 * W + c] + h * (v0 + 0.5 * x0)
        q1 = B[SB_R1 * W + c] + h * (v1 + 0.5 * x1)
        q2 = B[SB_R2 * W + c] + h * (v2 + 0.5 * x2)
        w0 = v0 + x0
        w1 = v1 + x1
        w2 = v2 + x2
        a0 = x0 * ih
        a1 = x1 * ih
        a2 = x2 * ih
        B[SB_R0 * W + c] = q0
        B[SB_R1 * W + c] = q1
        B[SB_R2 * W + c] = q2
        B[SB_V0 * W + c] = w0
        B[SB_V1 * W + c] = w1
        B[SB_V2 * W + c] = w2
        B[SB_A0 * W + c] = a0
        B[SB_A1 * W + c] = a1
        B[SB_A2 * W + c] = a2
        # Body points above the corners (full_car.corner_motion, same sums).
        S[SC_ZS * L + c] = q0 + t01 * q1 + t02 * q2
        S[SC_ZS * L + c1] = q0 + t11 * q1 + t12 * q2
        S[SC_ZS * L + c2] = q0 + t21 * q1 + t22 * q2
        S[SC_ZS * L + c3] = q0 + t31 * q1 + t32 * q2
        S[SC_VS * L + c] = w0 + t01 * w1 + t02 * w2
        S[SC_VS * L + c1] = w0 + t11 * w1 + t12 * w2
        S[SC_VS * L + c2] = w0 + t21 * w1 + t22 * w2
        S[SC_VS * L + c3] = w0 + t31 * w1 + t32 * w2
        S[SC_AS * L + c] = a0 + t01 * a1 + t02 * a2
        S[SC_AS * L + c1] = a0 + t11 * a1 + t12 * a2
        S[SC_AS * L + c2] = a0 + t21 * a1 + t22 * a2
        S[SC_AS * L + c3] = a0 + t31 * a1 + t32 * a2


@njit(error_model='numpy', cache=True)
def _uncoupled_axle(S, Pf, h, cl, cr):
    """One axle of the uncoupled body (``T = I``, no bar): ``full_car_step`` with its zeros.

    Each corner's body coordinate meets only its wheel, so the Schur complement is diagonal;
    what remains of the general step is, per corner, ``u = -e``, ``g = w' u / (w w')``,
    ``y = w' r / (w w')`` (``w'`` the other wheel's diagonal) and ``s = m + e - u g``.
    """
    w_l = S[WC_WD * L + cl]
    w_r = S[WC_WD * L + cr]
    idet = 1.0 / (w_l * w_r)
    for c, w_o in ((cl, w_r), (cr, w_l)):
        e = S[WC_E * L + c]
        u = -e
        gg = (w_o * u) * idet
        y = (w_o * (h * S[WC_RW * L + c])) * idet
        dvs = (h * S[WC_PHI * L + c] - u * y) * (1.0 / (e + Pf[PC_MB * L + c] - u * gg))
        S[WC_DVU * L + c] = y - gg * dvs
        vs = S[SC_VS * L + c]
        S[SC_ZS * L + c] += h * (vs + 0.5 * dvs)
        S[SC_VS * L + c] = vs + dvs
        S[SC_AS * L + c] = dvs * (1.0 / h)


@njit(error_model='numpy', cache=True)
def _uncoupled_phase(S, Pf, B, h):
    """Four independent bodies on their corners; the heave figures are front left's."""
    for c in range(W):
        _uncoupled_axle(S, Pf, h, c, W + c)
        _uncoupled_axle(S, Pf, h, 2 * W + c, 3 * W + c)
        B[SB_A0 * W + c] = S[SC_AS * L + c]


@njit(error_model='numpy', cache=True)
def _wheels_phase(S, Pf, h):
    """Wheel update, tyre force at mid-step (``quarter_car.tyre_mid``), corner metrics."""
    ih = 1.0 / h
    for c in range(L):
        dvu = S[WC_DVU * L + c]
        vu = S[SC_VU * L + c]
        kt = S[WC_KT * L + c]
        f_t = S[WC_FTL * L + c] - kt * h * (0.5 * vu + 0.25 * dvu) - 0.5 * S[WC_CT * L + c] * dvu
        f_t = f_t if (kt > 0.0 and not f_t < 0.0) else 0.0
        zu = S[SC_ZU * L + c] + h * (vu + 0.5 * dvu)
        S[SC_ZU * L + c] = zu
        S[SC_VU * L + c] = vu + dvu
        S[SC_AU * L + c] = dvu * ih
        x = S[SC_ZS * L + c] - zu
        dft = f_t - Pf[PC_FT0 * L + c]
        S[SC_X2 * L + c] += x * x
        S[SC_XMAX * L + c] = max(S[SC_XMAX * L + c], abs(x))
        S[SC_DF2 * L + c] += dft * dft
        S[SC_FTMIN * L + c] = min(S[SC_FTMIN * L + c], f_t)
        S[SC_EN * L + c] += S[WC_FD * L + c] * S[WC_V * L + c] * h


@njit(error_model='numpy', cache=True)
def _comfort_phase(B, Pb, wk, we):
    """ISO 2631-1 weightings (Wk at the CG and the seat, We on pitch and roll), body metrics.

    ``a_seat = a_z - x_seat theta'' + y_seat phi''``; each filter is its second-order
    sections in direct form II transposed (``metrics.sos_step``), unrolled.
    """
    k00, k01, k02, k04, k05 = wk[0, 0], wk[0, 1], wk[0, 2], wk[0, 4], wk[0, 5]
    k10, k11, k12, k14, k15 = wk[1, 0], wk[1, 1], wk[1, 2], wk[1, 4], wk[1, 5]
    k20, k21, k22, k24, k25 = wk[2, 0], wk[2, 1], wk[2, 2], wk[2, 4], wk[2, 5]
    k30, k31, k32, k34, k35 = wk[3, 0], wk[3, 1], wk[3, 2], wk[3, 4], wk[3, 5]
    e00, e01, e02, e04, e05 = we[0, 0], we[0, 1], we[0, 2], we[0, 4], we[0, 5]
    e10, e11, e12, e14, e15 = we[1, 0], we[1, 1], we[1, 2], we[1, 4], we[1, 5]
    e20, e21, e22, e24, e25 = we[2, 0], we[2, 1], we[2, 2], we[2, 4], we[2, 5]
    for c in range(W):
        a_z = B[SB_A0 * W + c]
        a_p = B[SB_A1 * W + c]
        a_r = B[SB_A2 * W + c]
        a_seat = a_z - Pb[PB_SX * W + c] * a_p + Pb[PB_SY * W + c] * a_r
        # Wk at the CG.
        x = a_z
        y = k00 * x + B[SB_K0 * W + c]
        B[SB_K0 * W + c] = k01 * x - k04 * y + B[SB_K1 * W + c]
        B[SB_K1 * W + c] = k02 * x - k05 * y
        x = y
        y = k10 * x + B[SB_K2 * W + c]
        B[SB_K2 * W + c] = k11 * x - k14 * y + B[SB_K3 * W + c]
        B[SB_K3 * W + c] = k12 * x - k15 * y
        x = y
        y = k20 * x + B[SB_K4 * W + c]
        B[SB_K4 * W + c] = k21 * x - k24 * y + B[SB_K5 * W + c]
        B[SB_K5 * W + c] = k22 * x - k25 * y
        x = y
        y = k30 * x + B[SB_K6 * W + c]
        B[SB_K6 * W + c] = k31 * x - k34 * y + B[SB_K7 * W + c]
        B[SB_K7 * W + c] = k32 * x - k35 * y
        y_cg = y
        # Wk at the seat.
        x = a_seat
        y = k00 * x + B[SB_S0 * W + c]
        B[SB_S0 * W + c] = k01 * x - k04 * y + B[SB_S1 * W + c]
        B[SB_S1 * W + c] = k02 * x - k05 * y
        x = y
        y = k10 * x + B[SB_S2 * W + c]
        B[SB_S2 * W + c] = k11 * x - k14 * y + B[SB_S3 * W + c]
        B[SB_S3 * W + c] = k12 * x - k15 * y
        x = y
        y = k20 * x + B[SB_S4 * W + c]
        B[SB_S4 * W + c] = k21 * x - k24 * y + B[SB_S5 * W + c]
        B[SB_S5 * W + c] = k22 * x - k25 * y
        x = y
        y = k30 * x + B[SB_S6 * W + c]
        B[SB_S6 * W + c] = k31 * x - k34 * y + B[SB_S7 * W + c]
        B[SB_S7 * W + c] = k32 * x - k35 * y
        y_seat = y
        # We on pitch.
        x = a_p
        y = e00 * x + B[SB_P0 * W + c]
        B[SB_P0 * W + c] = e01 * x - e04 * y + B[SB_P1 * W + c]
        B[SB_P1 * W + c] = e02 * x - e05 * y
        x = y
        y = e10 * x + B[SB_P2 * W + c]
        B[SB_P2 * W + c] = e11 * x - e14 * y + B[SB_P3 * W + c]
        B[SB_P3 * W + c] = e12 * x - e15 * y
        x = y
        y = e20 * x + B[SB_P4 * W + c]
        B[SB_P4 * W + c] = e21 * x - e24 * y + B[SB_P5 * W + c]
        B[SB_P5 * W + c] = e22 * x - e25 * y
        y_p = y
        # We on roll.
        x = a_r
        y = e00 * x + B[SB_Q0 * W + c]
        B[SB_Q0 * W + c] = e01 * x - e04 * y + B[SB_Q1 * W + c]
        B[SB_Q1 * W + c] = e02 * x - e05 * y
        x = y
        y = e10 * x + B[SB_Q2 * W + c]
        B[SB_Q2 * W + c] = e11 * x - e14 * y + B[SB_Q3 * W + c]
        B[SB_Q3 * W + c] = e12 * x - e15 * y
        x = y
        y = e20 * x + B[SB_Q4 * W + c]
        B[SB_Q4 * W + c] = e21 * x - e24 * y + B[SB_Q5 * W + c]
        B[SB_Q5 * W + c] = e22 * x - e25 * y
        y_r = y
        B[(SB_ACC + 0) * W + c] += a_z * a_z
        B[(SB_ACC + 1) * W + c] += y_cg * y_cg
        B[(SB_ACC + 2) * W + c] += y_seat * y_seat
        B[(SB_ACC + 3) * W + c] += y_seat * y_seat * y_seat * y_seat
        B[(SB_ACC + 4) * W + c] += y_p * y_p
        B[(SB_ACC + 5) * W + c] += y_r * y_r
        B[(SB_ACC + 6) * W + c] += a_p * a_p
        B[(SB_ACC + 7) * W + c] += a_r * a_r


@njit(error_model='numpy', cache=True)
def _modal_phase(S, Pf, B, Pb, dt):
    """Modal sky-hook (``modal.modal_step``): the corners' desired forces ``G Q_des``.

    ``v_z = lam v_z + dt a_z`` with the heave acceleration of the step before, then
    ``F_des,i = (G_i0 c_heave) v_z + (G_i1 c_pitch) w_pitch + (G_i2 c_roll) w_roll``.
    """
    for c in range(W):
        mv = Pb[PB_MLAM * W + c] * B[SB_MV * W + c] + dt * B[SB_A0 * W + c]
        B[SB_MV * W + c] = mv
        w_p = B[SB_V1 * W + c]
        w_r = B[SB_V2 * W + c]
        for i in range(N_CORNERS):
            j = i * W + c
            S[WC_FDES * L + j] = (Pf[PC_G0 * L + j] * mv + Pf[PC_G1 * L + j] * w_p
                                  + Pf[PC_G2 * L + j] * w_r)


@njit(error_model='numpy', cache=True)
def _command_phase(S, Pf, ring, slot, road_z, road_zd, k):
    """Clamp the commands (``laws.clamp_current``) into the delay line; road at mid-step."""
    for c in range(L):
        i_cmd = S[WC_I * L + c]
        i_min = Pf[PC_IMIN * L + c]
        i_max = Pf[PC_IMAX * L + c]
        i_cmd = i_max if i_cmd > i_max else i_cmd
        i_cmd = i_min if i_cmd < i_min else i_cmd
        i_cmd = i_cmd if i_cmd == i_cmd else i_min
        ring[slot, c] = i_cmd
    for i in range(N_CORNERS):
        z_r = 0.5 * (road_z[i, k] + road_z[i, k + 1])
        zr_dot = 0.5 * (road_zd[i, k] + road_zd[i, k + 1])
        for c in range(i * W, (i + 1) * W):
            S[WC_ZR * L + c] = z_r
            S[WC_ZRD * L + c] = zr_dot


@njit(error_model='numpy', cache=True)
def _chunk(law, coupled, est, dlaws, ilaws, delays, m, P, Pb, cps, road_z, road_zd, wk, we,
           dt, acc):
    """Run ``m`` cars (``W`` lanes, the rest padding) of one branch-uniform group."""
    Pf = P.ravel().copy()
    Pbf = Pb.ravel().copy()
    S = np.zeros(SC_ROWS * L)
    B = np.zeros(SB_ROWS * W)
    for c in range(L):
        S[SC_FTMIN * L + c] = 1e300
    lmax = 1
    for i in range(N_CORNERS):
        lmax = max(lmax, delays[i] + 1)
    same_delay = delays[0] == delays[1] == delays[2] == delays[3]
    same_dlaw = dlaws[0] == dlaws[1] == dlaws[2] == dlaws[3]
    same_ilaw = ilaws[0] == ilaws[1] == ilaws[2] == ilaws[3]
    ring = np.zeros((lmax, L))
    fs = np.zeros(laws.N_CTRL_STATE)
    h = dt
    # Laws that read no velocity need no estimate (it feeds nothing else).
    estimate = est == 0 and law != laws.CTRL_CONSTANT and law != laws.CTRL_FEBC
    n = road_z.shape[1] - 1
    for k in range(n):
        # 1. Measurements and estimation; 2. the law; 3. the inverse model.
        _measure_phase(estimate, S, Pf, dt)
        if law == MODAL:
            _modal_phase(S, Pf, B, Pbf, dt)
            inverse = True
        else:
            inverse = _law_phase(law, S, Pf, dt)
        if inverse:
            if same_ilaw:
                _inverse_phase(ilaws[0], S, Pf, cps, fs, 0, L, dt)
            else:
                for i in range(N_CORNERS):
                    _inverse_phase(ilaws[i], S, Pf, cps, fs, i * W, (i + 1) * W, dt)
        # 4. Clamp (laws.clamp_current), into the delay line; road under each wheel.
        _command_phase(S, Pf, ring, k % lmax, road_z, road_zd, k)
        # 5. Driver, fluid and damper force at the delayed command.
        if same_delay and same_dlaw:
            _damper_phase(dlaws[0], S, Pf, ring, (k - delays[0]) % lmax, 0, L)
        else:
            for i in range(N_CORNERS):
                _damper_phase(dlaws[i], S, Pf, ring, (k - delays[i]) % lmax, i * W,
                              (i + 1) * W)
        # 6. Plant: struts and tyres, body solve, wheels; comfort and metrics.
        _struts_phase(S, Pf, h)
        if coupled:
            _body_phase(S, Pf, B, Pbf, h)
        else:
            _uncoupled_phase(S, Pf, B, h)
        _wheels_phase(S, Pf, h)
        _comfort_phase(B, Pbf, wk, we)
    for c in range(m):
        for j in range(N_BODY_ACC):
            acc[c, j] = B[(SB_ACC + j) * W + c]
        for i in range(N_CORNERS):
            o = N_BODY_ACC + N_CORNER_ACC * i
            lane = i * W + c
            acc[c, o] = S[SC_X2 * L + lane]
            acc[c, o + 1] = S[SC_XMAX * L + lane]
            acc[c, o + 2] = S[SC_DF2 * L + lane]
            acc[c, o + 3] = S[SC_FTMIN * L + lane]
            acc[c, o + 4] = S[SC_EN * L + lane]


@njit(parallel=True, cache=True)
def _run_chunks(keys, starts, stops, P, Pb, cps, roads_z, roads_zd, wk, we, dt, acc):
    for j in prange(starts.shape[0]):
        a, b = starts[j], stops[j]
        m = b - a
        block = np.empty((PC_ROWS, L))
        body = np.empty((PB_ROWS, W))
        cp = np.empty((L, cps.shape[2]))
        for c in range(W):
            src = a + min(c, m - 1)  # pad with the chunk's last car
            body[:, c] = Pb[:, src]
            for i in range(N_CORNERS):
                block[:, i * W + c] = P[:, i, src]
                cp[i * W + c] = cps[src, i]
        key = keys[j]
        _chunk(key[1], key[2] != 0, key[3], key[4:8], key[8:12], key[12:16], m, block, body,
               cp, roads_z[key[0]], roads_zd[key[0]], wk, we, dt, acc[a:b])


def run(configs, road_index, roads_z, roads_zd, dt, wk, we):
    """Run full cars that :func:`eligible` accepts; returns their sums (cars x ``N_ACC``).

    ``roads_z``, ``roads_zd``: (roads x 4 x samples); the sums are laid out as
    :func:`~mr_suspension.sim.full_car_sim.full_car_loop`'s ``acc``. Cars are grouped by
    (road, law, body kind, estimation, damper and inverse laws, delays) so each chunk is
    branch-uniform, and groups are split so that every thread has work.
    """
    if wk.shape[0] != 4 or we.shape[0] != 3:
        raise ValueError('full-car batch kernel expects the 4-section Wk and 3-section We '
                         'filters')
    nc = len(configs)
    memo = {}
    cols = [_car_columns(cfg, memo) for cfg in configs]
    P = np.empty((PC_ROWS, N_CORNERS, nc))
    Pb = np.empty((PB_ROWS, nc))
    ncp = max(cp.size for col in cols for cp in col[2])
    cps = np.zeros((nc, N_CORNERS, ncp))
    full = np.empty((nc, 16), dtype=np.int64)
    full[:, 0] = np.asarray(road_index, dtype=np.int64)
    for c, (pc, pb, cp, key) in enumerate(cols):
        P[:, :, c] = pc
        Pb[:, c] = pb
        for i in range(N_CORNERS):
            cps[c, i, :cp[i].size] = cp[i]
        full[c, 1:] = key
    order = np.lexsort(full.T[::-1])
    full = full[order]
    P = np.ascontiguousarray(P[:, :, order])
    Pb = np.ascontiguousarray(Pb[:, order])
    cps = np.ascontiguousarray(cps[order])
    bounds = [0] + [j for j in range(1, nc) if (full[j] != full[j - 1]).any()] + [nc]
    n_groups = len(bounds) - 1
    threads = get_num_threads()
    starts, stops = [], []
    for a, b in zip(bounds[:-1], bounds[1:]):
        size = b - a
        pieces = max(-(-size // W), min(-(-threads // n_groups), -(-size // 2)))
        step = -(-size // pieces)
        for s in range(a, b, step):
            starts.append(s)
            stops.append(min(s + step, b))
    starts = np.array(starts, dtype=np.int64)
    stops = np.array(stops, dtype=np.int64)
    acc = np.zeros((nc, N_ACC))
    _run_chunks(np.ascontiguousarray(full[starts]), starts, stops, P, Pb, cps,
                np.ascontiguousarray(roads_z), np.ascontiguousarray(roads_zd), wk, we, dt, acc)
    out = np.empty_like(acc)
    out[order] = acc
    return out
