"""Independent full-car truth: a rigid body on four corners, hidden effects on one corner.

Written apart from the code it judges: no import of ``identification`` or of the core plant
(``core.full_car``, ``sim.full_car_sim``, ``sim.full_car_batch``, ``core.quarter_car``,
``core.damper``, ``core.driver``, ``sim.simulator``, ``core.extended``). Each corner is a
:class:`~mr_suspension.truth.vehicle.VehicleTruth` (its strut law ``_strut``, current chain and
Dahl friction, effect shapes and sensors are those of :mod:`~mr_suspension.truth.vehicle`);
body values come from ``config/vehicles/lisa_full_car.yaml``, the damper and driver from the
files of :func:`~mr_suspension.truth.vehicle.nominal_truth`; ``core.car_road`` only generates
the road. Own integrator: RK4 with substeps per sample from a stiffness bound, the road linear
between samples.

Axes after ISO 8855 (x forward, y left, z up). Body coordinates: heave ``z`` of the centre of
gravity, pitch ``theta`` about y (positive nose down), roll ``phi`` about x (positive left
side up), all from the static equilibrium, small angles. Corner ``i`` (front_left,
front_right, rear_left, rear_right) sits at ``(x_i, y_i)`` from the CG: ``x = +a`` front,
``-b`` rear, ``y = +t/2`` left, ``-t/2`` right, and the body point above it is at::

    z_b,i = z - x_i theta + y_i phi,         x_i^s = z_b,i - z_u,i  (stroke, + = extension)

Per corner the strut force on the body ``S_i = _strut(p_i, x_i^s, v_i^s, i_f,i, F_f,i)``
(preload ``m_nom,i g`` included, ``m_nom,i`` the static share ``m_b b / 2L`` front,
``m_b a / 2L`` rear, ``L = a + b``), an anti-roll bar per axle of wheel rate ``k_arb``
``A_L = -k_arb (x_L^s - x_R^s)``, ``A_R = -A_L``, and ``F_i = S_i + A_i``::

    m_b  z''      = sum_i F_i - m_b g
    I_yy theta''  = -sum_i x_i F_i
    I_xx phi''    =  sum_i y_i F_i
    m_u,i z_u,i'' = F_t,i - F_i - m_u,i g
    F_t,i = max(0, (m_nom,i + m_u,i) g + k_t,i (z_r,i - z_u,i) + c_t,i (z_r,i' - z_u,i'))

``sum_i m_nom,i = m_b`` and ``sum_i x_i m_nom,i = 0``, ``sum_i y_i m_nom,i = 0``: the preloads
carry the body, so the zero state is the static equilibrium where every run starts. Per corner
the current chain (command held per sample and seen after the dead time, coil lag rise/fall,
the extra field lag, the fluid lag, saturation) and the Dahl state
``dF_f/dt = sigma (v - |v| F_f / F_c)`` are those of ``truth.vehicle._deriv``. No top mount
and no load change: ``top_mount`` and ``sprung_mass`` are refused.

Outputs per sample: per corner the body-point and wheel accelerations, stroke and rate,
command, coil and field current, tyre force; the body's heave acceleration at the CG, the
pitch and roll rates (gyro about y and x). Sensors: per corner those of
:func:`~mr_suspension.truth.vehicle.measure`; a body IMU at the CG (specific force ``z'' + g``
with white and AR(1) noise, gyros with small white noise).
"""

from dataclasses import dataclass, field, replace
import math

from numba import njit
import numpy as np

import mr_suspension.core.car_road as cr
from mr_suspension.truth import vehicle as tv
from mr_suspension.truth.redraw import Redrawable
from mr_suspension.truth.vehicle import (P_CT, P_DEAD, P_FC, P_FFALL, P_FRISE, P_G, P_IMAX,
                                         P_KT, P_MNOM, P_MU, P_TFALL, P_TRISE, P_XFALL,
                                         P_XPRE, P_XRISE)

CORNERS = ('front_left', 'front_right', 'rear_left', 'rear_right')
REFUSED = ('top_mount', 'sprung_mass')
FULL_CAR_EFFECTS = tuple(e for e in tv.EFFECTS if e not in REFUSED)
SENSOR_FAULTS = tv.SENSOR_FAULTS
COMMANDS = tv.COMMANDS
CORNER_KEYS = ('body_acc', 'wheel_acc', 'stroke', 'stroke_rate', 'current_command',
               'coil_current', 'field_current', 'tyre_force', 'body_z', 'wheel_z')
