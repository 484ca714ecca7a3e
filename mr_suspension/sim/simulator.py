"""Fixed-step offline simulator: plant + driver + damper + controller, single corner or batch.

One step at ``t_n`` (the node set runs the same functions in the same order):

1. the controller reads the measurements (body/wheel acceleration, stroke and its rate, body
   and wheel velocity, field current) and returns a current command, delayed by
   ``control_delay`` (sensor and compute latency);
2. the driver and fluid turn it into coil and field current (:mod:`~mr_suspension.core.driver`);
3. the damper law gives the force and its tangent at the present stroke and rate;
4. the plant advances with the linearly implicit trapezoidal step
   (:func:`~mr_suspension.core.quarter_car.plant_step`), road at mid-step.

Deterministic: no randomness is drawn here (roads are generated from a seed beforehand).
"""

from dataclasses import dataclass, field, replace
from functools import lru_cache
import math

from numba import njit, prange
import numpy as np

from mr_suspension.control.laws import controller_step, ControllerParams, N_CTRL_STATE, N_MEAS
from mr_suspension.core import damper as dmp
from mr_suspension.core.driver import DRIVER_STATE_SIZE, driver_step, DriverParams, prepare
from mr_suspension.core.metrics import rms, sos_step, wk_sos
from mr_suspension.core.quarter_car import CAR_G, CAR_MS, CAR_MU, N_STATE, plant_step
from mr_suspension.core.quarter_car import QuarterCarParams, strut_motion, VS, VU, ZS, ZU
from mr_suspension.core.validation import check_range
from mr_suspension.sim import batch

# Recorded channels of a single-corner run.
CHANNELS = ('z_s', 'z_u', 'v_s', 'v_u', 'a_s', 'a_u', 'stroke', 'stroke_rate', 'f_d', 'f_t',
            'i_cmd', 'i_coil', 'i_field', 'z_r')
(CH_ZS, CH_ZU, CH_VS, CH_VU, CH_AS, CH_AU, CH_X, CH_V, CH_FD, CH_FT, CH_ICMD, CH_ICOIL,
 CH_IFIELD, CH_ZR) = range(len(CHANNELS))
# Online metrics of a batch run.
BATCH_METRICS = ('body_acc_rms', 'body_acc_peak', 'body_acc_wk_rms', 'vdv',
                 'working_space_rms', 'working_space_peak', 'tyre_load_rms', 'ntf_min',
                 'damper_energy')
DELAY_BUFFER = 256


@lru_cache(maxsize=8)
def _wk(dt):
    """Wk filter sections for ``dt``, designed once (scipy's design takes about 2 ms); shared."""
    return wk_sos(dt)


@dataclass(frozen=True)
class CornerConfig:
    """Everything that defines one simulated corner (SI units)."""

    car: QuarterCarParams = field(default_factory=QuarterCarParams)
    damper: object = field(default_factory=dmp.BinghamParams)
    driver: DriverParams = field(default_factory=DriverParams)
    controller: ControllerParams = field(default_factory=ControllerParams)
    dt: float = 1e-3
    control_delay: float = 0.0

    def __post_init__(self):
        check_range('CornerConfig', 'dt', self.dt, 1.0e-6, 0.01, 's',
                    'time step; > 0.01 s is neither stable nor accurate')
        check_range('CornerConfig', 'control_delay', self.control_delay, 0.0, 0.25, 's',
                    'sensor and compute delay')
        if self.control_delay / self.dt > DELAY_BUFFER - 1:
            raise ValueError(f'CornerConfig: control_delay must be < {DELAY_BUFFER} steps '
                             f'({(DELAY_BUFFER - 1) * self.dt:g} s at dt = {self.dt:g} s); '
                             'shorten it or use a larger --dt')
        for name, cls in (('car', QuarterCarParams), ('driver', DriverParams),
                          ('controller', ControllerParams)):
            if not isinstance(getattr(self, name), cls):
                raise ValueError(f'CornerConfig: {name} must be a {cls.__name__}')
        dmp.law_id_of(self.damper)

    def replace(self, **changes):
        """Return a copy with fields replaced."""
        return replace(self, **changes)

    def damper_static_force(self):
        """Damper force at rest (x = 0, v = 0, zero current): balanced by the spring preload."""
        s = np.zeros(dmp.n_state_of(self.damper) + 8)
        return float(dmp.damper_force(dmp.law_id_of(self.damper), self.damper.to_array(), s,
                                      0.0, 0.0, 0.0, self.dt)[0])

    def arrays(self):
        """Parameter arrays for the jitted kernels: (car, law, damper, driver, cid, ctrl)."""
        return (self.car.to_array(self.damper_static_force()), dmp.law_id_of(self.damper),
                self.damper.to_array(), prepare(self.driver, self.dt), self.controller.law_id,
                self.controller.to_array())


