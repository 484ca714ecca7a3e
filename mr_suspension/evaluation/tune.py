"""Tune a semi-active law's gains over a road set; place every law against the passive family.

Pure numerics (no ROS, no plotting). The design problem of a suspension engineer: for one car,
minimise discomfort and/or dynamic tyre load over a set of roads, with the working space
limited, and compare with the damper at every constant current.

Objective, over the road set ``R``, each road normalised by the softest passive setting (the
damper at the constant current ``i_min``, "soft"), with the comfort weight ``w`` in [0, 1]::

    J = w (1/|R|) sum_r a_wk,r / a_wk,r(soft) + (1 - w) (1/|R|) sum_r dF_t,r / dF_t,r(soft)

``a_wk``: ISO 2631-1 Wk-weighted body acceleration RMS [m/s^2]; ``dF_t``: dynamic tyre load
RMS ``rms(F_t - F_t0)`` [N] (:func:`~mr_suspension.core.metrics.ride_metrics`). Working-space
constraint on every road: ``x_r <= L_r`` with ``x`` the stroke RMS [m] and ``L_r`` = ``ws_limit``
[m] if given, else ``ws_ratio * x_r(soft)``; violation ``g = max_r x_r / L_r - 1``. It enters as
the penalty ``J + RHO max(g, 0)`` with ``RHO = 1000``: an infeasible candidate loses against
every feasible one whose ``J`` is within ``RHO g`` (J is of order 1), i.e. practically Deb's
feasibility rule, without a second simulation per candidate for a separate constraint function.

Optimiser: :func:`scipy.optimize.differential_evolution` (Storn & Price 1997) on the bounded
gains of :data:`SPACES` (damping gains and LQ weights searched in log10, currents linearly or in
log10), ``updating='deferred'`` and ``vectorized=True`` so that a whole generation is one call
of the batch simulator (:func:`mr_suspension.sim.corner.batch_metrics`), a fixed seed (the
result is reproducible), and the default gains as a member of the first population (``x0``):
DE keeps a member only when its trial is better, so the tuned gains are never worse than the
defaults on ``J``. No gradient polish: the on-off laws switch, so ``J`` is only piecewise smooth
in the gains. Why not a local method from a grid: with 1-3 gains and cheap batched candidates a
global population search costs a few seconds and does not depend on where a grid puts the
start; Nelder-Mead or Powell would need a start per basin and evaluate one point at a time.

Independent simulations are grouped in chunks of :data:`CHUNK` corners and mapped with
:func:`mr_suspension.parallel.map_tasks` (serially, on a local dask cluster or on a running
one); the chunking does not depend on the number of workers, so every path gives identical
numbers.

Equal-working-space comparison (:func:`passive_at_equal_space`): the passive family is
interpolated linearly in the current (a 0.005 A grid); the best passive setting for a point is
the current with the lowest comfort term among those whose working space is no larger on any
road of the set; the semi-active gain is ``1 - a_law / a_passive`` (per road, and on the
road-set mean of the normalised Wk RMS).
"""

import copy
from dataclasses import dataclass
import functools
import math
import time

import numpy as np
from scipy import optimize, signal

from mr_suspension import parallel
from mr_suspension.control.laws import ControllerParams, LAW_IDS
from mr_suspension.evaluation import scenarios as scn
from mr_suspension.sim import config as cfg, corner
from mr_suspension.sim.simulator import simulate

RHO = 1000.0
CHUNK = 16
DEFAULT_ROADS = ('iso_B_30', 'iso_C_20', 'bump')
# Metrics kept per candidate and road (ride_metrics names and SI units).
KEYS = ('body_acc_wk_rms', 'tyre_load_rms', 'working_space_rms', 'working_space_peak',
        'body_acc_rms', 'vdv', 'ntf_min')
# Semi-active laws of config/controllers placed on the carpet plot (default gains or tuned).
LAWS = ('skyhook_onoff', 'skyhook', 'groundhook', 'hybrid', 'add', 'sh_add', 'pdd',
        'clipped_optimal', 'febc')


class InfeasibleError(ValueError):
    """No gains of a law (or no damper setting) meet the working-space limit."""


@dataclass(frozen=True)
class Gain:
    """One tuned gain: a ControllerParams field (or ``lqr_weights[k]``), bounds, scale.

    ``lo``/``hi`` in the field's unit; ``None`` as ``hi`` means the driver's current range;
    ``crit``: the bounds are multiples of the body's critical damping ``2 sqrt(k_s m_s)``.
    """

    name: str
    lo: float
    hi: float = None
    log: bool = True
    unit: str = 'A'
    crit: bool = False


