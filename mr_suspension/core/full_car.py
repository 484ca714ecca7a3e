"""Full car: one rigid body (heave, pitch, roll) on four quarter-car corners (7 DOF).

Axes after ISO 8855: x forward, y left, z up; pitch ``theta`` about y (positive nose down),
roll ``phi`` about x (positive left side up). Corner ``i`` sits at ``(x_i, y_i)`` from the
centre of gravity (front ``x = a``, rear ``x = -b``, left ``y = +t/2``), and the body point
above it moves, for small angles, as

    z_s,i = z - x_i theta + y_i phi = T_i r,      r = (z, theta, phi).

Each corner is today's quarter-car corner (:mod:`~mr_suspension.core.quarter_car`: spring,
end stops, model options, tyre with lift-off, MR damper force and its tangent), its sprung
mass the body's static share ``m_s,i`` (``m_b b / 2L`` front, ``m_b a / 2L`` rear). An
anti-roll bar of wheel rate ``k_arb`` adds ``-k_arb (x_L - x_R)`` to the left strut force and
the opposite to the right one (roll stiffness ``k_arb t^2``). About the static
equilibrium (preloads balance gravity corner by corner):

    m_b z'' = sum_i S_i',   I_yy theta'' = -sum_i x_i S_i',   I_xx phi'' = sum_i y_i S_i',
    m_u,i z_u,i'' = F_t,i - S_i - m_u,i g,        S_i' = S_i - m_s,i g,

i.e. ``M q'' = Q(q, q')`` with ``q = (r, z_u)`` and the generalised strut forces ``T^T S'``.
The step is the quarter car's linearly implicit trapezoidal rule in generalised coordinates,

    (M + dt/2 C + dt^2/4 K) dv = dt (Q - dt/2 K v),    q_{n+1} = q_n + dt/2 (v_n + v_{n+1}),

with ``K``, ``C`` the tangent stiffness and damping ``B^T K_x B`` (``B = [T, -I]`` maps the
generalised coordinates to the strokes) plus the tyres'. With the body replaced by four
independent masses ``m_s,i`` (``T = I``, no anti-roll bar: :meth:`FullCarParams.body`
with ``coupled=False``) every corner is the quarter car of
:func:`~mr_suspension.core.quarter_car.plant_step` to round-off.

Body values after seed 000 (the LISA light city car; its Table 1 is not in the text, so the
packaged ``config/vehicles/lisa_full_car.yaml`` says where each value comes from).
"""

from dataclasses import dataclass, field, fields, replace
import math

from numba import njit
import numpy as np

from mr_suspension.core import quarter_car as qc
from mr_suspension.core.validation import build, check_declared, param

CORNERS = ('front_left', 'front_right', 'rear_left', 'rear_right')
AXLES = ('front', 'rear')
N_CORNERS = 4
N_BODY_MAX = 4
# Generalised state: body coordinates r[0:4] (3 used when coupled), wheels z_u[4:8], then the
# rates of both at [8:12] and [12:16].
N_FULL_STATE = 16
WHEEL0 = 4
RATE0 = 8


