"""Optimal references: the LQ gain of the clipped-optimal law and an offline semi-active bound.

LQ design (Dyke et al. 1996 use the same H2/LQG idea with the damper as an ideal actuator):
state ``X = [x, v_s, d, v_u]`` with stroke ``x = z_s - z_u``, tyre deflection ``d = z_u - z_r``,
damper force ``u`` (the body feels ``-u``, the wheel ``+u``)::

    x' = v_s - v_u,  m_s v_s' = -k_s x - u,  d' = v_u - z_r',
    m_u v_u' = k_s x + u - k_t d - c_t (v_u - z_r')

and the cost ``J = int q_a a_s^2 + q_x x^2 + q_d d^2 + r u^2 dt`` with ``a_s = (-k_s x - u)/m_s``
(a cross term ``N``). ``K = R^-1 (B^T P + N^T)`` from the continuous algebraic Riccati
equation; the active optimum is ``u = -K X``.

Offline semi-active bound (full knowledge of the road, ideal actuator, no delay): the current
trajectory ``i(t)``, piecewise constant on blocks of ``block`` seconds, that minimises a ride
index is found by L-BFGS-B with bounds ``[i_min, i_max]`` (finite-difference gradients, each
function value one jitted open-loop simulation with the simulator's step order). It is a
local optimum, so it is an *achievable* reference that no causal law with the same actuator
can be expected to beat by much; the gap between a law and this reference is a lower
estimate of the room left.
"""

import math

from numba import njit
import numpy as np
from scipy import linalg, optimize

from mr_suspension.core import damper as dmp
from mr_suspension.core.driver import DRIVER_STATE_SIZE, driver_step
from mr_suspension.core.metrics import sos_step, wk_sos
from mr_suspension.core.quarter_car import CAR_G, CAR_MS, CAR_MU, plant_step
from mr_suspension.core.quarter_car import ZS, ZU
from mr_suspension.core.validation import check_nonneg, check_positive

OBJECTIVES = ('body_acc_rms', 'body_acc_wk_rms', 'tyre_load_rms', 'working_space_rms')


def quarter_car_matrices(m_s, m_u, k_s, k_t, c_t):
    """Return ``(A, B, E)`` of ``X' = A X + B u + E z_r'`` (module doc)."""
    check_positive('quarter_car_matrices', m_s=m_s, m_u=m_u, k_s=k_s, k_t=k_t)
    check_nonneg('quarter_car_matrices', c_t=c_t)
    a = np.array([[0.0, 1.0, 0.0, -1.0],
                  [-k_s / m_s, 0.0, 0.0, 0.0],
                  [0.0, 0.0, 0.0, 1.0],
                  [k_s / m_u, 0.0, -k_t / m_u, -c_t / m_u]])
    b = np.array([[0.0], [-1.0 / m_s], [0.0], [1.0 / m_u]])
    e = np.array([[0.0], [0.0], [-1.0], [c_t / m_u]])
    return a, b, e


def lqr_gain(m_s, m_u, k_s, k_t, c_t, q_acc=1.0, q_x=1.0e3, q_d=1.0e3, r=1.0e-6):
    """LQ gain ``K`` (length 4) for ``u = -K [x, v_s, d, v_u]`` (module doc)."""
    check_nonneg('lqr_gain', q_acc=q_acc, q_x=q_x, q_d=q_d)
    check_positive('lqr_gain', r=r)
    a, b, _ = quarter_car_matrices(m_s, m_u, k_s, k_t, c_t)
    ca = np.array([[-k_s / m_s, 0.0, 0.0, 0.0]])
    da = -1.0 / m_s
    q = q_acc * ca.T @ ca + np.diag([q_x, 0.0, q_d, 0.0])
    rr = np.array([[q_acc * da * da + r]])
    n = q_acc * ca.T * da
    p = linalg.solve_continuous_are(a, b, q, rr, s=n)
    k = np.linalg.solve(rr, b.T @ p + n.T)
    return k.ravel()