BODY_KEYS = ('heave_acc', 'pitch_rate', 'roll_rate', 'heave', 'pitch', 'roll')
AXLE_KEYS = ('m_u', 'k_s', 'k_t', 'c_t', 'stroke_max', 'stroke_min', 'k_stop', 'g')
BUMP_LENGTH = 1.0  # [m] length of the (1 - cos) bump of a case with ``bump``

NB = 6  # body states: z, theta, phi, z', theta', phi'
NC = 6  # corner states: z_u, v_u, F_f, i_c, i_x, i_f
NS = NB + 4 * NC
B_MB, B_IXX, B_IYY, B_KARBF, B_KARBR, B_G, NBP = range(7)


def _axle(i):
    return 'front' if i < 2 else 'rear'


@dataclass(frozen=True)
class FullCarTruth:
    """Truth of a full car (SI): body values and four corners in :data:`CORNERS` order.

    ``corners``: four :class:`~mr_suspension.truth.vehicle.VehicleTruth`; their ``m_s`` and
    ``m_nom`` are set to the body's static share of the corner. ``hidden``: the corner that
    carries the hidden effects (None: none); the other corners carry none.
    """

    m_b: float
    i_xx: float
    i_yy: float
    a: float
    b: float
    track_f: float
    track_r: float
    k_arb_f: float
    k_arb_r: float
    g: float
    corners: tuple
    hidden: str = None

    def __post_init__(self):
        """Check the body and corners; set each corner's sprung mass to its static share."""
        for name in ('m_b', 'i_xx', 'i_yy', 'a', 'b', 'track_f', 'track_r', 'g'):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0.0):
                raise ValueError(f'FullCarTruth: {name} must be a positive number, got {v!r}')
        for name in ('k_arb_f', 'k_arb_r'):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0.0):
                raise ValueError(f'FullCarTruth: {name} must be >= 0, got {v!r}')
        if self.hidden is not None and self.hidden not in CORNERS:
            raise ValueError(f'FullCarTruth: hidden must be None or one of {CORNERS}, got '
                             f'{self.hidden!r}')
        corners = tuple(self.corners)
        if len(corners) != 4 or not all(isinstance(c, tv.VehicleTruth) for c in corners):
            raise ValueError('FullCarTruth: corners must be four VehicleTruth in the order '
                             f'{CORNERS}')
        placed = []
        for i, (name, c) in enumerate(zip(CORNERS, corners)):
            refused = [e for e in c.effects if e in REFUSED]
            if refused or c.k_tm > 0.0 or c.m_s != c.m_nom:
                raise ValueError(f'FullCarTruth: {name} has a top mount or a sprung-mass '
                                 f'change ({refused or "k_tm > 0 or m_s != m_nom"}); the full '
                                 'car has rigid strut mounts and the body sets the load')
            if c.effects and name != self.hidden:
                raise ValueError(f'FullCarTruth: {name} carries effects {c.effects} but the '
                                 f'hidden corner is {self.hidden!r}')
            if c.g != self.g:
                raise ValueError(f'FullCarTruth: {name} has g = {c.g} but the body {self.g}')
            share = self.share(i)
            placed.append(c if c.m_nom == share and c.m_s == share
                          else replace(c, m_s=share, m_nom=share))
        object.__setattr__(self, 'corners', tuple(placed))

    @property
    def wheelbase(self):
        """Wheelbase ``L = a + b`` [m]."""
        return self.a + self.b

    def share(self, i):
        """Return the static sprung mass of corner ``i`` [kg]: ``m_b b / 2L`` front, else ``a``."""
        lever = self.b if i < 2 else self.a
        return self.m_b * lever / (2.0 * self.wheelbase)

    def positions(self):
        """Corner positions ``(x_i, y_i)`` from the CG [m], shape (4, 2)."""
        a, b, tf, tr = self.a, self.b, self.track_f, self.track_r
        return np.array([[a, 0.5 * tf], [a, -0.5 * tf], [-b, 0.5 * tr], [-b, -0.5 * tr]])

    @property
    def effects(self):
        """Effects of the hidden corner (empty without one)."""
        return self.corner(self.hidden).effects if self.hidden is not None else ()

    def corner(self, name):
        """Return the :class:`VehicleTruth` of corner ``name`` (or index 0..3)."""
        i = CORNERS.index(name) if isinstance(name, str) else int(name)
        return self.corners[i]

    def without(self, effect):
        """Return the same car with ``effect`` switched off on the hidden corner."""
        if effect not in self.effects:
            raise ValueError(f'FullCarTruth.without: {effect!r} is not an effect of the hidden '
                             f'corner ({self.effects})')
        i = CORNERS.index(self.hidden)
        corners = list(self.corners)
        corners[i] = corners[i].without(effect)
        return replace(self, corners=tuple(corners))

    def arrays(self):
        """Kernel arrays: corner parameters (4, NP), body values (NBP,), positions (4, 2)."""
        body = np.zeros(NBP)
        body[B_MB], body[B_IXX], body[B_IYY] = self.m_b, self.i_xx, self.i_yy
        body[B_KARBF], body[B_KARBR], body[B_G] = self.k_arb_f, self.k_arb_r, self.g
        return (np.ascontiguousarray(np.stack([c.array() for c in self.corners])), body,
                self.positions())