@dataclass(frozen=True)
class FullCarParams:
    """Body of a full car and its two axles' corners (SI units).

    ``front`` and ``rear``: the corners of each axle as
    :class:`~mr_suspension.core.quarter_car.QuarterCarParams` whose ``m_s`` is the body's static
    share (set here from ``m_b``, ``a`` and ``b``; a file must not give it).
    """

    m_b: float = param(440.0, 50.0, 20000.0, 'kg', 'sprung (body) mass')
    i_xx: float = param(130.0, 5.0, 50000.0, 'kg m^2', 'roll inertia about the CG')
    i_yy: float = param(440.0, 5.0, 100000.0, 'kg m^2', 'pitch inertia about the CG')
    a: float = param(0.95, 0.1, 5.0, 'm', 'CG to front axle')
    b: float = param(1.05, 0.1, 5.0, 'm', 'CG to rear axle')
    track_f: float = param(1.3, 0.5, 3.0, 'm', 'front track width')
    track_r: float = param(1.3, 0.5, 3.0, 'm', 'rear track width')
    k_arb_f: float = param(6000.0, 0.0, 1.0e6, 'N/m', 'front anti-roll bar wheel rate')
    k_arb_r: float = param(2000.0, 0.0, 1.0e6, 'N/m', 'rear anti-roll bar wheel rate')
    seat_x: float = param(0.1, -5.0, 5.0, 'm', "driver's seat ahead of the CG",
                          required=False)
    seat_y: float = param(0.3, -1.5, 1.5, 'm', "driver's seat left of the CG", required=False)
    front: qc.QuarterCarParams = field(default_factory=qc.QuarterCarParams)
    rear: qc.QuarterCarParams = field(default_factory=qc.QuarterCarParams)

    def __post_init__(self):
        check_declared(self)
        for axle in AXLES:
            corner = getattr(self, axle)
            if not isinstance(corner, qc.QuarterCarParams):
                raise ValueError(f'FullCarParams: {axle} must be a QuarterCarParams')
            if corner.k_tm > 0.0:
                raise ValueError(f'FullCarParams: {axle} has a top mount (k_tm > 0); the full '
                                 'car models rigid strut mounts, set k_tm = 0')
            share = self.static_share(axle)
            if not math.isclose(corner.m_s, share, rel_tol=1e-12):
                object.__setattr__(self, axle, replace(corner, m_s=share))

    @property
    def wheelbase(self):
        """Wheelbase ``L = a + b`` [m]."""
        return self.a + self.b

    def static_share(self, axle):
        """Return the static sprung mass of a corner of ``axle`` (``m_b b / 2L`` front)."""
        lever = self.b if axle == 'front' else self.a
        return self.m_b * lever / (2.0 * self.wheelbase)

    def corner(self, i):
        """Quarter-car parameters of corner ``i`` (order :data:`CORNERS`)."""
        return self.front if i < 2 else self.rear

    def positions(self):
        """Corner positions ``(x_i, y_i)`` from the CG [m], shape (4, 2)."""
        a, b, tf, tr = self.a, self.b, self.track_f, self.track_r
        return np.array([[a, 0.5 * tf], [a, -0.5 * tf], [-b, 0.5 * tr], [-b, -0.5 * tr]])

    def body(self, coupled=True):
        """Body arrays ``(T, m, arb)`` for :func:`full_car_step`.

        ``T`` (4 x 4): corner map, its first ``nb`` columns used; ``m`` (4): the body's
        generalised masses; ``arb`` (3): ``nb`` and the two anti-roll bar rates. Coupled: the
        rigid body (``nb = 3``, ``T_i = (1, -x_i, y_i)``, ``m = (m_b, I_yy, I_xx)``);
        uncoupled: four independent masses ``m_s,i`` (``T = I``) and no anti-roll bar.
        """
        t = np.zeros((N_CORNERS, N_BODY_MAX))
        m = np.zeros(N_BODY_MAX)
        if coupled:
            pos = self.positions()
            t[:, 0] = 1.0
            t[:, 1] = -pos[:, 0]
            t[:, 2] = pos[:, 1]
            m[:3] = (self.m_b, self.i_yy, self.i_xx)
            return t, m, np.array([3.0, self.k_arb_f, self.k_arb_r])
        for i in range(N_CORNERS):
            t[i, i] = 1.0
            m[i] = self.corner(i).m_s
        return t, m, np.array([4.0, 0.0, 0.0])

    def corner_arrays(self, f_d0=(0.0, 0.0, 0.0, 0.0)):
        """Corner parameter arrays (4 x ``N_CAR``, layout ``CAR_*``) with each static force."""
        return np.stack([self.corner(i).to_array(f_d0[i]) for i in range(N_CORNERS)])

    def linear_matrices(self, c_f=0.0, c_r=None, coupled=True):
        """Mass, damping and stiffness of the linearised car (7 x 7: r, then the wheels).

        Viscous dampers ``c_f``, ``c_r`` [N s/m] in place of the MR dampers; no end stops, no
        lift-off, no model options.
        """
        c_r = c_f if c_r is None else c_r
        t, m, arb = self.body(coupled)
        nb = int(arb[0])
        n = nb + N_CORNERS
        bmap = np.zeros((N_CORNERS, n))
        bmap[:, :nb] = t[:, :nb]
        bmap[:, nb:] = -np.eye(N_CORNERS)
        kx = np.diag([self.corner(i).k_s for i in range(N_CORNERS)])
        for axle, k in enumerate(arb[1:]):
            left, right = 2 * axle, 2 * axle + 1
            kx[np.ix_([left, right], [left, right])] += k * np.array([[1.0, -1.0],
                                                                      [-1.0, 1.0]])
        cx = np.diag([c_f, c_f, c_r, c_r])
        mass = np.diag(np.concatenate([m[:nb], [self.corner(i).m_u for i in range(4)]]))
        stiff = bmap.T @ kx @ bmap
        damp = bmap.T @ cx @ bmap
        for i in range(N_CORNERS):
            stiff[nb + i, nb + i] += self.corner(i).k_t
            damp[nb + i, nb + i] += self.corner(i).c_t
        return mass, damp, stiff

    def natural_frequencies(self):
        """Undamped frequencies [Hz] of heave, pitch and roll and the wheel hop modes.

        From ``det(K - w^2 M) = 0`` of :meth:`linear_matrices`; each body mode is the
        eigenvector with the largest share (mass-weighted) in its body coordinate. Returns a
        dict ``heave``, ``pitch``, ``roll`` and ``wheel`` (the four highest).
        """
        mass, _, stiff = self.linear_matrices()
        w2, vec = np.linalg.eig(np.linalg.solve(mass, stiff))
        order = np.argsort(w2.real)
        w2, vec = w2.real[order], vec.real[:, order]
        energy = vec ** 2 * np.diag(mass)[:, None]
        energy /= energy.sum(axis=0)
        hz = np.sqrt(np.maximum(w2, 0.0)) / (2.0 * np.pi)
        out = {name: float(hz[np.argmax(energy[k])]) for k, name in
               enumerate(('heave', 'pitch', 'roll'))}
        out['wheel'] = tuple(float(f) for f in hz[3:])
        return out

    def to_dict(self):
        """Plain dict (YAML friendly); the corners without their derived ``m_s``."""
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name not in AXLES}
        for axle in AXLES:
            corner = getattr(self, axle).to_dict()
            corner.pop('m_s')
            out[axle] = corner
        return out

    @classmethod
    def from_dict(cls, data, source=None):
        """Build from a mapping with ``front`` and ``rear`` corner mappings (no ``m_s``)."""
        owner = str(source) if source is not None else cls.__name__
        if not isinstance(data, dict):
            raise ValueError(f'{owner}: expected a mapping of parameters, got '
                             f'{type(data).__name__}')
        data = dict(data)
        axles = {}
        for axle in AXLES:
            corner = data.pop(axle, None)
            if not isinstance(corner, dict):
                raise ValueError(f'{owner}: {axle} must be a mapping of corner parameters '
                                 '(m_u, k_s, k_t, ...), got '
                                 f'{type(corner).__name__}')
            if 'm_s' in corner:
                raise ValueError(f'{owner}: {axle}.m_s is the static share of m_b and comes '
                                 'from a and b; remove it')
            axles[axle] = build(qc.QuarterCarParams, {**corner, 'm_s': 100.0},
                                owner=f'{owner}: {axle}',
                                source=None if source is None else f'{owner}: {axle}')
        return build(cls, {**data, **axles}, source=source)