_C = {'lo': 0.05, 'hi': 10.0, 'unit': 'N s/m', 'crit': True}
SPACES = {
    'constant': (Gain('current', 0.0, None, False),),
    'skyhook_onoff': (Gain('i_max', 0.05),),
    'skyhook': (Gain('c_sky', **_C), Gain('i_max', 0.1)),
    'groundhook': (Gain('c_ground', **_C), Gain('i_max', 0.1)),
    'hybrid': (Gain('c_sky', **_C), Gain('c_ground', **_C), Gain('alpha', 0.0, 1.0, False, '-')),
    'add': (Gain('i_max', 0.05),),
    'sh_add': (Gain('i_max', 0.05), Gain('f_cross', 0.5, 10.0, True, 'Hz')),
    'pdd': (Gain('i_max', 0.05),),
    'clipped_optimal': (Gain('lqr_weights[1]', 1.0, 1.0e6, True, '-'),
                        Gain('lqr_weights[2]', 1.0, 1.0e6, True, '-'), Gain('i_max', 0.1)),
    'febc': (Gain('febc_i_body', 0.0, None, False), Gain('febc_i_road', 0.0, None, False)),
}


@dataclass(frozen=True)
class Plant:
    """Vehicle, damper, driver (names, paths or objects), roads and step of a tuning study."""

    vehicle: object = 'city_car'
    damper: object = 'rd1005_bingham'
    driver: object = 'wonder_box'
    roads: tuple = DEFAULT_ROADS
    dt: float = 1e-3
    control_delay: float = 0.0

    def corner(self, controller):
        """Corner of ``controller`` (set, law name or ControllerParams) on this plant."""
        return corner.build_corner(controller, self.vehicle, self.damper, self.driver,
                                   dt=self.dt, control_delay=self.control_delay)


def check_roads(roads):
    """Expand and check a road set (scenario names or groups); ValueError if empty/unknown."""
    if isinstance(roads, str):
        roads = [roads]
    if not roads or not [r for r in roads if str(r).strip()]:
        raise ValueError('tune: the road set is empty; give scenario names such as '
                         f'{",".join(DEFAULT_ROADS)}')
    names = scn.expand(list(roads))
    for name in names:
        scn.make(name, 1e-3)  # unknown names raise here, before any simulation
    return tuple(names)


def resolve_law(law):
    """Return ``(label, ControllerParams)`` of a controller set, YAML path or law name."""
    if isinstance(law, ControllerParams):
        return law.law, law
    try:
        base = corner.load_controller(law)
    except ValueError:
        raise ValueError(f'tune: unknown law {law!r}; laws: {sorted(SPACES)}, controller '
                         f'sets: {cfg.available("controllers")}') from None
    if base.law not in SPACES:  # pragma: no cover - every law of LAW_IDS has a space
        raise ValueError(f'tune: no gain space for law {base.law!r}')
    label = str(law) if str(law) in cfg.available('controllers') or law in LAW_IDS \
        else base.law
    return label, base


def gain_bounds(law, plant):
    """Return the gains of ``law`` and their bounds ``[(lo, hi), ...]`` in the field units."""
    car = corner.load_vehicle(plant.vehicle)
    i_range = corner.load_driver(plant.driver).i_range
    c_crit = 2.0 * math.sqrt(car.k_s * car.m_s)
    out = []
    for g in SPACES[law]:
        lo, hi = g.lo, (i_range if g.hi is None else g.hi)
        if g.crit:
            lo, hi = lo * c_crit, hi * c_crit
        if not hi > lo:
            raise ValueError(f'tune: empty range for {g.name}: [{lo:g}, {hi:g}] {g.unit}')
        out.append((g, (lo, hi)))
    return out


def _to_search(g, value):
    return math.log10(max(value, 1e-12)) if g.log else float(value)


def _from_search(g, u):
    return 10.0 ** u if g.log else float(u)