def _body_config():
    car = tv._read('vehicles', 'lisa_full_car')
    return car, {k: car[k] for k in ('m_b', 'i_xx', 'i_yy', 'a', 'b', 'track_f', 'track_r',
                                     'k_arb_f', 'k_arb_r')}


def _place(corner, axle_cfg, kt_factor=1.0):
    """Put an axle's values into a drawn corner (``k_t`` keeps the corner's spread factor)."""
    kw = {k: float(axle_cfg[k]) for k in AXLE_KEYS}
    kw['k_t'] *= kt_factor
    return replace(corner, **kw)


def nominal_full_car():
    """Return the nominal full car (LISA body, RD-1005 Bingham dampers, Wonder Box) from config."""
    car, body = _body_config()
    base = tv.nominal_truth()
    corners = tuple(_place(base, car[_axle(i)]) for i in range(4))
    return FullCarTruth(g=float(car['front']['g']), corners=corners,
                        **{k: float(v) for k, v in body.items()})


def _check_effects(owner, effects):
    effects = tuple(effects)
    refused = [e for e in effects if e in REFUSED]
    if refused:
        raise ValueError(f'{owner}: {refused} not available in the full car (no top mount; the '
                         f'body sets the corner loads); known: {FULL_CAR_EFFECTS}')
    bad = [e for e in effects if e not in FULL_CAR_EFFECTS]
    if bad or len(set(effects)) != len(effects):
        raise ValueError(f'{owner}: unknown or repeated effects {bad or list(effects)}; known: '
                         f'{FULL_CAR_EFFECTS}')
    if 'current_lag' in effects and 'current_lag_asymmetric' in effects:
        raise ValueError(f'{owner}: current_lag and current_lag_asymmetric exclude each other')
    return effects


def _check_corner(owner, corner):
    if corner is not None and (not isinstance(corner, str) or corner not in CORNERS):
        raise ValueError(f'{owner}: corner must be one of {CORNERS} (or None), got {corner!r}')
    return corner


def draw_full_car(rng, corner, effects=(), strength=None, spread=0.0):
    """Draw a full car with hidden ``effects`` on ``corner`` (``draw_truth``'s ranges).

    Each corner in :data:`CORNERS` order is drawn by
    :func:`~mr_suspension.truth.vehicle.draw_truth` (the hidden one with ``effects`` and
    ``strength``), then its axle's values and static share are put in; the drawn effect
    parameters stay. ``spread`` > 0: every corner has its own production spread of ``c0``,
    ``c1``, ``fc0``, ``fc1`` and ``k_t`` (the axle's ``k_t`` times the drawn factor).
    """
    effects = _check_effects('draw_full_car', effects)
    corner = _check_corner('draw_full_car', corner)
    if effects and corner is None:
        raise ValueError('draw_full_car: effects need a hidden corner')
    car, body = _body_config()
    base = tv.nominal_truth()
    corners = []
    for i, name in enumerate(CORNERS):
        drawn = tv.draw_truth(rng, effects if name == corner else (), strength, spread)
        corners.append(_place(drawn, car[_axle(i)], drawn.k_t / base.k_t))
    return FullCarTruth(g=float(car['front']['g']), corners=tuple(corners), hidden=corner,
                        **{k: float(v) for k, v in body.items()})