@njit(cache=True)
def body_point(t, nb, q, i):
    """Height and vertical velocity ``T_i r``, ``T_i r'`` of the body point above corner ``i``."""
    zs = 0.0
    vs = 0.0
    for j in range(nb):
        zs += t[i, j] * q[j]
        vs += t[i, j] * q[RATE0 + j]
    return zs, vs


@njit(cache=True)
def corner_motion(t, nb, q, i):
    """Stroke and stroke rate ``(x_i, v_i)`` of corner ``i``: body point minus wheel."""
    zs, vs = body_point(t, nb, q, i)
    return zs - q[WHEEL0 + i], vs - q[RATE0 + WHEEL0 + i]


@njit(cache=True)
def full_car_step(t, mb, arb, cps, q, f_d, c_d, z_r, zr_dot, dt, acc, f_t_out, wm, wv):
    """Advance the full car one step (module doc); writes accelerations and tyre forces.

    ``t, mb, arb``: :meth:`FullCarParams.body`; ``cps``: corner arrays (4 x ``N_CAR``);
    ``q``: state (:data:`N_FULL_STATE`); ``f_d, c_d``: damper forces and tangents per corner;
    ``z_r, zr_dot``: the road under each wheel at mid-step; ``wm`` (3 x 8 x 8), ``wv``
    (12 x 8): scratch, allocated once per run.
    ``acc`` (8) receives the mean accelerations over the step of the body coordinates
    ``[0:nb]`` and of the wheels ``[4:8]``; ``f_t_out`` (4) the tyre forces at mid-step.

    The matrix ``A = M + dt/2 C + dt^2/4 K`` is a sum of rank-one strut terms
    ``e_i b_i b_i^T`` (``e_i = dt/2 c_i + dt^2/4 k_i``, ``b_i`` row ``i`` of ``B = [T, -I]``),
    anti-roll bar terms ``e_a (b_L - b_R)(b_L - b_R)^T`` (``e_a = dt^2/4 k_arb``) and the
    masses and tyres on the diagonal; the right-hand side is ``dt (Q - dt/2 K v)``. Ordered
    ``[r; z_u]``, ``A = [[A_rr, A_rw], [A_wr, A_ww]]`` with ``A_ww`` block diagonal (one
    2 x 2 block per axle: a wheel meets only the other wheel of its axle, through the bar), so
    the wheels are eliminated per axle and the body solves the ``nb x nb`` Schur complement
    (block Gaussian elimination, Golub & Van Loan, *Matrix Computations*, 4th ed., 3.2.10):

        (A_rr - A_rw A_ww^-1 A_wr) dr = b_r - A_rw A_ww^-1 b_w,
        dz_u' = A_ww^-1 b_w - (A_ww^-1 A_wr) dr,

    the Schur complement by ``L D L^T`` (symmetric positive definite). The batch kernel
    (:mod:`~mr_suspension.sim.full_car_batch`) runs these operations in this order.
    """
    nb = int(arb[0])
    h = dt
    hh = 0.5 * h
    qh = 0.25 * h * h
    ih = 1.0 / h
    sc = wm[0]  # Schur complement, then L (lower), c = L D (upper) and 1 / D (diagonal)
    ug = wm[1]  # rows 0-3: A_wr (u_i = column i of A_rw); rows 4-7: A_ww^-1 A_wr
    cw = wm[2]  # per corner: e, wheel diagonal, phi, wheel rhs, A_ww^-1 b_w; per axle: psi
    e_r = cw[0]
    wd_r = cw[1]
    phi_r = cw[2]
    r_w = cw[3]
    y_w = cw[4]
    psi_r = cw[5]
    b = wv[0]
    xs = wv[1]
    vs = wv[2]
    ftl = wv[3]
    kt_r = wv[4]
    ct_r = wv[5]
    s_force = wv[6]
    for i in range(N_CORNERS):
        p = cps[i]
        x, v = corner_motion(t, nb, q, i)
        xs[i] = x
        vs[i] = v
        f_stop, k_x = qc.end_stop(p, x)
        k_x += p[qc.CAR_KS]
        c = c_d[i]
        if p[qc.CAR_KS3] != 0.0 or p[qc.CAR_KBS] > 0.0 or p[qc.CAR_FFRIC] > 0.0:
            f_x, k_e, c_e = qc.strut_extra(p, x, v)
            f_stop += f_x
            k_x += k_e
            c += c_e
        ms = p[qc.CAR_MS]
        mu = p[qc.CAR_MU]
        g = p[qc.CAR_G]
        sf = ms * g + p[qc.CAR_FD0] - p[qc.CAR_KS] * x - f_d[i] - f_stop
        s_force[i] = sf
        vu = q[RATE0 + WHEEL0 + i]
        f_lin = (ms + mu) * g + p[qc.CAR_KT] * (z_r[i] - q[WHEEL0 + i]) \
            + p[qc.CAR_CT] * (zr_dot[i] - vu)
        ftl[i] = f_lin
        kt = p[qc.CAR_KT] if f_lin > 0.0 else 0.0
        ct = p[qc.CAR_CT] if f_lin > 0.0 else 0.0
        f_t = f_lin if f_lin > 0.0 else 0.0
        kt_r[i] = kt
        ct_r[i] = ct
        e = hh * c + qh * k_x
        hk = hh * (k_x * v)
        e_r[i] = e
        ea = qh * arb[1 + i // 2]
        wd_r[i] = e + ea + (mu + hh * ct + qh * kt)
        phi_r[i] = s_force[i] - ms * g - hk
        r_w[i] = f_t - sf - mu * g + hk - hh * (kt * vu)
    # Anti-roll bars: -k (x_L - x_R) - dt/2 k (v_L - v_R) along d = b_L - b_R; then each
    # axle's 2 x 2 wheel block [[w_L, -e_a], [-e_a, w_R]] eliminated.
    for axle in range(2):
        left = 2 * axle
        right = left + 1
        k_a = arb[1 + axle]
        ea = qh * k_a
        psi = -(k_a * (xs[left] - xs[right]) + hh * (k_a * (vs[left] - vs[right])))
        psi_r[axle] = psi
        r_l = h * (r_w[left] - psi)
        r_r = h * (r_w[right] + psi)
        e_l = e_r[left]
        e_rr = e_r[right]
        for j in range(nb):
            d = t[left, j] - t[right, j]
            ug[left, j] = -(e_l * t[left, j] + ea * d)
            ug[right, j] = ea * d - e_rr * t[right, j]
        w_l = wd_r[left]
        w_r = wd_r[right]
        idet = 1.0 / (w_l * w_r - ea * ea)
        for j in range(nb):
            u_l = ug[left, j]
            u_r = ug[right, j]
            ug[4 + left, j] = (w_r * u_l + ea * u_r) * idet
            ug[4 + right, j] = (ea * u_l + w_l * u_r) * idet
        y_w[left] = (w_r * r_l + ea * r_r) * idet
        y_w[right] = (ea * r_l + w_l * r_r) * idet
    # Schur complement (lower triangle) and the body's right-hand side.
    for j in range(nb):
        for k in range(j + 1):
            a = e_r[0] * t[0, j] * t[0, k]
            for i in range(1, N_CORNERS):
                a += e_r[i] * t[i, j] * t[i, k]
            for axle in range(2):
                ea = qh * arb[1 + axle]
                a += ea * (t[2 * axle, j] - t[2 * axle + 1, j]) \
                    * (t[2 * axle, k] - t[2 * axle + 1, k])
            if j == k:
                a += mb[j]
            w = ug[0, j] * ug[4, k]
            for i in range(1, N_CORNERS):
                w += ug[i, j] * ug[4 + i, k]
            sc[j, k] = a - w
        s = t[0, j] * phi_r[0]
        for i in range(1, N_CORNERS):
            s += t[i, j] * phi_r[i]
        for axle in range(2):
            s += (t[2 * axle, j] - t[2 * axle + 1, j]) * psi_r[axle]
        w = ug[0, j] * y_w[0]
        for i in range(1, N_CORNERS):
            w += ug[i, j] * y_w[i]
        b[j] = h * s - w
    # L D L^T in place: l_jk below the diagonal, c_jk = l_jk d_k above it, 1 / d_j on it.
    for j in range(nb):
        for k in range(j):
            c = sc[j, k]
            for m in range(k):
                c -= sc[m, j] * sc[k, m]
            sc[k, j] = c
            sc[j, k] = c * sc[k, k]
        d = sc[j, j]
        for k in range(j):
            d -= sc[k, j] * sc[j, k]
        sc[j, j] = 1.0 / d
    for j in range(nb):
        for k in range(j):
            b[j] -= sc[j, k] * b[k]
    for j in range(nb - 1, -1, -1):
        x = b[j] * sc[j, j]
        for k in range(j + 1, nb):
            x -= sc[k, j] * b[k]
        b[j] = x
    for j in range(nb):
        q[j] += h * (q[RATE0 + j] + 0.5 * b[j])
        q[RATE0 + j] += b[j]
        acc[j] = b[j] * ih
    for i in range(N_CORNERS):
        s = ug[4 + i, 0] * b[0]
        for j in range(1, nb):
            s += ug[4 + i, j] * b[j]
        dvu = y_w[i] - s
        f_t_out[i] = qc.tyre_mid(ftl[i], kt_r[i], ct_r[i], q[RATE0 + WHEEL0 + i], dvu, h)
        q[WHEEL0 + i] += h * (q[RATE0 + WHEEL0 + i] + 0.5 * dvu)
        q[RATE0 + WHEEL0 + i] += dvu
        acc[WHEEL0 + i] = dvu * ih
