"""Fixed-step offline simulator of the full car: four corners' control chains on one body.

One step at ``t_n``, the quarter car's (:mod:`~mr_suspension.sim.simulator`) for each corner:

1. each corner's measurements (its body point's and wheel's acceleration, stroke, stroke rate,
   body point and wheel velocity, coil current of the step before) go to its control law
   (:func:`~mr_suspension.control.laws.controller_step`), or the body's IMU (vertical
   acceleration at the CG, pitch and roll rates) and the four corners' measurements go to the
   modal law (:func:`~mr_suspension.control.modal.modal_step`);
2. each command is delayed by ``control_delay`` and turned into coil and field current by its
   corner's driver, then into a damper force and tangent;
3. the body and the four wheels advance with :func:`~mr_suspension.core.full_car.full_car_step`,
   each wheel on its own road at mid-step.

Comfort is read at the centre of gravity and at the driver's seat (ISO 2631-1: Wk on the
vertical, We on pitch and roll, :mod:`~mr_suspension.core.comfort`); road holding per wheel.
"""

from dataclasses import dataclass, field, replace
from functools import lru_cache
import math

from numba import njit, prange
import numpy as np

from mr_suspension.control import laws
from mr_suspension.control.modal import modal_map, modal_step, ModalParams, N_MODAL_STATE
from mr_suspension.core import damper as dmp
from mr_suspension.core import full_car as fc
from mr_suspension.core.car_road import CarRoad
from mr_suspension.core.comfort import Comfort, comfort, K_RX, K_RY, we_sos
from mr_suspension.core.driver import DRIVER_STATE_SIZE, driver_step, DriverParams
from mr_suspension.core.metrics import sos_step
from mr_suspension.core.validation import check_range
from mr_suspension.sim import full_car_batch
from mr_suspension.sim.simulator import _wk, CHANNELS, CornerConfig, DELAY_BUFFER

BODY_CHANNELS = ('z', 'theta', 'phi', 'v_z', 'w_pitch', 'w_roll', 'a_z', 'alpha_pitch',
                 'alpha_roll')
# Online metrics of a batch run: body figures, then per corner (suffix _fl, _fr, _rl, _rr).
BODY_METRICS = ('heave_acc_rms', 'heave_wk_rms', 'seat_wk_rms', 'seat_vdv', 'pitch_we_rms',
                'roll_we_rms', 'pitch_acc_rms', 'roll_acc_rms')
CORNER_METRICS = ('working_space_rms', 'working_space_peak', 'tyre_load_rms', 'ntf_min',
                  'damper_energy')
N_BODY_ACC = len(BODY_METRICS)
N_ACC = N_BODY_ACC + fc.N_CORNERS * len(CORNER_METRICS)


@lru_cache(maxsize=8)
def _we(dt):
    return we_sos(dt)


def _four(value, name):
    if isinstance(value, (tuple, list)):
        if len(value) != fc.N_CORNERS:
            raise ValueError(f'FullCarConfig: {name} must be one value or four (front left, '
                             f'front right, rear left, rear right), got {len(value)}')
        return tuple(value)
    return (value,) * fc.N_CORNERS