def gains_of(base, space, u):
    """Field changes of ``base`` for the search vector ``u`` (``lqr_weights[k]`` handled)."""
    changes = {}
    weights = list(base.lqr_weights)
    for (g, (lo, hi)), uk in zip(space, u):
        value = min(max(_from_search(g, uk), lo), hi)
        if g.name.startswith('lqr_weights['):
            weights[int(g.name[len('lqr_weights['):-1])] = value
            changes['lqr_weights'] = tuple(weights)
        else:
            changes[g.name] = value
    if 'i_max' in changes:
        changes['i_min'] = min(base.i_min, changes['i_max'])
    return changes


def current_gains(base, space):
    """Values of the tuned gains in ``base`` (for reports and the start member ``x0``)."""
    out = {}
    for g, _ in space:
        if g.name.startswith('lqr_weights['):
            out[g.name] = float(base.lqr_weights[int(g.name[len('lqr_weights['):-1])])
        else:
            out[g.name] = float(getattr(base, g.name))
    return out


@functools.lru_cache(maxsize=32)
def _road(name, dt):
    return scn.make(name, dt).road


def simulate_chunk(task):
    """Metrics of a chunk of corners on every road: array ``(corners, roads, len(KEYS))``.

    ``task = (configs, road_names, dt)``; module level, so dask can ship it to workers.
    """
    configs, road_names, dt = task
    out = np.empty((len(configs), len(road_names), len(KEYS)))
    for r, name in enumerate(road_names):
        met = corner.batch_metrics(configs, [_road(name, dt)])
        for k, key in enumerate(KEYS):
            out[:, r, k] = met[key]
    return out


def evaluate(configs, road_names, dt, dask_client=None):
    """Metrics of corners on roads: ``{key: array (corners, roads)}`` (chunked, mapped)."""
    configs = list(configs)
    chunks = [(tuple(configs[k:k + CHUNK]), tuple(road_names), dt)
              for k in range(0, len(configs), CHUNK)]
    parts = parallel.map_tasks(simulate_chunk, chunks, dask_client=dask_client)
    arr = np.concatenate(parts, axis=0) if parts else np.empty((0, len(road_names), len(KEYS)))
    return {key: arr[:, :, k] for k, key in enumerate(KEYS)}


def passive_sweep(plant, n=81, i_max=None, dask_client=None):
    """Metrics of the damper at ``n`` constant currents from 0 to ``i_max`` (driver range).

    The currents are spaced quadratically, ``I_k = i_max (k / (n - 1))^2``: the family bends
    most at small currents (an MR damper's yield force grows fastest there), where the
    equal-working-space interpolation needs the points. Returns ``{'current': array, key:
    array (n, roads)}``; ``n >= 2``.
    """
    if n < 2:
        raise ValueError(f'tune: the passive sweep needs at least 2 currents, got {n}')
    i_top = corner.load_driver(plant.driver).i_range if i_max is None else i_max
    return _constant_runs(plant, i_top * np.linspace(0.0, 1.0, int(n)) ** 2, dask_client)


def _constant_runs(plant, currents, dask_client=None):
    currents = np.asarray(currents, dtype=float)
    configs = [plant.corner(ControllerParams(law='constant', current=float(i)))
               for i in currents]
    met = evaluate(configs, plant.roads, plant.dt, dask_client)
    met['current'] = currents
    return met


class Objective:
    """``J``, constraint violation ``g`` and penalised value of metric arrays (module doc)."""

    def __init__(self, soft, comfort_weight=1.0, ws_limit=None, ws_ratio=0.9):
        if not 0.0 <= comfort_weight <= 1.0:
            raise ValueError(f'tune: comfort weight must be in [0, 1], got {comfort_weight}')
        self.w = float(comfort_weight)
        self.wk0 = np.asarray(soft['body_acc_wk_rms'], dtype=float)
        self.ft0 = np.asarray(soft['tyre_load_rms'], dtype=float)
        if ws_limit is not None:
            if not ws_limit > 0.0:
                raise ValueError(f'tune: working-space limit must be > 0 m, got {ws_limit}')
            self.limit = np.full(self.wk0.shape, float(ws_limit))
        else:
            if not ws_ratio > 0.0:
                raise ValueError(f'tune: working-space ratio must be > 0, got {ws_ratio}')
            self.limit = ws_ratio * np.asarray(soft['working_space_rms'], dtype=float)

    def with_weight(self, comfort_weight):
        """Copy with another comfort weight (same normalisation and limits)."""
        out = copy.copy(self)
        out.w = float(comfort_weight)
        return out

    def comfort(self, met):
        """Road-set mean of ``a_wk / a_wk(soft)``."""
        return np.mean(np.asarray(met['body_acc_wk_rms']) / self.wk0, axis=-1)

    def road_holding(self, met):
        """Road-set mean of ``dF_t / dF_t(soft)``."""
        return np.mean(np.asarray(met['tyre_load_rms']) / self.ft0, axis=-1)

    def value(self, met):
        """``J = w comfort + (1 - w) road holding``."""
        return self.w * self.comfort(met) + (1.0 - self.w) * self.road_holding(met)

    def violation(self, met):
        """``g = max_r x_r / L_r - 1`` (<= 0: the working space is within the limit)."""
        return np.max(np.asarray(met['working_space_rms']) / self.limit, axis=-1) - 1.0

    def penalised(self, met):
        """``J + RHO max(g, 0)``."""
        return self.value(met) + RHO * np.maximum(self.violation(met), 0.0)

    def to_dict(self):
        """Weights and limits for the report."""
        return {'comfort_weight': self.w, 'ws_limit_m': self.limit.tolist(),
                'soft_wk_rms': self.wk0.tolist(), 'soft_tyre_load_rms': self.ft0.tolist()}