@dataclass(frozen=True)
class SimResult:
    """Time histories of a single-corner run (SI units); see :data:`CHANNELS`."""

    dt: float
    data: np.ndarray
    static_tyre_load: float
    config: CornerConfig

    def __getattr__(self, name):
        if name in CHANNELS:
            return self.data[:, CHANNELS.index(name)]
        raise AttributeError(name)

    @property
    def t(self):
        """Sample times [s] (end of each step)."""
        return (np.arange(self.data.shape[0]) + 1) * self.dt

    def to_csv(self, path):
        """Write ``time`` plus all channels as CSV with a header."""
        header = ','.join(('time',) + CHANNELS)
        np.savetxt(path, np.column_stack([self.t, self.data]), delimiter=',', header=header,
                   comments='', fmt='%.9g')


@njit(cache=True)
def corner_loop(car_p, law, dp, ds, drv_p, drv_s, cid, cp, cs, road_z, road_zd, dt,
                delay_n, q, out, record, sos, acc):
    """Run one corner over the road; records channels into ``out`` and metrics into ``acc``.

    ``acc`` accumulates [sum a^2, max |a|, sum a_w^2, sum a_w^4, sum x^2, max |x|,
    sum dF_t^2, min F_t, sum F_d v dt]. The law's field-current slot gets what a car measures:
    the driver's coil current of the step before (NaN at the first step), as the node set's
    controller gets it from ``coil_current``.
    """
    n = road_z.shape[0] - 1
    m = np.zeros(N_MEAS)
    dbuf = np.zeros(DELAY_BUFFER)
    head = 0
    a_s = 0.0
    a_u = 0.0
    coil = math.nan  # measured coil current of the step before: none yet at k = 0
    nsec = sos.shape[0]
    zi = np.zeros((nsec, 2))
    f_t0 = (car_p[CAR_MS] + car_p[CAR_MU]) * car_p[CAR_G]
    acc[7] = 1e300
    for k in range(n):
        x, v = strut_motion(car_p, q)  # body (or strut top) minus wheel
        m[0] = a_s
        m[1] = a_u
        m[2] = x
        m[3] = v
        m[4] = q[VS]
        m[5] = q[VU]
        m[6] = coil
        i_cmd = controller_step(cid, cp, cs, m, dt)
        if delay_n > 0:
            i_apply = dbuf[head]
            dbuf[head] = i_cmd
            head = (head + 1) % delay_n
        else:
            i_apply = i_cmd
        coil, f_field = driver_step(drv_p, drv_s, i_apply)
        f_d, c_d = dmp.damper_force(law, dp, ds, x, v, f_field, dt)
        z_r = 0.5 * (road_z[k] + road_z[k + 1])
        zr_dot = 0.5 * (road_zd[k] + road_zd[k + 1])
        a_s, a_u, f_t = plant_step(car_p, q, f_d, c_d, z_r, zr_dot, dt)
        y = sos_step(sos, zi, a_s)  # Wk-weighted body acceleration
        xs, vs = strut_motion(car_p, q)
        acc[0] += a_s * a_s
        acc[1] = max(acc[1], abs(a_s))
        acc[2] += y * y
        acc[3] += y * y * y * y
        acc[4] += xs * xs
        acc[5] = max(acc[5], abs(xs))
        acc[6] += (f_t - f_t0) * (f_t - f_t0)
        acc[7] = min(acc[7], f_t)
        acc[8] += f_d * v * dt
        if record:
            out[k, 0] = q[ZS]
            out[k, 1] = q[ZU]
            out[k, 2] = q[VS]
            out[k, 3] = q[VU]
            out[k, 4] = a_s
            out[k, 5] = a_u
            out[k, 6] = xs
            out[k, 7] = vs
            out[k, 8] = f_d
            out[k, 9] = f_t
            out[k, 10] = i_cmd
            out[k, 11] = coil
            out[k, 12] = f_field
            out[k, 13] = road_z[k + 1]