@dataclass(frozen=True)
class FullCarConfig:
    """Everything that defines one simulated full car (SI units).

    ``damper`` and ``driver``: one for all four corners or a tuple of four (order
    :data:`~mr_suspension.core.full_car.CORNERS`); ``controller``: the corner law each corner
    runs (with ``modal`` set, it gives the corners' estimation, inverse model and current
    range, and the modal law decides the force); ``coupled=False`` replaces the body by four
    independent quarter bodies (each corner then is today's quarter car).
    """

    car: fc.FullCarParams = field(default_factory=fc.FullCarParams)
    damper: object = field(default_factory=dmp.BinghamParams)
    driver: object = field(default_factory=DriverParams)
    controller: laws.ControllerParams = field(default_factory=laws.ControllerParams)
    modal: object = None
    dt: float = 1e-3
    control_delay: float = 0.0
    coupled: bool = True

    def __post_init__(self):
        if not isinstance(self.car, fc.FullCarParams):
            raise ValueError('FullCarConfig: car must be a FullCarParams')
        if not isinstance(self.controller, laws.ControllerParams):
            raise ValueError('FullCarConfig: controller must be a ControllerParams')
        if self.modal is not None and not isinstance(self.modal, ModalParams):
            raise ValueError('FullCarConfig: modal must be a ModalParams or None')
        if self.modal is not None and not self.coupled:
            raise ValueError('FullCarConfig: a modal law needs the coupled body')
        object.__setattr__(self, 'damper', _four(self.damper, 'damper'))
        object.__setattr__(self, 'driver', _four(self.driver, 'driver'))
        for i in range(fc.N_CORNERS):
            self.corner(i)  # validates dt, delay, damper and driver of every corner

    def replace(self, **changes):
        """Return a copy with fields replaced."""
        return replace(self, **changes)

    def corner(self, i):
        """Return the :class:`~mr_suspension.sim.simulator.CornerConfig` of corner ``i``.

        Its car is the corner's quarter car (sprung mass: the static share), its controller
        the corner law with the corner's plant knowledge.
        """
        car = self.car.corner(i)
        ctrl = self.controller.with_plant(car, self.damper[i], self.driver[i])
        return CornerConfig(car=car, damper=self.damper[i], driver=self.driver[i],
                            controller=ctrl, dt=self.dt, control_delay=self.control_delay)

    def arrays(self):
        """Arrays of the jitted loop (see :func:`full_car_loop`)."""
        corners = [self.corner(i).arrays() for i in range(fc.N_CORNERS)]
        t, mb, arb = self.car.body(self.coupled)
        nd = max(c[2].size for c in corners)
        nc = max(c[5].size for c in corners)
        dps = np.zeros((fc.N_CORNERS, nd))
        cps = np.zeros((fc.N_CORNERS, nc))
        for i, c in enumerate(corners):
            dps[i, :c[2].size] = c[2]
            cps[i, :c[5].size] = c[5]
        modal = self.modal if self.modal is not None else ModalParams()
        return {
            't': t, 'mb': mb, 'arb': arb,
            'car_ps': np.stack([c[0] for c in corners]),
            'law': np.array([c[1] for c in corners], dtype=np.int64),
            'dps': dps,
            'drv_ps': np.stack([c[3] for c in corners]),
            'cid': np.array([c[4] for c in corners], dtype=np.int64),
            'cps': cps,
            'use_modal': self.modal is not None,
            'g': modal_map(t) if self.coupled else np.zeros((fc.N_CORNERS, 6)),
            'mp': modal.to_array(self.car) if self.modal is not None else modal.to_array(),
            'seat': np.array([self.car.seat_x, self.car.seat_y]),
            'n_dstate': max(dmp.n_state_of(d) for d in self.damper) + 8,
            'delay': int(round(self.control_delay / self.dt)),
        }