def _row(met, k):
    return {key: np.asarray(met[key])[k].tolist() for key in KEYS}


def check_feasible(objective, sweep, roads):
    """Raise ValueError when no damper setting can meet the working-space limit.

    The stiffest constant current bounds the working space from below in practice (no
    semi-active law reached it in the gain families of ``docs/control.md``); a limit below it
    on some road is infeasible.
    """
    least = np.min(np.asarray(sweep['working_space_rms']), axis=0)
    bad = [k for k in range(len(roads)) if objective.limit[k] < least[k]]
    if bad:
        k = bad[0]
        raise InfeasibleError(f'tune: working-space limit infeasible on {roads[k]}: '
                              f'{1e3 * objective.limit[k]:.3g} mm RMS is below the '
                              f'{1e3 * least[k]:.3g} mm of the stiffest passive setting '
                              f'({sweep["current"][-1]:g} A); raise --ws-limit or --ws-ratio')


def tune_law(law, plant, objective, maxiter=25, seed=1, dask_client=None):
    """Tune the gains of ``law`` (set, YAML path or law name) for ``objective`` on ``plant``.

    Returns a dict: ``law``, ``label``, ``gains`` (names, bounds, units), ``default`` and
    ``tuned`` (gains, per-road metrics, ``J``, ``g``), ``controller`` (the tuned
    :class:`ControllerParams`, without plant knowledge), ``history`` (every evaluated
    candidate: gains and metrics), ``evaluations``, ``wall_s`` and ``message``. ValueError if the
    tuned gains still violate the working-space limit.
    """
    t0 = time.perf_counter()
    label, base = resolve_law(law)
    space = gain_bounds(base.law, plant)
    bounds = [(_to_search(g, lo), _to_search(g, hi)) for g, (lo, hi) in space]
    default = current_gains(base, space)
    u_def = np.array([_to_search(g, default[g.name]) for g, _ in space])
    x0 = np.clip(u_def, [b[0] for b in bounds], [b[1] for b in bounds])
    history = {'u': [], 'met': []}

    def run(u_cols, configs=None):
        u_cols = np.atleast_2d(np.asarray(u_cols, dtype=float).T)  # (members, dims)
        if configs is None:
            configs = [plant.corner(corner.load_controller(base, gains_of(base, space, u)))
                       for u in u_cols]
        met = evaluate(configs, plant.roads, plant.dt, dask_client)
        history['u'].append(u_cols)
        history['met'].append(met)
        return met

    # The default set exactly as configured: row 0 of the history. When its gains lie inside
    # the bounds it competes for the best, so the tuned gains are never worse than it.
    run(x0[:, None], [plant.corner(base)])
    inside = bool(np.allclose(x0, u_def))

    def cost(u_cols):
        return objective.penalised(run(u_cols))

    d = len(space)
    members = 8 + 4 * d
    res = optimize.differential_evolution(
        cost, bounds, maxiter=int(maxiter), popsize=int(math.ceil(members / d)), tol=1e-3,
        mutation=(0.5, 1.0), recombination=0.7, rng=np.random.default_rng(seed),
        polish=False, init='latinhypercube', updating='deferred', vectorized=True,
        x0=x0)
    u_all = np.concatenate(history['u'], axis=0)
    met_all = {key: np.concatenate([m[key] for m in history['met']], axis=0) for key in KEYS}
    pen = objective.penalised(met_all)
    if not inside:
        pen[0] = np.inf
    k_best = int(np.argmin(pen))
    k_def = 0
    out = {'law': base.law, 'label': label, 'evaluations': int(u_all.shape[0]),
           'message': str(res.message), 'generations': int(res.nit),
           'gains': [{'name': g.name, 'lo': lo, 'hi': hi, 'unit': g.unit,
                      'scale': 'log' if g.log else 'linear'} for g, (lo, hi) in space]}
    names = [g.name for g, _ in space]
    for key, k in (('default', k_def), ('tuned', k_best)):
        exact = k == 0  # the set as configured, not its gains through log10 and back
        gains = dict(default) if exact else dict(zip(names, _values(space, u_all[k])))
        out[key] = {'gains': gains,
                    'changes': {} if exact else gains_of(base, space, u_all[k]),
                    'metrics': _row(met_all, k),
                    'J': float(objective.value(met_all)[k]),
                    'comfort': float(objective.comfort(met_all)[k]),
                    'road_holding': float(objective.road_holding(met_all)[k]),
                    'g': float(objective.violation(met_all)[k])}
    out['controller'] = corner.load_controller(base, out['tuned']['changes'])
    out['history'] = {'gains': [_values(space, u) for u in u_all],
                      **{key: met_all[key].tolist() for key in KEYS}}
    out['wall_s'] = time.perf_counter() - t0
    if out['tuned']['g'] > 1e-9:
        k = int(np.argmax(np.asarray(out['tuned']['metrics']['working_space_rms'])
                          / objective.limit))
        raise InfeasibleError(
            f'tune: working-space limit infeasible for {label}: the best gains found still '
            f'use {1e3 * out["tuned"]["metrics"]["working_space_rms"][k]:.3g} mm RMS on '
            f'{plant.roads[k]} (limit {1e3 * objective.limit[k]:.3g} mm); raise --ws-limit '
            'or --ws-ratio')
    return out


