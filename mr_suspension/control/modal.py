"""Full-car control: modal sky-hook and the full car's clipped-optimal law.

The body's modal velocities come from what a car has at its centre of gravity: the vertical
accelerometer (gravity removed) integrated with the corner laws' leak
(:mod:`~mr_suspension.control.estimation`), ``v_z[k] = lam v_z[k-1] + dt a_z[k]``,
``lam = exp(-2 pi f_hp dt)``, and the gyroscope's pitch and roll rates. The sky-hook acts on
each mode (Karnopp, Crosby & Harwood 1974, applied per mode as in the full-vehicle studies
cited by seed 000, e.g. Choi, Lee & Park 2002):

    Q_des = -diag(c_heave, c_pitch, c_roll) r',    r = (z, theta, phi),

and the body feels ``-T^T F`` from damper forces ``F`` (``T`` the corner map of
:meth:`~mr_suspension.core.full_car.FullCarParams.body`), so the least-squares distribution
``F_des = T (T^T T)^-1 diag(c) r'`` gives each corner the force its MR damper is asked for;
each corner turns it into a current with its own stroke-rate estimate, inverse damper model
and passivity clip (:func:`~mr_suspension.control.laws.force_command`).

Clipped optimal for the full car (``modal_clipped_optimal``; the corner law's design of Dyke,
Spencer, Sain & Carlson 1996 on the whole car): state
``X = [x_1..4, d_1..4, r', v_u,1..4]`` (strokes, tyre deflections ``z_u - z_r``, body rates,
wheel velocities), damper forces ``u`` (the body feels ``-T^T u``, each wheel ``+u_i``)::

    x' = T r' - v_u,   d' = v_u - z_r',   M_b r'' = -T^T (K_x x + u),
    m_u v_u' = K_x x + u - k_t d - c_t (v_u - z_r')

(``K_x``: springs and anti-roll bars in stroke coordinates) and the cost
``J = int q_a |T r''|^2 + q_x |x|^2 + q_d |d|^2 + r |u|^2 dt`` (the body's accelerations at
the four corners, the corner law's weights). ``u = -K X`` with ``K`` from the continuous
algebraic Riccati equation with the cross term of ``r''``'s dependence on ``u``. The state is
estimated as the corner law does: strokes measured, body rates from the IMU, ``v_u,i`` the
body point's velocity ``T_i r'`` minus the corner's stroke-rate estimate, and the tyre
deflection from Newton's law on the corner, ``d_i = -(m_s,i a_s,i + m_u a_u,i) / k_t``.
"""

from dataclasses import asdict, dataclass
import math

from numba import njit
import numpy as np
from scipy import linalg

from mr_suspension.control import laws
from mr_suspension.core.full_car import N_CORNERS
from mr_suspension.core.validation import check_declared, check_nonneg, check_positive, param

MODAL_LAWS = ('modal_skyhook', 'modal_clipped_optimal')
# Gains array layout: law, sky-hook gains, leak, then the LQ gain K (4 x 15, row-major).
G_LAW, G_HEAVE, G_PITCH, G_ROLL, G_FHP, G_K = range(6)
N_LQ_STATE = 15
N_MODAL = G_K + N_CORNERS * N_LQ_STATE
# IMU vector: vertical acceleration at the CG (gravity removed), pitch rate, roll rate.
IMU_AZ, IMU_WPITCH, IMU_WROLL = range(3)
N_IMU = 3
# Modal controller state: heave velocity estimate.
N_MODAL_STATE = 2