@njit(cache=True)
def open_loop_cost(car_p, law, dp, drv_p, i_seq, block_n, road_z, road_zd, dt, sos, objective,
                   nstate):
    """Simulate with the current schedule ``i_seq`` (one value per block) and return the index.

    Same step order as :func:`~mr_suspension.sim.simulator.corner_loop` without controller:
    driver and fluid, damper force and tangent, plant with the road at mid-step.
    ``objective``: 0 body acc RMS, 1 Wk-weighted body acc RMS, 2 dynamic tyre load RMS,
    3 working space RMS.
    """
    n = road_z.shape[0] - 1
    ds = np.zeros(nstate)
    drv_s = np.zeros(DRIVER_STATE_SIZE)
    q = np.zeros(4)
    nsec = sos.shape[0]
    zi = np.zeros((nsec, 2))
    f_t0 = (car_p[CAR_MS] + car_p[CAR_MU]) * car_p[CAR_G]
    acc = 0.0
    nb = i_seq.shape[0]
    for k in range(n):
        b = k // block_n
        if b >= nb:
            b = nb - 1
        x = q[ZS] - q[ZU]
        v = q[2] - q[3]
        coil, f_field = driver_step(drv_p, drv_s, i_seq[b])
        f_d, c_d = dmp.damper_force(law, dp, ds, x, v, f_field, dt)
        z_r = 0.5 * (road_z[k] + road_z[k + 1])
        zr_dot = 0.5 * (road_zd[k] + road_zd[k + 1])
        a_s, a_u, f_t = plant_step(car_p, q, f_d, c_d, z_r, zr_dot, dt)
        if objective == 1:
            y = sos_step(sos, zi, a_s)
            acc += y * y
        elif objective == 2:
            acc += (f_t - f_t0) * (f_t - f_t0)
        elif objective == 3:
            xs = q[ZS] - q[ZU]
            acc += xs * xs
        else:
            acc += a_s * a_s
    return math.sqrt(acc / n)


def semi_active_bound(config, road, objective='body_acc_rms', block=0.02, x0=None,
                      maxiter=60):
    """Best current trajectory found offline for ``objective`` (module doc).

    ``config``: a :class:`~mr_suspension.sim.simulator.CornerConfig` (its controller is
    ignored; use an ideal driver and zero delay for the bound), ``road``: the road, known in
    full. ``x0``: initial schedule (per block) or ``None`` for the mid current. Returns
    ``(value, schedule, t_blocks)``.
    """
    if objective not in OBJECTIVES:
        raise ValueError(f'semi_active_bound: objective must be one of {OBJECTIVES}')
    check_positive('semi_active_bound', block=block)
    if abs(road.dt - config.dt) > 1e-12:
        raise ValueError('semi_active_bound: road and config must share dt')
    block_n = max(1, int(round(block / config.dt)))
    nb = int(math.ceil(road.n_steps / block_n))
    car_p, law, dp, drv_p, _, cp = config.arrays()
    i_lo, i_hi = float(cp[0]), float(cp[1])
    if x0 is None:
        x0 = np.full(nb, 0.5 * (i_lo + i_hi))
    x0 = np.clip(np.asarray(x0, dtype=float), i_lo, i_hi)
    if x0.shape != (nb,):
        raise ValueError(f'semi_active_bound: x0 must have {nb} blocks')
    sos = wk_sos(config.dt)
    obj = OBJECTIVES.index(objective)
    nstate = dmp.n_state_of(config.damper) + 8

    def cost(sched):
        return open_loop_cost(car_p, law, dp, drv_p, np.ascontiguousarray(sched), block_n,
                              road.z, road.zdot, config.dt, sos, obj, nstate)

    res = optimize.minimize(cost, x0, method='L-BFGS-B', bounds=[(i_lo, i_hi)] * nb,
                            options={'maxiter': maxiter, 'eps': 1e-4 * (i_hi - i_lo)})
    return float(res.fun), res.x, np.arange(nb) * block_n * config.dt


def schedule_from_run(i_cmd, dt, block, n_blocks):
    """Average a recorded command over blocks (warm start for :func:`semi_active_bound`)."""
    block_n = max(1, int(round(block / dt)))
    out = np.empty(n_blocks)
    for b in range(n_blocks):
        seg = i_cmd[b * block_n:(b + 1) * block_n]
        out[b] = seg.mean() if seg.size else i_cmd[-1]
    return out