def _values(space, u):
    return [min(max(_from_search(g, uk), lo), hi) for (g, (lo, hi)), uk in zip(space, u)]


def _dense(sweep, step=0.005):
    """Passive family interpolated linearly in the current (``step`` A grid)."""
    cur = np.asarray(sweep['current'])
    grid = np.linspace(cur[0], cur[-1], max(2, int(round((cur[-1] - cur[0]) / step)) + 1))
    out = {'current': grid}
    for key in KEYS:
        arr = np.asarray(sweep[key])
        out[key] = np.column_stack([np.interp(grid, cur, arr[:, r])
                                    for r in range(arr.shape[1])])
    return out


def best_passive(sweep, objective, ws=None, plant=None, dask_client=None):
    """Best constant current for ``objective`` with working space ``<= ws`` on every road.

    ``ws``: per-road working-space RMS [m] (default: the objective's limit). The family is
    interpolated linearly in the current; with ``plant`` the pick is refined by simulating 16
    currents between its neighbours in the sweep, so the returned metrics are simulated, not
    interpolated. Returns ``None`` when no current fits, else ``{'current', 'metrics', 'J',
    'comfort', 'road_holding'}`` (metrics per road).
    """
    dense = _dense(sweep)
    ws = objective.limit if ws is None else np.asarray(ws, dtype=float)
    k = _pick(dense, objective, ws)
    if k is None:
        return None
    if plant is not None:
        cur = np.asarray(sweep['current'])
        j = int(np.searchsorted(cur, dense['current'][k]))
        lo, hi = cur[max(j - 1, 0)], cur[min(j + 1, cur.size - 1)]
        runs = _constant_runs(plant, np.linspace(lo, hi, 16), dask_client)
        cand = {key: np.concatenate([np.asarray(sweep[key]), runs[key]])
                for key in ('current',) + KEYS}
        k2 = _pick(cand, objective, ws)
        if k2 is not None:
            dense, k = cand, k2
    return {'current': float(dense['current'][k]), 'metrics': _row(dense, k),
            'J': float(objective.value(dense)[k]), 'comfort': float(objective.comfort(dense)[k]),
            'road_holding': float(objective.road_holding(dense)[k])}


def _pick(family, objective, ws):
    fits = np.all(np.asarray(family['working_space_rms']) <= ws * (1.0 + 1e-9), axis=1)
    if not np.any(fits):
        return None
    return int(np.argmin(np.where(fits, objective.value(family), np.inf)))