@njit(cache=True)
def _chain(p, u, ic, ix, i_f):
    """Current-chain rates ``(di_c, di_x, di_f)`` and the field current in the strut law.

    As ``truth.vehicle._deriv``: coil lag (rise/fall), the extra field lag when set, the fluid
    lag (none while rising with a zero rise constant: the field follows).
    """
    tau = p[P_TRISE] if u > ic else p[P_TFALL]
    dic = (u - ic) / tau if tau > 0.0 else 0.0
    if p[P_XRISE] > 0.0:
        tau = p[P_XRISE] if ic > ix else p[P_XFALL]
        dix = (ic - ix) / tau
        rate = dix
    else:
        dix = 0.0
        ix = ic
        rate = dic
    if p[P_FRISE] <= 0.0 and (ix > i_f or (ix == i_f and rate >= 0.0)):
        return dic, dix, rate, ix
    tau = p[P_FRISE] if ix > i_f else p[P_FFALL]
    return dic, dix, (ix - i_f) / tau, i_f


@njit(cache=True)
def _rates(cp, body, pos, y, u, zr, zrd, dy, work):
    """Right-hand side of the full car (module docstring) with the corner commands ``u``.

    ``work`` rows on return: strokes, stroke rates, anti-roll bar forces, tyre forces.
    """
    g = body[B_G]
    vz, vth, vph = y[3], y[4], y[5]
    for i in range(4):
        c = NB + NC * i
        work[0, i] = y[0] - pos[i, 0] * y[1] + pos[i, 1] * y[2] - y[c]
        work[1, i] = vz - pos[i, 0] * vth + pos[i, 1] * vph - y[c + 1]
    for axle in range(2):
        left = 2 * axle
        d = body[B_KARBF + axle] * (work[0, left] - work[0, left + 1])
        work[2, left] = -d
        work[2, left + 1] = d
    fz = 0.0
    m_pitch = 0.0
    m_roll = 0.0
    for i in range(4):
        p = cp[i]
        c = NB + NC * i
        x = work[0, i]
        v = work[1, i]
        dic, dix, dif, i_f = _chain(p, u[i], y[c + 3], y[c + 4], y[c + 5])
        dy[c + 3] = dic
        dy[c + 4] = dix
        dy[c + 5] = dif
        f_f = 0.0
        if p[P_FC] > 0.0:
            f_f = y[c + 2]
            dy[c + 2] = p[P_FC] / p[P_XPRE] * (v - abs(v) * f_f / p[P_FC])
        else:
            dy[c + 2] = 0.0
        f = tv._strut(p, x, v, i_f, f_f) + work[2, i]
        mu = p[P_MU]
        f_t = ((p[P_MNOM] + mu) * p[P_G] + p[P_KT] * (zr[i] - y[c])
               + p[P_CT] * (zrd[i] - y[c + 1]))
        if f_t < 0.0:
            f_t = 0.0
        work[3, i] = f_t
        dy[c] = y[c + 1]
        dy[c + 1] = (f_t - f - mu * p[P_G]) / mu
        fz += f
        m_pitch -= pos[i, 0] * f
        m_roll += pos[i, 1] * f
    dy[0] = vz
    dy[1] = vth
    dy[2] = vph
    dy[3] = fz / body[B_MB] - g
    dy[4] = m_pitch / body[B_IYY]
    dy[5] = m_roll / body[B_IXX]