@dataclass(frozen=True)
class ModalParams:
    """Gains of the modal sky-hook (SI): damping of heave, pitch and roll, heave-velocity leak.

    The defaults equal a corner sky-hook of 1000 N s/m at each corner of a 2 m x 1.3 m car
    (``c_heave = 4 c``, ``c_pitch = c sum x_i^2``, ``c_roll = c sum y_i^2``).
    """

    law: str = 'modal_skyhook'
    c_heave: float = param(4000.0, 0.0, 1.0e6, 'N s/m', 'heave sky-hook damping')
    c_pitch: float = param(4000.0, 0.0, 1.0e6, 'N m s/rad', 'pitch sky-hook damping')
    c_roll: float = param(1700.0, 0.0, 1.0e6, 'N m s/rad', 'roll sky-hook damping')
    f_hp: float = param(0.1, 0.001, 5.0, 'Hz', 'leak of the heave-velocity integrator')
    lqr_weights: tuple = (1.0, 1.0e3, 1.0e3, 1.0e-6)

    def __post_init__(self):
        if self.law not in MODAL_LAWS:
            raise ValueError(f'ModalParams: unknown law {self.law!r}; known {MODAL_LAWS}')
        check_declared(self)
        w = tuple(self.lqr_weights)
        if len(w) != 4:
            raise ValueError('ModalParams: lqr_weights must be 4 numbers (body acceleration, '
                             f'stroke, tyre deflection, force), got {self.lqr_weights!r}')
        check_nonneg('ModalParams', q_acc=w[0], q_x=w[1], q_d=w[2])
        check_positive('ModalParams', r=w[3])
        object.__setattr__(self, 'lqr_weights', tuple(float(v) for v in w))

    def to_array(self, car=None):
        """Gains array (layout ``G_*``); the clipped-optimal law needs the ``car``."""
        out = np.zeros(N_MODAL)
        out[G_LAW] = MODAL_LAWS.index(self.law)
        out[G_HEAVE:G_K] = (self.c_heave, self.c_pitch, self.c_roll, self.f_hp)
        if self.law == 'modal_clipped_optimal':
            if car is None:
                raise ValueError('ModalParams: the clipped-optimal law needs the car')
            out[G_K:] = full_car_lqr_gain(car, *self.lqr_weights).ravel()
        return out

    def to_dict(self):
        """Plain dict (YAML friendly)."""
        return asdict(self)


def distribution(t):
    """Least-squares force distribution ``G = T (T^T T)^-1`` (4 x 3) of a coupled body map."""
    tb = np.asarray(t, dtype=float)[:, :3]
    return tb @ np.linalg.inv(tb.T @ tb)


def modal_map(t):
    """``[G | T]`` (4 x 6): the force distribution and the coupled body's corner map."""
    return np.hstack([distribution(t), np.asarray(t, dtype=float)[:, :3]])


def full_car_matrices(car):
    """Return the linear full car's ``(A, B, E, C_a, D_a)`` (module doc).

    ``X' = A X + B u + E z_r'`` and the body's accelerations at the corners
    ``T r'' = C_a X + D_a u``.
    """
    t, mb, arb = car.body(True)
    t = t[:, :3]
    m_inv = np.diag(1.0 / mb[:3])
    mass, _, stiff = car.linear_matrices()
    kx = np.diag([car.corner(i).k_s for i in range(N_CORNERS)])
    for axle in range(2):
        lr = [2 * axle, 2 * axle + 1]
        kx[np.ix_(lr, lr)] += arb[1 + axle] * np.array([[1.0, -1.0], [-1.0, 1.0]])
    m_u = np.array([car.corner(i).m_u for i in range(N_CORNERS)])
    k_t = np.array([car.corner(i).k_t for i in range(N_CORNERS)])
    c_t = np.array([car.corner(i).c_t for i in range(N_CORNERS)])
    n = N_LQ_STATE
    ix, idf, ir, iu = slice(0, 4), slice(4, 8), slice(8, 11), slice(11, 15)
    a = np.zeros((n, n))
    b = np.zeros((n, N_CORNERS))
    e = np.zeros((n, N_CORNERS))
    a[ix, ir] = t
    a[ix, iu] = -np.eye(N_CORNERS)
    a[idf, iu] = np.eye(N_CORNERS)
    e[idf, :] = -np.eye(N_CORNERS)
    a[ir, ix] = -m_inv @ t.T @ kx
    b[ir, :] = -m_inv @ t.T
    a[iu, ix] = kx / m_u[:, None]
    a[iu, idf] = -np.diag(k_t / m_u)
    a[iu, iu] = -np.diag(c_t / m_u)
    b[iu, :] = np.diag(1.0 / m_u)
    e[iu, :] = np.diag(c_t / m_u)
    c_a = t @ a[ir, :]
    d_a = t @ b[ir, :]
    return a, b, e, c_a, d_a