def passive_at_equal_space(point, sweep, objective, plant=None, dask_client=None):
    """Compare a law point with the best passive setting using no more working space.

    ``point``: ``{'metrics': per-road metrics}`` of a law. Comparison on the comfort term
    (``comfort_weight = 1``: best passive by Wk RMS) on the road set and per road. Returns
    ``{'current', 'wk_change_pct', 'tyre_change_pct', 'ws_change_pct', 'per_road': [...]}``
    (negative change = the law is better); ``current`` None when no passive setting uses as
    little working space.
    """
    met = point['metrics']
    comfort = objective.with_weight(1.0)
    ws = np.asarray(met['working_space_rms'])
    best = best_passive(sweep, comfort, ws, plant, dask_client)
    out = {'current': None, 'wk_change_pct': math.nan, 'tyre_change_pct': math.nan,
           'ws_change_pct': math.nan, 'per_road': []}
    if best is not None:
        law_c = float(comfort.comfort(met))
        law_t = float(comfort.road_holding(met))
        out.update(current=best['current'],
                   wk_change_pct=100.0 * (law_c / best['comfort'] - 1.0),
                   tyre_change_pct=100.0 * (law_t / best['road_holding'] - 1.0),
                   ws_change_pct=100.0 * float(np.mean(
                       ws / np.asarray(best['metrics']['working_space_rms']) - 1.0)),
                   passive=best)
    dense = _dense(sweep)
    cur = np.asarray(sweep['current'])
    for r in range(ws.size):
        family = dense
        fits = family['working_space_rms'][:, r] <= ws[r] * (1.0 + 1e-9)
        if np.any(fits) and plant is not None:  # refine around the pick by simulation
            k = int(np.argmin(np.where(fits, family['body_acc_wk_rms'][:, r], np.inf)))
            j = int(np.searchsorted(cur, family['current'][k]))
            runs = _constant_runs(plant, np.linspace(cur[max(j - 1, 0)],
                                                     cur[min(j + 1, cur.size - 1)], 16),
                                  dask_client)
            family = {key: np.concatenate([np.asarray(sweep[key]), runs[key]])
                      for key in ('current',) + KEYS}
            fits = family['working_space_rms'][:, r] <= ws[r] * (1.0 + 1e-9)
        if not np.any(fits):
            out['per_road'].append({'current': None, 'wk_change_pct': math.nan,
                                    'tyre_change_pct': math.nan})
            continue
        k = int(np.argmin(np.where(fits, family['body_acc_wk_rms'][:, r], np.inf)))
        out['per_road'].append({
            'current': float(family['current'][k]),
            'passive_wk': float(family['body_acc_wk_rms'][k, r]),
            'passive_tyre': float(family['tyre_load_rms'][k, r]),
            'passive_ws': float(family['working_space_rms'][k, r]),
            'wk_change_pct': 100.0 * (met['body_acc_wk_rms'][r]
                                      / family['body_acc_wk_rms'][k, r] - 1.0),
            'tyre_change_pct': 100.0 * (met['tyre_load_rms'][r]
                                        / family['tyre_load_rms'][k, r] - 1.0)})
    return out


def pareto_front(comfort, road):
    """Return the indices of the points not dominated in (comfort, road holding), sorted."""
    comfort = np.asarray(comfort, dtype=float)
    road = np.asarray(road, dtype=float)
    order = np.lexsort((comfort, road))
    front = []
    best = math.inf
    for k in order:
        if comfort[k] < best:
            front.append(int(k))
            best = comfort[k]
    return front


def default_points(plant, laws=LAWS, dask_client=None):
    """Metrics of each law's ``config/controllers`` set at its default gains: ``{law: row}``."""
    configs = [plant.corner(law) for law in laws]
    met = evaluate(configs, plant.roads, plant.dt, dask_client)
    return {law: _row(met, k) for k, law in enumerate(laws)}