@dataclass(frozen=True)
class FullCarResult:
    """Time histories of a full-car run (SI units).

    ``body``: steps x :data:`BODY_CHANNELS`; ``corners``: 4 x steps x
    :data:`~mr_suspension.sim.simulator.CHANNELS` (each corner as a quarter-car
    :class:`~mr_suspension.sim.simulator.SimResult` records it: ``z_s``, ``v_s``, ``a_s`` are
    the body point above the corner); ``acc``: the online sums of :func:`full_car_loop`
    (:meth:`metrics`).
    """

    dt: float
    body: np.ndarray
    corners: np.ndarray
    config: FullCarConfig
    acc: np.ndarray = None

    def metrics(self):
        """Return the run's online metrics as :func:`simulate_batch` gives them (one car)."""
        if self.acc is None:
            raise ValueError('FullCarResult.metrics: this result carries no online sums')
        return metrics_from_acc(self.acc[None, :], self.body.shape[0], self.dt)

    @property
    def t(self):
        """Sample times [s] (end of each step)."""
        return (np.arange(self.body.shape[0]) + 1) * self.dt

    def channel(self, name, corner=None):
        """Return a body channel, or a corner channel of ``corner`` (index or name)."""
        if corner is None:
            if name not in BODY_CHANNELS:
                raise ValueError(f'unknown body channel {name!r}; known {BODY_CHANNELS}')
            return self.body[:, BODY_CHANNELS.index(name)]
        if isinstance(corner, str):
            if corner not in fc.CORNERS:
                raise ValueError(f'unknown corner {corner!r}; known {fc.CORNERS}')
            corner = fc.CORNERS.index(corner)
        if name not in CHANNELS:
            raise ValueError(f'unknown corner channel {name!r}; known {CHANNELS}')
        return self.corners[corner, :, CHANNELS.index(name)]

    def comfort(self, at='seat'):
        """Return the ISO 2631-1 comfort at ``'seat'`` or ``'cg'``.

        A :class:`~mr_suspension.core.comfort.Comfort`.
        """
        if at not in ('seat', 'cg'):
            raise ValueError(f"comfort: at must be 'seat' or 'cg', got {at!r}")
        x, y = ((self.config.car.seat_x, self.config.car.seat_y) if at == 'seat'
                else (0.0, 0.0))
        return comfort(self.channel('a_z'), self.channel('alpha_pitch'),
                       self.channel('alpha_roll'), self.dt, x=x, y=y)

    def summary(self):
        """Typed figures of the run (:class:`FullCarFigures`)."""
        seat = self.comfort('seat')
        static = [self.config.car.corner(i).static_tyre_load for i in range(fc.N_CORNERS)]
        return FullCarFigures(
            seat=seat, cg=self.comfort('cg'),
            working_space_rms=tuple(float(np.sqrt(np.mean(self.channel('stroke', i) ** 2)))
                                    for i in range(fc.N_CORNERS)),
            tyre_load_rms=tuple(float(np.sqrt(np.mean((self.channel('f_t', i) - static[i])
                                                      ** 2)))
                                for i in range(fc.N_CORNERS)))


@dataclass(frozen=True)
class FullCarFigures:
    """Comfort at the seat and the CG; working space and dynamic tyre load per wheel."""

    seat: Comfort
    cg: Comfort
    working_space_rms: tuple
    tyre_load_rms: tuple