@njit(cache=True)
def _run(cp, body, pos, road_z, road_zd, cmd, mode, i_sky, dt, nsub, out_c, out_b):
    """Integrate from the static equilibrium; fill ``out_c[k, i, :]`` and ``out_b[k, :]``.

    ``out_c`` columns in ``CORNER_KEYS`` order, ``out_b`` in ``BODY_KEYS`` order. ``mode`` 0:
    ``cmd[i, k]`` given; 1: on-off skyhook per corner from the true state at each sample
    (``i_sky`` when body-point velocity times stroke rate > 0, else 0), held over the sample.
    """
    n = road_z.shape[1]
    y = np.zeros(NS)
    dy = np.zeros(NS)
    ks = np.zeros((4, NS))
    tmp = np.zeros(NS)
    work = np.zeros((4, 4))
    u = np.zeros(4)
    zr = np.zeros(4)
    zrd = np.zeros(4)
    h = dt / nsub
    for k in range(n):
        for i in range(4):
            u[i] = 0.0
            zr[i] = road_z[i, k]
            zrd[i] = road_zd[i, k]
        _rates(cp, body, pos, y, u, zr, zrd, dy, work)
        for i in range(4):
            c = NB + NC * i
            xi = pos[i, 0]
            yi = pos[i, 1]
            if mode == 1:
                vb = y[3] - xi * y[4] + yi * y[5]
                cmd[i, k] = i_sky if vb * work[1, i] > 0.0 else 0.0
            out_c[k, i, 0] = dy[3] - xi * dy[4] + yi * dy[5]
            out_c[k, i, 1] = dy[c + 1]
            out_c[k, i, 2] = work[0, i]
            out_c[k, i, 3] = work[1, i]
            out_c[k, i, 4] = cmd[i, k]
            out_c[k, i, 5] = y[c + 3]
            out_c[k, i, 6] = y[c + 5]
            out_c[k, i, 7] = work[3, i]
            out_c[k, i, 8] = y[0] - xi * y[1] + yi * y[2]
            out_c[k, i, 9] = y[c]
        out_b[k, 0] = dy[3]
        out_b[k, 1] = y[4]
        out_b[k, 2] = y[5]
        out_b[k, 3] = y[0]
        out_b[k, 4] = y[1]
        out_b[k, 5] = y[2]
        if k == n - 1:
            break
        for j in range(nsub):
            t0 = k * dt + j * h
            for stage in range(4):
                cs = 0.0 if stage == 0 else (1.0 if stage == 3 else 0.5)
                if stage == 0:
                    for m in range(NS):
                        tmp[m] = y[m]
                else:
                    for m in range(NS):
                        tmp[m] = y[m] + cs * h * ks[stage - 1, m]
                ts = t0 + cs * h
                a = (j + cs) / nsub
                for i in range(4):
                    # Command held per sample, seen after the dead time (negative = 0 A).
                    kd = min(int(math.floor((ts - cp[i, P_DEAD]) / dt + 1e-9)), k)
                    ui = cmd[i, kd] if kd >= 0 else 0.0
                    u[i] = min(max(ui, 0.0), cp[i, P_IMAX])
                    zr[i] = (1.0 - a) * road_z[i, k] + a * road_z[i, k + 1]
                    zrd[i] = (1.0 - a) * road_zd[i, k] + a * road_zd[i, k + 1]
                _rates(cp, body, pos, tmp, u, zr, zrd, ks[stage], work)
            for m in range(NS):
                y[m] += h / 6.0 * (ks[0, m] + 2.0 * ks[1, m] + 2.0 * ks[2, m] + ks[3, m])
            for i in range(4):
                # A zero rise time constant of the fluid: no lag while rising.
                c = NB + NC * i
                ix = y[c + 4] if cp[i, P_XRISE] > 0.0 else y[c + 3]
                if cp[i, P_FRISE] <= 0.0 and y[c + 5] < ix:
                    y[c + 5] = ix
                if y[c + 5] < 0.0:
                    y[c + 5] = 0.0


def substeps(truth, dt):
    """RK4 substeps per sample from a stiffness bound (``|lambda| h <= 2``), over the corners.

    Each corner's bound of ``truth.vehicle._substeps``, the wheel with both anti-roll bar
    springs, and the body seen at each corner (its effective mass
    ``1 / (1/m_b + x_i^2/I_yy + y_i^2/I_xx)``) on the strut's damping and stiffness.
    """
    pos = truth.positions()
    n = 2
    for i, c in enumerate(truth.corners):
        n = max(n, tv._substeps(c, dt))
        k_arb = 2.0 * (truth.k_arb_f if i < 2 else truth.k_arb_r)
        m_eff = 1.0 / (1.0 / truth.m_b + pos[i, 0] ** 2 / truth.i_yy
                       + pos[i, 1] ** 2 / truth.i_xx)
        c_max = c.c0 + c.c1 * c.i_max + (c.fc0 + c.fc1 * c.i_max) / c.v_y
        lam = max(math.sqrt((c.k_t + c.k_stop + k_arb) / c.m_u), c_max / m_eff,
                  math.sqrt((c.k_s + c.k_stop + k_arb) / m_eff))
        n = max(n, int(math.ceil(lam * dt / 2.0)))
    return n