def full_car_lqr_gain(car, q_acc=1.0, q_x=1.0e3, q_d=1.0e3, r=1.0e-6):
    """LQ gain ``K`` (4 x 15) of ``u = -K X`` for the full car (module doc)."""
    check_nonneg('full_car_lqr_gain', q_acc=q_acc, q_x=q_x, q_d=q_d)
    check_positive('full_car_lqr_gain', r=r)
    a, b, _, c_a, d_a = full_car_matrices(car)
    q = q_acc * c_a.T @ c_a
    q[:4, :4] += q_x * np.eye(N_CORNERS)
    q[4:8, 4:8] += q_d * np.eye(N_CORNERS)
    rr = q_acc * d_a.T @ d_a + r * np.eye(N_CORNERS)
    n = q_acc * c_a.T @ d_a
    p = linalg.solve_continuous_are(a, b, q, rr, s=n)
    return np.linalg.solve(rr, b.T @ p + n.T)


@njit(cache=True)
def modal_step(g, mp, ms, imu, cps, css, meas, dt, out):
    """Write the four corners' current commands into ``out`` from the IMU (module doc).

    ``g``: :func:`modal_map`; ``mp``: :meth:`ModalParams.to_array`; ``ms``:
    modal state; ``imu``: ``(a_z, pitch rate, roll rate)``, NaN where a sensor gives nothing
    (counted 0); ``cps, css, meas``: each corner's controller parameters, state and
    measurements as :func:`~mr_suspension.control.laws.controller_step` takes them.
    """
    a_z = imu[IMU_AZ] if imu[IMU_AZ] == imu[IMU_AZ] else 0.0
    lam = math.exp(-2.0 * math.pi * mp[G_FHP] * dt)
    ms[0] = lam * ms[0] + dt * a_z
    w_p = imu[IMU_WPITCH] if imu[IMU_WPITCH] == imu[IMU_WPITCH] else 0.0
    w_r = imu[IMU_WROLL] if imu[IMU_WROLL] == imu[IMU_WROLL] else 0.0
    xs = np.empty(N_CORNERS)
    vs = np.empty(N_CORNERS)
    fields = np.empty(N_CORNERS)
    x_lq = np.empty(N_LQ_STATE)
    for i in range(N_CORNERS):
        x, a_s, a_u, v_s, v, v_u, i_field = laws.measure(cps[i], css[i], meas[i], dt)
        xs[i] = x
        vs[i] = v
        fields[i] = i_field
        if mp[G_LAW] == 1.0:
            p = cps[i]
            if not a_u == a_u:
                a_u = 0.0
            x_lq[i] = x
            x_lq[4 + i] = -(p[laws.P_MS] * a_s + p[laws.P_MU] * a_u) / p[laws.P_KT]
    if mp[G_LAW] == 1.0:
        x_lq[8] = ms[0]
        x_lq[9] = w_p
        x_lq[10] = w_r
        for i in range(N_CORNERS):
            # Body point velocity T_i r' minus the stroke rate.
            v_body = g[i, 3] * ms[0] + g[i, 4] * w_p + g[i, 5] * w_r
            x_lq[11 + i] = v_body - vs[i]
    for i in range(N_CORNERS):
        if mp[G_LAW] == 1.0:
            f_des = 0.0
            for j in range(N_LQ_STATE):
                f_des -= mp[G_K + i * N_LQ_STATE + j] * x_lq[j]
        else:
            f_des = (g[i, 0] * mp[G_HEAVE] * ms[0] + g[i, 1] * mp[G_PITCH] * w_p
                     + g[i, 2] * mp[G_ROLL] * w_r)
        out[i] = laws.force_command(cps[i], css[i], xs[i], vs[i], fields[i], f_des, dt)