def _delay_steps(config):
    return int(round(config.control_delay / config.dt))


def _check_road(road, dt):
    if abs(road.dt - dt) > 1e-12 * dt:
        raise ValueError(f'road sampled at dt={road.dt} but the simulator steps at dt={dt}')
    if not (np.all(np.isfinite(road.z)) and np.all(np.isfinite(road.zdot))):
        raise ValueError('road profile contains NaN or inf')


def simulate(config, road):
    """Simulate one corner over ``road`` and return a :class:`SimResult`."""
    _check_road(road, config.dt)
    car_p, law, dp, drv_p, cid, cp = config.arrays()
    ds = np.zeros(dmp.n_state_of(config.damper) + 8)
    drv_s = np.zeros(DRIVER_STATE_SIZE)
    cs = np.zeros(N_CTRL_STATE)
    q = np.zeros(N_STATE)
    out = np.empty((road.n_steps, len(CHANNELS)))
    acc = np.zeros(len(BATCH_METRICS))
    corner_loop(car_p, law, dp, ds, drv_p, drv_s, cid, cp, cs, road.z, road.zdot, config.dt,
                _delay_steps(config), q, out, True, _wk(config.dt), acc)
    if not np.all(np.isfinite(out)):
        raise FloatingPointError('simulation diverged (non-finite state); check parameters')
    return SimResult(config.dt, out, config.car.static_tyre_load, config)


@njit(parallel=True, cache=True)
def _batch(car_ps, laws, dps, drv_ps, cids, cps, road_idx, roads_z, roads_zd, dt, delays,
           sos, nstate, acc, rec, out):
    nc = car_ps.shape[0]
    for c in prange(nc):
        ds = np.zeros(nstate)
        drv_s = np.zeros(DRIVER_STATE_SIZE)
        cs = np.zeros(N_CTRL_STATE)
        q = np.zeros(N_STATE)
        r = road_idx[c]
        corner_loop(car_ps[c], laws[c], dps[c], ds, drv_ps[c], drv_s, cids[c], cps[c], cs,
                    roads_z[r], roads_zd[r], dt, delays[c], q, out[c] if rec else out[0],
                    rec, sos, acc[c])


def _stack(arrays):
    width = max(a.size for a in arrays)
    out = np.zeros((len(arrays), width))
    for k, a in enumerate(arrays):
        out[k, :a.size] = a
    return out


def _generic(configs, road_index, roads_z, roads_zd, dt, record):
    """Run corners one per thread with :func:`corner_loop` (any law, any controller)."""
    nc = len(configs)
    arrs = batch.corner_arrays(configs)
    acc = np.zeros((nc, len(BATCH_METRICS)))
    steps = roads_z.shape[1] - 1
    out = np.zeros((nc, steps, len(CHANNELS))) if record else np.zeros((1, 1, len(CHANNELS)))
    nstate = max(dmp.n_state_of(c.damper) for c in configs) + 8
    _batch(_stack([a[0] for a in arrs]), np.array([a[1] for a in arrs], dtype=np.int64),
           _stack([a[2] for a in arrs]), _stack([a[3] for a in arrs]),
           np.array([a[4] for a in arrs], dtype=np.int64), _stack([a[5] for a in arrs]),
           road_index, roads_z, roads_zd, dt,
           np.array([_delay_steps(c) for c in configs], dtype=np.int64), _wk(dt), nstate,
           acc, record, out)
    return acc, (out if record else None)


def kernel_of(config, fast=True, record=False):
    """Name the kernel :func:`simulate_batch` runs a corner on: 'affine', 'exact' or 'generic'.

    'affine': :func:`~mr_suspension.sim.batch.run` (affine-tanh law at constant current,
    reciprocals and fastmath: metrics equal to the one-corner run to about 1e-13); 'exact':
    :func:`~mr_suspension.sim.batch.run_exact` (any control law with estimation, driver and
    stateless affine-tanh damper and inverse model: the one-corner operations in the same
    order, so bit for bit the same numbers); 'generic': :func:`corner_loop` per thread. A corner
    with a model option on (:attr:`QuarterCarParams.options_on`) always takes 'generic'.
    """
    if not fast or config.car.options_on:
        return 'generic'
    if not record and batch.eligible([config]):
        return 'affine'
    return 'exact' if batch.exact_eligible(config) else 'generic'