def simulate_full_car(truth, road, cmd=None, mode='given', i_sky=1.0, nsub=None):
    """Integrate the full car over ``road`` (a ``core.car_road.CarRoad``); return arrays.

    ``cmd``: current command [A] per corner and sample, shape (4, n), with ``mode='given'``;
    None with ``mode='skyhook'`` (on-off skyhook per corner, ``i_sky`` [A] when the body-point
    velocity times the stroke rate is positive, decided at each sample from the true state).
    Keys, shape (4, n) in :data:`CORNERS` order: ``body_acc`` (body point above the corner),
    ``wheel_acc``, ``stroke``, ``stroke_rate``, ``current_command``, ``coil_current``,
    ``field_current``, ``tyre_force``, ``body_z``, ``wheel_z``; shape (n,): ``heave_acc`` (at
    the CG), ``pitch_rate`` (positive nose down), ``roll_rate`` (positive left up), ``heave``,
    ``pitch``, ``roll``. Accelerations are true (gravity not included).
    """
    if not isinstance(truth, FullCarTruth):
        raise ValueError(f'simulate_full_car: truth must be a FullCarTruth, got '
                         f'{type(truth).__name__}')
    if not isinstance(road, cr.CarRoad):
        raise ValueError(f'simulate_full_car: road must be a car_road.CarRoad, got '
                         f'{type(road).__name__}')
    if not math.isclose(road.wheelbase, truth.wheelbase, rel_tol=1e-9):
        raise ValueError(f'simulate_full_car: the road is for a wheelbase of {road.wheelbase:g} '
                         f'm but the car has {truth.wheelbase:g} m')
    n = road.z.shape[1]
    if mode == 'given':
        if cmd is None or np.shape(cmd) != (4, n):
            raise ValueError(f'simulate_full_car: cmd must have shape (4, {n}): one command per '
                             f'corner {CORNERS} and road sample, got '
                             f'{None if cmd is None else np.shape(cmd)}')
        c = np.array(cmd, dtype=float)
        m = 0
    elif mode == 'skyhook':
        c = np.zeros((4, n))
        m = 1
    else:
        raise ValueError(f'simulate_full_car: mode must be given or skyhook, got {mode!r}')
    if not np.all(np.isfinite(c)):
        raise ValueError('simulate_full_car: command contains NaN or inf')
    if not (isinstance(i_sky, (int, float)) and math.isfinite(i_sky) and i_sky >= 0.0):
        raise ValueError(f'simulate_full_car: i_sky must be a current >= 0 A, got {i_sky!r}')
    nsub = substeps(truth, road.dt) if nsub is None else int(nsub)
    if nsub < 1:
        raise ValueError(f'simulate_full_car: nsub must be >= 1, got {nsub}')
    cp, body, pos = truth.arrays()
    out_c = np.zeros((n, 4, len(CORNER_KEYS)))
    out_b = np.zeros((n, len(BODY_KEYS)))
    _run(cp, body, pos, np.ascontiguousarray(road.z), np.ascontiguousarray(road.zdot), c, m,
         float(i_sky), float(road.dt), nsub, out_c, out_b)
    if not (np.all(np.isfinite(out_c)) and np.all(np.isfinite(out_b))):
        raise FloatingPointError('simulate_full_car: the truth diverged; check the parameters')
    out = {k: np.ascontiguousarray(out_c[:, :, j].T) for j, k in enumerate(CORNER_KEYS)}
    out.update({k: out_b[:, j].copy() for j, k in enumerate(BODY_KEYS)})
    return out


def draw_body_sensor(rng):
    """Draw the body IMU's noise: accelerometer white and AR(1) [m/s^2], gyro white [rad/s]."""
    return {'acc_white': float(rng.uniform(0.01, 0.05)),
            'acc_ar': float(rng.uniform(0.005, 0.03)),
            'acc_ar_tau': float(rng.uniform(0.02, 0.2)),
            'gyro_white': float(rng.uniform(2e-4, 1e-3))}


def _rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


@dataclass(frozen=True, eq=False)
class FullCarCase(Redrawable):
    """One synthetic full-car record with its truth.

    ``corner``: the hidden corner (None: nothing hidden). ``columns``: per corner name the
    columns of a ``truth.vehicle.VehicleCase`` (``time``, ``body_acc``, ``wheel_acc`` [m/s^2,
    IMU specific force, +g at rest], ``stroke`` [m], ``current_command`` [A], optional
    ``coil_current`` [A]); ``body``: the CG IMU (``time``, ``pitch_rate``, ``roll_rate``
    [rad/s, ISO 8855], ``acc_z`` [m/s^2, specific force]). ``sensors``: one
    :class:`~mr_suspension.truth.vehicle.SensorSpec` per corner; ``body_sensor``: the CG IMU's
    noise levels. ``noise_rms``: per corner the body-IMU noise RMS. ``contributions``: per
    hidden effect the RMS change of the hidden corner's true body-point acceleration without it
    / that corner's ``noise_rms`` (per sensor fault, of its channel / the channel's noise);
    ``leak``: per effect the largest such ratio over the other corners. ``clean``: the
    noise-free outputs of :func:`simulate_full_car` (+ ``road``), ``args``: the arguments.
    """

    seed: int
    record: int
    corner: str
    columns: dict
    body: dict
    truth: FullCarTruth
    sensors: tuple
    body_sensor: dict
    noise_rms: dict
    contributions: dict
    leak: dict
    clean: dict = field(repr=False)
    args: dict = field(repr=False)

    @property
    def effects(self):
        """Effects of the hidden corner."""
        return self.truth.effects