@njit(cache=True)
def full_car_loop(t, mb, arb, car_ps, law, dps, dss, drv_ps, drv_ss, cid, cps, css, use_modal,
                  g, mp, road_z, road_zd, dt, delay_n, seat, q, body_out, corner_out, record,
                  wk, we, acc):
    """Run the full car over its four roads (module doc); metrics into ``acc``.

    ``acc`` accumulates the body figures of :data:`BODY_METRICS` as sums (squares, fourth
    powers) and per corner [sum x^2, max |x|, sum dF_t^2, min F_t, sum F_d v dt].
    """
    nc = fc.N_CORNERS
    nb = int(arb[0])
    n = road_z.shape[1] - 1
    meas = np.zeros((nc, laws.N_MEAS))
    imu = np.zeros(3)
    ms = np.zeros(N_MODAL_STATE)
    dbuf = np.zeros((nc, DELAY_BUFFER))
    head = 0
    a = np.zeros(8)
    f_t = np.zeros(nc)
    f_d = np.zeros(nc)
    c_d = np.zeros(nc)
    coil = np.full(nc, math.nan)
    field_i = np.zeros(nc)
    i_cmd = np.zeros(nc)
    z_r = np.zeros(nc)
    zr_dot = np.zeros(nc)
    xs = np.zeros(nc)
    vs = np.zeros(nc)
    f_t0 = np.zeros(nc)
    for i in range(nc):
        f_t0[i] = (car_ps[i, 0] + car_ps[i, 1]) * car_ps[i, 8]
        acc[N_BODY_ACC + 5 * i + 3] = 1e300
    zw = np.zeros((wk.shape[0], 2))
    zs_w = np.zeros((wk.shape[0], 2))
    zp = np.zeros((we.shape[0], 2))
    zr = np.zeros((we.shape[0], 2))
    wm = np.zeros((3, fc.N_BODY_MAX + nc, fc.N_BODY_MAX + nc))
    wv = np.zeros((12, fc.N_BODY_MAX + nc))
    for k in range(n):
        for i in range(nc):
            x, v = fc.corner_motion(t, nb, q, i)
            xs[i] = x
            vs[i] = v
            a_s = 0.0
            for j in range(nb):
                a_s += t[i, j] * a[j]
            _, v_s = fc.body_point(t, nb, q, i)
            meas[i, 0] = a_s
            meas[i, 1] = a[fc.WHEEL0 + i]
            meas[i, 2] = x
            meas[i, 3] = v
            meas[i, 4] = v_s
            meas[i, 5] = q[fc.RATE0 + fc.WHEEL0 + i]
            meas[i, 6] = coil[i]
        if use_modal:
            imu[0] = a[0]
            imu[1] = q[fc.RATE0 + 1]
            imu[2] = q[fc.RATE0 + 2]
            modal_step(g, mp, ms, imu, cps, css, meas, dt, i_cmd)
        else:
            for i in range(nc):
                i_cmd[i] = laws.controller_step(cid[i], cps[i], css[i], meas[i], dt)
        for i in range(nc):
            if delay_n > 0:
                i_apply = dbuf[i, head]
                dbuf[i, head] = i_cmd[i]
            else:
                i_apply = i_cmd[i]
            coil[i], field_i[i] = driver_step(drv_ps[i], drv_ss[i], i_apply)
            f_d[i], c_d[i] = dmp.damper_force(law[i], dps[i], dss[i], xs[i], vs[i], field_i[i],
                                              dt)
            z_r[i] = 0.5 * (road_z[i, k] + road_z[i, k + 1])
            zr_dot[i] = 0.5 * (road_zd[i, k] + road_zd[i, k + 1])
        if delay_n > 0:
            head = (head + 1) % delay_n
        fc.full_car_step(t, mb, arb, car_ps, q, f_d, c_d, z_r, zr_dot, dt, a, f_t, wm, wv)
        # Body figures: heave, pitch and roll (coupled); the seat point's vertical.
        a_z = a[0]
        a_p = a[1] if nb == 3 else 0.0
        a_rl = a[2] if nb == 3 else 0.0
        a_seat = a_z - seat[0] * a_p + seat[1] * a_rl
        y_cg = sos_step(wk, zw, a_z)
        y_seat = sos_step(wk, zs_w, a_seat)
        y_p = sos_step(we, zp, a_p)
        y_r = sos_step(we, zr, a_rl)
        acc[0] += a_z * a_z
        acc[1] += y_cg * y_cg
        acc[2] += y_seat * y_seat
        acc[3] += y_seat * y_seat * y_seat * y_seat
        acc[4] += y_p * y_p
        acc[5] += y_r * y_r
        acc[6] += a_p * a_p
        acc[7] += a_rl * a_rl
        for i in range(nc):
            x, v = fc.corner_motion(t, nb, q, i)
            o = N_BODY_ACC + 5 * i
            acc[o] += x * x
            acc[o + 1] = max(acc[o + 1], abs(x))
            acc[o + 2] += (f_t[i] - f_t0[i]) * (f_t[i] - f_t0[i])
            acc[o + 3] = min(acc[o + 3], f_t[i])
            acc[o + 4] += f_d[i] * vs[i] * dt
            if record:
                z_s, v_s = fc.body_point(t, nb, q, i)
                a_s = 0.0
                for j in range(nb):
                    a_s += t[i, j] * a[j]
                corner_out[i, k, 0] = z_s
                corner_out[i, k, 1] = q[fc.WHEEL0 + i]
                corner_out[i, k, 2] = v_s
                corner_out[i, k, 3] = q[fc.RATE0 + fc.WHEEL0 + i]
                corner_out[i, k, 4] = a_s
                corner_out[i, k, 5] = a[fc.WHEEL0 + i]
                corner_out[i, k, 6] = x
                corner_out[i, k, 7] = v
                corner_out[i, k, 8] = f_d[i]
                corner_out[i, k, 9] = f_t[i]
                corner_out[i, k, 10] = i_cmd[i]
                corner_out[i, k, 11] = coil[i]
                corner_out[i, k, 12] = field_i[i]
                corner_out[i, k, 13] = road_z[i, k + 1]
        if record:
            body_out[k, 0] = q[0]
            body_out[k, 1] = q[1] if nb == 3 else 0.0
            body_out[k, 2] = q[2] if nb == 3 else 0.0
            body_out[k, 3] = q[fc.RATE0]
            body_out[k, 4] = q[fc.RATE0 + 1] if nb == 3 else 0.0
            body_out[k, 5] = q[fc.RATE0 + 2] if nb == 3 else 0.0
            body_out[k, 6] = a_z
            body_out[k, 7] = a_p
            body_out[k, 8] = a_rl