def simulate_batch(configs, roads, road_index=None, fast=True, record=False):
    """Simulate many corners in parallel; returns a dict of metric arrays (one per corner).

    ``configs`` is a sequence of :class:`CornerConfig` (same ``dt``), ``roads`` a sequence of
    roads of equal length, ``road_index[c]`` which road corner ``c`` drives (default: all the
    first). Metrics are accumulated online. Each corner takes the fastest kernel that computes
    its one-corner result (:func:`kernel_of`); ``fast=False`` forces the generic one.
    ``record=True`` also returns the time histories under ``'data'`` (corners x steps x
    :data:`CHANNELS`, as :attr:`SimResult.data`; memory grows with corners times steps).
    """
    configs = list(configs)
    roads = list(roads)
    if not configs or not roads:
        raise ValueError('simulate_batch needs at least one config and one road')
    for c in configs:
        if not isinstance(c, CornerConfig):
            raise ValueError(f'simulate_batch: configs must be CornerConfig, got '
                             f'{type(c).__name__}')
    dt = configs[0].dt
    if any(abs(c.dt - dt) > 1e-15 for c in configs):
        raise ValueError('simulate_batch: all corners must share dt')
    n = roads[0].z.size
    for road in roads:
        _check_road(road, dt)
        if road.z.size != n or road.zdot.size != n:
            raise ValueError('simulate_batch: all roads must have the same length')
    if n < 2:
        raise ValueError('simulate_batch: a road needs at least two samples (one step)')
    nc = len(configs)
    if road_index is None:
        road_index = np.zeros(nc, dtype=np.int64)
    else:
        raw = np.asarray(road_index)
        if raw.shape != (nc,) or not np.issubdtype(raw.dtype, np.integer):
            raise ValueError(f'simulate_batch: road_index must be {nc} integers (one road per '
                             f'corner), got shape {raw.shape} of {raw.dtype}')
        road_index = raw.astype(np.int64)
    if road_index.min() < 0 or road_index.max() >= len(roads):
        raise ValueError(f'simulate_batch: road_index must give a valid road (0 to '
                         f'{len(roads) - 1}) for every corner')
    roads_z = np.stack([r.z for r in roads])
    roads_zd = np.stack([r.zdot for r in roads])
    steps = n - 1
    sos = _wk(dt)
    memo = {}
    for c in configs:  # the choice depends on the car, the damper and the controller only
        key = (id(c.car), id(c.damper), id(c.controller))
        if key not in memo:
            memo[key] = kernel_of(c, fast, record)
    kinds = np.array([memo[id(c.car), id(c.damper), id(c.controller)] for c in configs])
    acc = np.zeros((nc, len(BATCH_METRICS)))
    data = np.zeros((nc, steps, len(CHANNELS))) if record else None
    for kind in ('affine', 'exact', 'generic'):
        sel = np.flatnonzero(kinds == kind)
        if sel.size == 0:
            continue
        part = [configs[j] for j in sel]
        if kind == 'affine':
            acc[sel] = batch.run(part, road_index[sel], roads_z, roads_zd, dt, sos,
                                 len(BATCH_METRICS))
            continue
        if kind == 'exact':
            a, hist = batch.run_exact(part, road_index[sel], roads_z, roads_zd, dt, sos,
                                      len(BATCH_METRICS), record)
        else:
            a, hist = _generic(part, road_index[sel], roads_z, roads_zd, dt, record)
        acc[sel] = a
        if record:
            data[sel] = hist
    out = _metrics_from_acc(acc, steps, dt)
    if record:
        out['data'] = data
    return out


def _metrics_from_acc(acc, steps, dt):
    acc = np.asarray(acc)
    return {
        'body_acc_rms': np.sqrt(acc[:, 0] / steps),
        'body_acc_peak': acc[:, 1],
        'body_acc_wk_rms': np.sqrt(acc[:, 2] / steps),
        'vdv': (acc[:, 3] * dt) ** 0.25,
        'working_space_rms': np.sqrt(acc[:, 4] / steps),
        'working_space_peak': acc[:, 5],
        'tyre_load_rms': np.sqrt(acc[:, 6] / steps),
        'ntf_min': acc[:, 7],
        'damper_energy': acc[:, 8],
    }


def summary(result):
    """Short dict of the main figures of a run (used by the CLI and the node-set checks)."""
    return {'body_acc_rms': rms(result.a_s), 'working_space_rms': rms(result.stroke),
            'tyre_load_rms': rms(result.f_t - result.static_tyre_load)}