def _check_case_args(seed, record, corner, effects, sensor_faults, duration, rate, command,
                     i_max, bump):
    owner = 'make_full_car_case'
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f'{owner}: seed must be a non-negative integer, got {seed!r}')
    if isinstance(record, bool) or not isinstance(record, (int, np.integer)) or record < 0:
        raise ValueError(f'{owner}: record must be a non-negative integer, got {record!r}')
    _check_corner(owner, corner)
    _check_effects(owner, effects)
    bad = [f for f in sensor_faults if f not in SENSOR_FAULTS]
    if bad or len(set(sensor_faults)) != len(tuple(sensor_faults)):
        raise ValueError(f'{owner}: unknown or repeated sensor faults {bad or sensor_faults}; '
                         f'known: {SENSOR_FAULTS}')
    if not (isinstance(i_max, (int, float)) and 0.0 < i_max <= 2.0):
        raise ValueError(f'{owner}: i_max must be in (0, 2] A, got {i_max!r}')
    if command not in COMMANDS:
        raise ValueError(f'{owner}: command must be one of {COMMANDS}, got {command!r}')
    if not (isinstance(duration, (int, float)) and 1.0 <= duration <= 3600.0):
        raise ValueError(f'{owner}: duration must be 1 to 3600 s, got {duration!r}')
    if not (isinstance(rate, (int, float)) and 100.0 <= rate <= 10000.0):
        raise ValueError(f'{owner}: rate must be 100 to 10000 Hz, got {rate!r}')
    if bump is not None and not (isinstance(bump, (int, float)) and 0.0 < bump <= 0.2):
        raise ValueError(f'{owner}: bump must be a height in (0, 0.2] m or None, got {bump!r}')