def _check_road(road, dt):
    if not isinstance(road, CarRoad):
        raise ValueError(f'full car: road must be a CarRoad (four wheels), got '
                         f'{type(road).__name__}; core.car_road.from_track makes one from a '
                         'single track')
    if abs(road.dt - dt) > 1e-12 * dt:
        raise ValueError(f'road sampled at dt={road.dt} but the simulator steps at dt={dt}')


def _states(arr):
    nc = fc.N_CORNERS
    return (np.zeros((nc, arr['n_dstate'])), np.zeros((nc, DRIVER_STATE_SIZE)),
            np.zeros((nc, laws.N_CTRL_STATE)), np.zeros(fc.N_FULL_STATE))


def simulate(config, road):
    """Simulate the full car over a four-wheel ``road``; returns a :class:`FullCarResult`."""
    if not isinstance(config, FullCarConfig):
        raise ValueError('full_car_sim.simulate: config must be a FullCarConfig')
    _check_road(road, config.dt)
    arr = config.arrays()
    dss, drv_ss, css, q = _states(arr)
    n = road.n_steps
    body = np.zeros((n, len(BODY_CHANNELS)))
    corners = np.zeros((fc.N_CORNERS, n, len(CHANNELS)))
    acc = np.zeros(N_ACC)
    full_car_loop(arr['t'], arr['mb'], arr['arb'], arr['car_ps'], arr['law'], arr['dps'], dss,
                  arr['drv_ps'], drv_ss, arr['cid'], arr['cps'], css, arr['use_modal'],
                  arr['g'], arr['mp'], road.z, road.zdot, config.dt, arr['delay'],
                  arr['seat'], q, body, corners, True, _wk(config.dt), _we(config.dt), acc)
    if not (np.all(np.isfinite(body)) and np.all(np.isfinite(corners))):
        raise FloatingPointError('full-car simulation diverged (non-finite state); check '
                                 'parameters')
    return FullCarResult(config.dt, body, corners, config, acc)