def transmissibility(config, road, nperseg=4096, f_max=25.0):
    """Body-acceleration and tyre-load transmissibility from a random-road run (H1 estimate).

    ``H(f) = |S_zy(f)| / S_zz(f)`` (Welch cross- and auto-spectra, Bendat & Piersol 2010,
    eq. 9.56) with ``z`` the road height and ``y`` the body acceleration [(m/s^2)/m] or the
    dynamic tyre load [N/m]. Returns ``(f, H_acc, H_tyre)`` up to ``f_max`` Hz.
    """
    res = simulate(config, road)
    fs = 1.0 / config.dt
    z = res.z_r
    n = min(int(nperseg), z.size)
    f, pzz = signal.welch(z, fs=fs, nperseg=n)
    _, pza = signal.csd(z, res.a_s, fs=fs, nperseg=n)
    _, pzf = signal.csd(z, res.f_t - res.static_tyre_load, fs=fs, nperseg=n)
    sel = (f > 0.0) & (f <= f_max)
    return f[sel], np.abs(pza[sel]) / pzz[sel], np.abs(pzf[sel]) / pzz[sel]


def study(laws, plant, comfort_weight=1.0, ws_limit=None, ws_ratio=0.9, n_passive=81,
          maxiter=25, seed=1, workers=0, scheduler=None, log=None):
    """Tune ``laws`` and place every law against the passive family (the ``tune`` command).

    Returns a dict with ``plant`` (names), ``roads``, ``objective``, ``passive`` (the sweep),
    ``best_passive`` (at the working-space limit), ``defaults`` (every law of :data:`LAWS` at
    its default gains), ``tuned`` (one :func:`tune_law` result per law, with its
    ``equal_space`` comparison), ``infeasible`` (laws that cannot meet the limit; with one law
    that is an :class:`InfeasibleError`), ``wall_s``.
    """
    t0 = time.perf_counter()
    laws = [laws] if isinstance(laws, str) else list(laws)
    if not laws:
        raise ValueError('tune: no law given')
    for law in laws:
        resolve_law(law)
    roads = check_roads(plant.roads)
    plant = Plant(plant.vehicle, plant.damper, plant.driver, roads, plant.dt,
                  plant.control_delay)
    if n_passive < 11:
        raise ValueError(f'tune: sweep the passive damper over at least 11 currents, got '
                         f'{n_passive}')
    with parallel.client(workers, scheduler) as dc:
        sweep = passive_sweep(plant, n_passive, dask_client=dc)
        soft = {key: sweep[key][0] for key in KEYS}
        objective = Objective(soft, comfort_weight, ws_limit, ws_ratio)
        check_feasible(objective, sweep, roads)
        defaults = default_points(plant, dask_client=dc)
        best_at_limit = best_passive(sweep, objective, plant=plant, dask_client=dc)
        tuned, infeasible = [], []
        for law in laws:
            try:
                res = tune_law(law, plant, objective, maxiter, seed, dc)
            except InfeasibleError as exc:
                if len(laws) == 1:
                    raise
                infeasible.append({'label': str(law), 'message': str(exc)})
                if log:
                    log(f'{exc}: left out')
                continue
            res['equal_space'] = passive_at_equal_space(res['tuned'], sweep, objective, plant,
                                                        dc)
            res['default']['equal_space'] = passive_at_equal_space(res['default'], sweep,
                                                                   objective, plant, dc)
            if log:
                eq = res['equal_space']
                log(f'tuned {res["label"]}: J {res["default"]["J"]:.4f} -> '
                    f'{res["tuned"]["J"]:.4f} in {res["evaluations"]} evaluations, '
                    f'{res["wall_s"]:.1f} s; Wk RMS {eq["wk_change_pct"]:+.1f} % vs the best '
                    'passive setting at equal working space')
            tuned.append(res)
        if not tuned:
            raise InfeasibleError('tune: working-space limit infeasible for every law: '
                                  + '; '.join(x['message'] for x in infeasible))
    return {'plant': {'vehicle': _name(plant.vehicle), 'damper': _name(plant.damper),
                      'driver': _name(plant.driver), 'dt': plant.dt,
                      'control_delay': plant.control_delay},
            'roads': list(roads), 'objective': objective.to_dict(),
            'objective_obj': objective, 'passive': sweep,
            'best_passive': best_at_limit,
            'defaults': defaults, 'tuned': tuned, 'infeasible': infeasible, 'plant_obj': plant,
            'optimiser': {'method': 'scipy.optimize.differential_evolution', 'seed': seed,
                          'maxiter': maxiter, 'strategy': 'best1bin',
                          'updating': 'deferred (one batch simulation per generation)'},
            'wall_s': time.perf_counter() - t0}


def _name(value):
    return value if isinstance(value, str) else type(value).__name__