def make_full_car_case(seed, effects=(), corner=None, sensor_faults=(), duration=30.0,
                       rate=1000.0, command='random', road_class=None, speed=None, bump=None,
                       strength=None, measured_current=True, record=0, i_max=1.0, spread=0.0):
    """Draw a full-car case: hidden ``effects`` on one corner, road, commands and sensors.

    From independent streams of ``seed`` (as ``truth.vehicle.make_vehicle_case``): the hidden
    corner (drawn when ``corner`` is None and there are effects or sensor faults; the draw is
    made either way, so naming the drawn corner gives the same car) and the car
    (:func:`draw_full_car`); each corner's sensor spec (``sensor_faults`` on the hidden
    corner only) and the body IMU's; per ``record`` the road (ISO 8608 two tracks, class B-D at
    10-30 m/s unless given, plus a (1 - cos) bump of height ``bump`` [m] under the left or the
    right wheels), the commands (per corner ``random`` levels, on-off ``skyhook`` or
    ``constant``, at most ``i_max`` [A]) and the noise.
    """
    effects = tuple(effects)
    sensor_faults = tuple(sensor_faults)
    _check_case_args(seed, record, corner, effects, sensor_faults, duration, rate, command,
                     i_max, bump)
    args = {'seed': int(seed), 'effects': effects, 'corner': corner,
            'sensor_faults': sensor_faults, 'duration': duration, 'rate': rate,
            'command': command, 'road_class': road_class, 'speed': speed, 'bump': bump,
            'strength': strength, 'measured_current': measured_current, 'record': int(record),
            'i_max': i_max, 'spread': spread}
    dt = 1.0 / rate
    r_car = tv._rng(seed, 1)
    drawn = CORNERS[int(r_car.integers(0, 4))]
    hidden = corner if corner is not None else (drawn if effects or sensor_faults else None)
    truth = draw_full_car(r_car, hidden, effects, strength, spread)
    specs = tuple(tv.draw_sensor(tv._rng(seed, 2, i), sensor_faults if name == hidden else ())
                  for i, name in enumerate(CORNERS))
    body_spec = draw_body_sensor(tv._rng(seed, 5))
    r = tv._rng(seed, 3, record)
    cls = road_class or str(r.choice(['B', 'C', 'C', 'D']))
    spd = float(speed) if speed is not None else float(r.uniform(10.0, 30.0))
    track = 0.5 * (truth.track_f + truth.track_r)
    road = cr.iso8608_two_track(road_class=cls, speed=spd, duration=duration, dt=dt,
                                seed=int(r.integers(0, 2 ** 31)), track=track,
                                wheelbase=truth.wheelbase)
    if bump is not None:
        side = str(r.choice(['left', 'right']))
        b = cr.bump(height=float(bump), length=BUMP_LENGTH, speed=spd, t0=0.5 * duration,
                    side=side, duration=duration, dt=dt, track=track,
                    wheelbase=truth.wheelbase)
        road = cr.CarRoad(f'{road.name}+bump_{side}', dt, road.z + b.z, road.zdot + b.zdot,
                          spd, truth.wheelbase)
    n = road.z.shape[1]
    mode = 'skyhook' if command == 'skyhook' else 'given'
    cmd = None if mode == 'skyhook' else np.stack(
        [tv._command(r, n, dt, command, float(i_max)) for _ in CORNERS])
    clean = simulate_full_car(truth, road, cmd, mode, i_sky=float(i_max))
    clean['road'] = road.z.copy()
    time = np.arange(n) * dt
    columns, noise_rms = {}, {}
    for i, name in enumerate(CORNERS):
        cols, noise = tv.measure(tv._rng(seed, 4, record, i), _corner_clean(clean, i),
                                 specs[i], truth.g, dt)
        noise_rms[name] = _rms(noise)
        columns[name] = {'time': time.copy(), **cols}
        if not measured_current:
            del columns[name]['coil_current']
    rb = tv._rng(seed, 6, record)
    acc_noise = (rb.normal(0.0, body_spec['acc_white'], n)
                 + tv._ar1(rb, n, body_spec['acc_ar'], body_spec['acc_ar_tau'], dt))
    body = {'time': time.copy(),
            'pitch_rate': clean['pitch_rate'] + rb.normal(0.0, body_spec['gyro_white'], n),
            'roll_rate': clean['roll_rate'] + rb.normal(0.0, body_spec['gyro_white'], n),
            'acc_z': clean['heave_acc'] + truth.g + acc_noise}
    contrib, leak = {}, {}
    for e in truth.effects:
        other = simulate_full_car(truth.without(e), road, cmd, mode, i_sky=float(i_max))
        ratio = {name: _rms(clean['body_acc'][i] - other['body_acc'][i]) / noise_rms[name]
                 for i, name in enumerate(CORNERS)}
        contrib[e] = ratio[hidden]
        leak[e] = max(v for k, v in ratio.items() if k != hidden)
    if hidden is not None:
        h = CORNERS.index(hidden)
        spec = specs[h]
        ideal = replace(spec, bias=0.0, scale=1.0, stroke_lag=0.0, rail=0.0)
        for f in spec.faults:
            one = {'acc_bias': {'bias': spec.bias}, 'acc_scale': {'scale': spec.scale},
                   'stroke_lag': {'stroke_lag': spec.stroke_lag},
                   'clipping': {'rail': spec.rail}}[f]
            a, _ = tv.measure(tv._rng(seed, 4, record, h), _corner_clean(clean, h),
                              replace(ideal, **one), truth.g, dt)
            b, _ = tv.measure(tv._rng(seed, 4, record, h), _corner_clean(clean, h), ideal,
                              truth.g, dt)
            ch, floor = (('stroke', spec.stroke_noise) if f == 'stroke_lag'
                         else ('body_acc', noise_rms[hidden]))
            contrib[f] = _rms(a[ch] - b[ch]) / floor
    return FullCarCase(seed=int(seed), record=int(record), corner=hidden, columns=columns,
                       body=body, truth=truth, sensors=specs, body_sensor=body_spec,
                       noise_rms=noise_rms, contributions=contrib, leak=leak, clean=clean,
                       args=args)


def _corner_clean(clean, i):
    return {k: clean[k][i] for k in ('body_acc', 'wheel_acc', 'stroke', 'current_command',
                                     'coil_current')}


FullCarCase.make = make_full_car_case  # what ``unseen`` draws again