@njit(parallel=True, cache=True)
def _batch(ts, mbs, arbs, car_ps, laws_, dps, drv_ps, cids, cps, use_modal, gs, mps, seats,
           road_idx, roads_z, roads_zd, dt, delays, n_dstate, wk, we, acc):
    n_cars = ts.shape[0]
    dummy_b = np.zeros((1, len(BODY_CHANNELS)))
    dummy_c = np.zeros((fc.N_CORNERS, 1, len(CHANNELS)))
    for c in prange(n_cars):
        dss = np.zeros((fc.N_CORNERS, n_dstate))
        drv_ss = np.zeros((fc.N_CORNERS, DRIVER_STATE_SIZE))
        css = np.zeros((fc.N_CORNERS, laws.N_CTRL_STATE))
        q = np.zeros(fc.N_FULL_STATE)
        r = road_idx[c]
        full_car_loop(ts[c], mbs[c], arbs[c], car_ps[c], laws_[c], dps[c], dss, drv_ps[c],
                      drv_ss, cids[c], cps[c], css, use_modal[c], gs[c], mps[c], roads_z[r],
                      roads_zd[r], dt, delays[c], seats[c], q, dummy_b, dummy_c, False, wk,
                      we, acc[c])


def _pad_stack(arrays):
    shape = tuple(max(a.shape[d] for a in arrays) for d in range(arrays[0].ndim))
    out = np.zeros((len(arrays),) + shape)
    for k, a in enumerate(arrays):
        out[(k,) + tuple(slice(0, s) for s in a.shape)] = a
    return out


@dataclass(frozen=True)
class FullCarMetrics:
    """Online metrics of a batch of full cars: one array per figure (one value per car).

    ``body``: :data:`BODY_METRICS` -> array (n_cars); ``corners``:
    :data:`CORNER_METRICS` -> array (n_cars x 4); ``comfort``: the ISO 2631-1 total at the
    seat, ``sqrt(a_wz^2 + (k_pitch a_wpitch)^2 + (k_roll a_wroll)^2)`` [m/s^2].
    """

    body: dict
    corners: dict
    comfort: np.ndarray


def kernel_of(config, fast=True):
    """Name the kernel :func:`simulate_batch` runs a car on: 'batch' or 'reference'.

    'batch': :func:`~mr_suspension.sim.full_car_batch.run` (cars as SIMD lanes, every corner
    law and the modal law with stateless affine-tanh dampers; metrics equal to
    :func:`simulate`'s to round-off); 'reference': :func:`full_car_loop`, one car per thread
    (any damper, sensor noise, model options).
    """
    return 'batch' if fast and full_car_batch.eligible(config) else 'reference'


def simulate_batch(configs, roads, road_index=None, fast=True):
    """Simulate many full cars in parallel; returns :class:`FullCarMetrics`.

    ``configs``: :class:`FullCarConfig` (same ``dt``); ``roads``: :class:`CarRoad` of equal
    length; ``road_index[c]``: the road car ``c`` drives (default: the first). Each car takes
    the fastest kernel that computes its :func:`simulate` result (:func:`kernel_of`): the
    vectorised :mod:`~mr_suspension.sim.full_car_batch`, or :func:`full_car_loop` one car per
    thread; ``fast=False`` forces the latter for every car.
    """
    configs = list(configs)
    roads = list(roads)
    if not configs or not roads:
        raise ValueError('full_car_sim.simulate_batch needs at least one config and one road')
    for c in configs:
        if not isinstance(c, FullCarConfig):
            raise ValueError('full_car_sim.simulate_batch: configs must be FullCarConfig')
    dt = configs[0].dt
    if any(abs(c.dt - dt) > 1e-15 for c in configs):
        raise ValueError('full_car_sim.simulate_batch: all cars must share dt')
    for road in roads:
        _check_road(road, dt)
    n = roads[0].z.shape[1]
    for road in roads:
        if road.z.shape[1] != n:
            raise ValueError('full_car_sim.simulate_batch: all roads must have the same '
                             'length')
    nc = len(configs)
    if road_index is None:
        road_index = np.zeros(nc, dtype=np.int64)
    road_index = np.asarray(road_index)
    if (road_index.shape != (nc,) or not np.issubdtype(road_index.dtype, np.integer)
            or road_index.min() < 0 or road_index.max() >= len(roads)):
        raise ValueError(f'full_car_sim.simulate_batch: road_index must be {nc} integers '
                         f'from 0 to {len(roads) - 1}')
    road_index = road_index.astype(np.int64)
    roads_z = np.stack([r.z for r in roads])
    roads_zd = np.stack([r.zdot for r in roads])
    memo = {}
    kinds = []
    for c in configs:  # the choice depends on the car, the dampers and the controllers only
        key = (id(c.car.front), id(c.car.rear), tuple(map(id, c.damper)), id(c.controller),
               id(c.modal))
        if key not in memo:
            memo[key] = kernel_of(c, fast)
        kinds.append(memo[key])
    kinds = np.array(kinds)
    acc = np.zeros((nc, N_ACC))
    sel = np.flatnonzero(kinds == 'batch')
    if sel.size:
        acc[sel] = full_car_batch.run([configs[j] for j in sel], road_index[sel], roads_z,
                                      roads_zd, dt, _wk(dt), _we(dt))
    sel = np.flatnonzero(kinds == 'reference')
    if sel.size:
        acc[sel] = _reference([configs[j] for j in sel], road_index[sel], roads_z, roads_zd,
                              dt)
    return metrics_from_acc(acc, n - 1, dt)


def _reference(configs, road_index, roads_z, roads_zd, dt):
    """Run cars one per thread with :func:`full_car_loop`; returns their sums."""
    arrs = [c.arrays() for c in configs]
    acc = np.zeros((len(configs), N_ACC))
    _batch(np.stack([a['t'] for a in arrs]), np.stack([a['mb'] for a in arrs]),
           np.stack([a['arb'] for a in arrs]), np.stack([a['car_ps'] for a in arrs]),
           np.stack([a['law'] for a in arrs]), _pad_stack([a['dps'] for a in arrs]),
           np.stack([a['drv_ps'] for a in arrs]), np.stack([a['cid'] for a in arrs]),
           _pad_stack([a['cps'] for a in arrs]),
           np.array([a['use_modal'] for a in arrs]), np.stack([a['g'] for a in arrs]),
           np.stack([a['mp'] for a in arrs]), np.stack([a['seat'] for a in arrs]),
           road_index, roads_z, roads_zd, dt,
           np.array([a['delay'] for a in arrs], dtype=np.int64),
           max(a['n_dstate'] for a in arrs), _wk(dt), _we(dt), acc)
    return acc


def metrics_from_acc(acc, steps, dt):
    """Turn the loop's sums into :class:`FullCarMetrics`."""
    acc = np.asarray(acc)
    body = {
        'heave_acc_rms': np.sqrt(acc[:, 0] / steps),
        'heave_wk_rms': np.sqrt(acc[:, 1] / steps),
        'seat_wk_rms': np.sqrt(acc[:, 2] / steps),
        'seat_vdv': (acc[:, 3] * dt) ** 0.25,
        'pitch_we_rms': np.sqrt(acc[:, 4] / steps),
        'roll_we_rms': np.sqrt(acc[:, 5] / steps),
        'pitch_acc_rms': np.sqrt(acc[:, 6] / steps),
        'roll_acc_rms': np.sqrt(acc[:, 7] / steps),
    }
    per = acc[:, N_BODY_ACC:].reshape(acc.shape[0], fc.N_CORNERS, len(CORNER_METRICS))
    corners = {
        'working_space_rms': np.sqrt(per[:, :, 0] / steps),
        'working_space_peak': per[:, :, 1],
        'tyre_load_rms': np.sqrt(per[:, :, 2] / steps),
        'ntf_min': per[:, :, 3],
        'damper_energy': per[:, :, 4],
    }
    total = np.sqrt(body['seat_wk_rms'] ** 2 + (K_RY * body['pitch_we_rms']) ** 2
                    + (K_RX * body['roll_we_rms']) ** 2)
    return FullCarMetrics(body, corners, total)


def check_duration(duration):
    """Validate a simulated duration [s]."""
    return check_range('full car', 'duration', duration, 1e-3, 3600.0, 's', 'simulated time')
