"""Tune the full car's laws and place them against the passive damper (carpet plot).

The quarter car's design problem (:mod:`~mr_suspension.evaluation.tune`) on the whole car:
the same objective, constraint and optimiser, with the full car's figures in place of the
corner's. Comfort is the ISO 2631-1 point vibration total value at the driver's seat,
``a_v = sqrt(a_wz^2 + (0.40 a_wpitch)^2 + (0.63 a_wroll)^2)`` (Wk on the seat's vertical, We on
pitch and roll); road holding the dynamic tyre load RMS averaged over the four wheels; the
working space the largest stroke RMS of the four corners. Each is normalised per road by the
softest passive setting (all four dampers at ``i_min``), and the working space is limited to
``ws_ratio`` times the soft car's on every road.

Roads (:func:`scenario`): ``iso_<class>_<speed>`` (two ISO 8608 tracks with the isotropic
left/right coherence, 20 s unless the plant says otherwise, fixed seed), ``bump_left`` /
``bump_right`` (a 5 cm, 2 m bump under one side at 10 m/s), ``bump_both`` (full width).

Laws: every corner law of :mod:`~mr_suspension.control.laws` with the same gains at the four
corners (search space :data:`~mr_suspension.evaluation.tune.SPACES`, damping bounds from the
front corner's critical damping), and ``modal_skyhook`` (:mod:`~mr_suspension.control.modal`)
with its heave, pitch and roll damping each searched over 0.05-10 times that mode's critical
damping ``2 sqrt(k_mode m_mode)`` (rigid tyres), and ``modal_clipped_optimal`` with the
stroke and tyre-deflection weights of its LQ cost searched over 1-1e6 (as the corner law).
"""

from dataclasses import dataclass, field, replace
import functools
import math

import numpy as np
from scipy import optimize

from mr_suspension.control.laws import ControllerParams, LAW_IDS
from mr_suspension.control.modal import ModalParams
from mr_suspension.core import car_road as cr
from mr_suspension.evaluation import tune
from mr_suspension.sim import config as cfg
from mr_suspension.sim import full_car_sim as fs

DEFAULT_ROADS = ('iso_C_20', 'bump_left')
FULL_CAR_LAWS = ('modal_skyhook', 'modal_clipped_optimal') + tuple(sorted(LAW_IDS))
LQ_GAINS = ('lqr_weights[1]', 'lqr_weights[2]')  # stroke, tyre deflection (body acc. = 1)
SCENARIO_DURATION = 20.0
BUMP_DURATION = 5.0
MODAL_GAINS = ('c_heave', 'c_pitch', 'c_roll')
MODAL_BOUNDS = (0.05, 10.0)  # x the mode's critical damping


@dataclass(frozen=True)
class FullCarPlant:
    """Full car, damper, driver (names, paths or objects), road names and step of a study."""

    vehicle: object = 'lisa_full_car'
    damper: object = 'rd1005_bingham'
    driver: object = 'wonder_box'
    roads: tuple = DEFAULT_ROADS
    dt: float = 1e-3
    duration: float = SCENARIO_DURATION

    @functools.cached_property
    def car(self):
        """The :class:`~mr_suspension.core.full_car.FullCarParams`."""
        if isinstance(self.vehicle, str):
            return cfg.load_full_car(self.vehicle)
        return self.vehicle

    @functools.cached_property
    def parts(self):
        """``(damper, driver)`` parameter objects."""
        damper = cfg.load_damper(self.damper) if isinstance(self.damper, str) else self.damper
        driver = cfg.load_driver(self.driver) if isinstance(self.driver, str) else self.driver
        return damper, driver

    def config(self, controller, modal=None):
        """:class:`~mr_suspension.sim.full_car_sim.FullCarConfig` of a law on this plant."""
        damper, driver = self.parts
        return fs.FullCarConfig(car=self.car, damper=damper, driver=driver,
                                controller=controller, modal=modal, dt=self.dt)

    def road(self, name):
        """Return the four-wheel road of scenario ``name``."""
        return scenario(name, self.car, self.dt, self.duration)


@functools.lru_cache(maxsize=16)
def _scenario(name, wheelbase, track, dt, duration):
    if name.startswith('iso_'):
        parts = name.split('_')
        if len(parts) != 3:
            raise ValueError(f'full car: scenario {name!r} is not iso_<class>_<speed>')
        try:
            speed = float(parts[2])
        except ValueError:
            raise ValueError(f'full car: speed of {name!r} is not a number') from None
        return cr.iso8608_two_track(parts[1], speed, duration, dt, seed=1,
                                    track=track, wheelbase=wheelbase)
    sides = {'bump_left': 'left', 'bump_right': 'right', 'bump_both': 'both'}
    if name in sides:
        return cr.bump(0.05, 2.0, 10.0, t0=0.5, side=sides[name],
                       duration=min(duration, BUMP_DURATION), dt=dt, track=track,
                       wheelbase=wheelbase)
    raise ValueError(f'full car: unknown scenario {name!r}; use iso_<class>_<speed>, '
                     'bump_left, bump_right or bump_both')


def scenario(name, car, dt=1e-3, duration=SCENARIO_DURATION):
    """Four-wheel road of a named scenario for ``car`` (module doc); bumps last at most 5 s."""
    fs.check_duration(duration)
    return _scenario(str(name), car.wheelbase, car.track_f, dt, float(duration))


KEYS = ('body_acc_wk_rms', 'tyre_load_rms', 'working_space_rms', 'heave_wk_rms',
        'pitch_we_rms', 'roll_we_rms')


def evaluate(configs, plant):
    """Figures of full cars on the plant's roads: ``{key: array (cars, roads)}``.

    ``body_acc_wk_rms`` holds the seat's ISO 2631-1 total (the key the quarter car's
    :class:`~mr_suspension.evaluation.tune.Objective` reads), ``tyre_load_rms`` the four
    wheels' mean, ``working_space_rms`` the largest corner's.
    """
    configs = list(configs)
    out = {key: np.empty((len(configs), len(plant.roads))) for key in KEYS}
    for r, name in enumerate(plant.roads):
        met = fs.simulate_batch(configs, [plant.road(name)])
        out['body_acc_wk_rms'][:, r] = met.comfort
        out['tyre_load_rms'][:, r] = met.corners['tyre_load_rms'].mean(axis=1)
        out['working_space_rms'][:, r] = met.corners['working_space_rms'].max(axis=1)
        out['heave_wk_rms'][:, r] = met.body['seat_wk_rms']
        out['pitch_we_rms'][:, r] = met.body['pitch_we_rms']
        out['roll_we_rms'][:, r] = met.body['roll_we_rms']
    return out


def passive_sweep(plant, n=21):
    """Run the dampers at ``n`` constant currents ``i_max (k / (n - 1))^2`` (driver range)."""
    if n < 2:
        raise ValueError(f'full car: the passive sweep needs at least 2 currents, got {n}')
    i_top = plant.parts[1].i_range
    currents = i_top * np.linspace(0.0, 1.0, int(n)) ** 2
    met = evaluate([plant.config(ControllerParams(law='constant', current=float(i)))
                    for i in currents], plant)
    met['current'] = currents
    return met


def modal_critical(car):
    """Critical damping ``2 sqrt(k m)`` of heave, pitch and roll with rigid tyres."""
    k_f, k_r = car.front.k_s, car.rear.k_s
    k_heave = 2.0 * (k_f + k_r)
    k_pitch = 2.0 * (k_f * car.a ** 2 + k_r * car.b ** 2)
    k_roll = (0.5 * (k_f + 2.0 * car.k_arb_f) * car.track_f ** 2
              + 0.5 * (k_r + 2.0 * car.k_arb_r) * car.track_r ** 2)
    return (2.0 * math.sqrt(k_heave * car.m_b), 2.0 * math.sqrt(k_pitch * car.i_yy),
            2.0 * math.sqrt(k_roll * car.i_xx))


@dataclass(frozen=True)
class Space:
    """Search space of one law: gain names, bounds in the field units, log scale flags."""

    law: str
    names: tuple
    bounds: tuple
    log: tuple

    def to_search(self, values):
        """Gain values -> search vector."""
        return np.array([math.log10(v) if lg else v
                         for v, lg in zip(values, self.log)])

    def from_search(self, u):
        """Search vector -> gain values clipped to the bounds."""
        return tuple(min(max(10.0 ** x if lg else float(x), lo), hi)
                     for x, lg, (lo, hi) in zip(u, self.log, self.bounds))


def space(law, plant):
    """Return the :class:`Space` of ``law`` on ``plant`` (module doc)."""
    if law == 'modal_skyhook':
        crit = modal_critical(plant.car)
        return Space(law, MODAL_GAINS, tuple((MODAL_BOUNDS[0] * c, MODAL_BOUNDS[1] * c)
                                             for c in crit), (True,) * 3)
    if law == 'modal_clipped_optimal':
        return Space(law, LQ_GAINS, ((1.0, 1.0e6), (1.0, 1.0e6)), (True, True))
    if law not in tune.SPACES:
        raise ValueError(f'full car: unknown law {law!r}; laws: {FULL_CAR_LAWS}')
    front = plant.car.front
    c_crit = 2.0 * math.sqrt(front.k_s * front.m_s)
    i_range = plant.parts[1].i_range
    names, bounds, logs = [], [], []
    for g in tune.SPACES[law]:
        lo, hi = g.lo, (i_range if g.hi is None else g.hi)
        if g.crit:
            lo, hi = lo * c_crit, hi * c_crit
        names.append(g.name)
        bounds.append((lo, hi))
        logs.append(g.log)
    return Space(law, tuple(names), tuple(bounds), tuple(logs))


def law_config(plant, law, values=None):
    """Full-car config of ``law`` with gain ``values`` (None: the law's defaults)."""
    if law == 'modal_skyhook':
        modal = ModalParams() if values is None else ModalParams(
            **dict(zip(MODAL_GAINS, values)))
        return plant.config(ControllerParams(law='skyhook'), modal=modal)
    if law == 'modal_clipped_optimal':
        w = list(ModalParams().lqr_weights)
        if values is not None:
            w[1], w[2] = values
        return plant.config(ControllerParams(law='skyhook'),
                            modal=ModalParams(law=law, lqr_weights=tuple(w)))
    base = ControllerParams(law=law)
    if values is None:
        return plant.config(base)
    sp = space(law, plant)
    changes = {}
    weights = list(base.lqr_weights)
    for name, value in zip(sp.names, values):
        if name.startswith('lqr_weights['):
            weights[int(name[len('lqr_weights['):-1])] = value
            changes['lqr_weights'] = tuple(weights)
        else:
            changes[name] = value
    if 'i_max' in changes:
        changes['i_min'] = min(base.i_min, changes['i_max'])
    return plant.config(replace(base, **changes))


def default_values(law, plant):
    """Gain values of the law's defaults, clipped into its space."""
    sp = space(law, plant)
    cfg_ = law_config(plant, law)
    out = []
    for name, (lo, hi) in zip(sp.names, sp.bounds):
        if law == 'modal_skyhook':
            v = getattr(cfg_.modal, name)
        elif name.startswith('lqr_weights['):
            src = cfg_.modal if law == 'modal_clipped_optimal' else cfg_.controller
            v = src.lqr_weights[int(name[len('lqr_weights['):-1])]
        else:
            v = getattr(cfg_.controller, name)
        out.append(min(max(float(v), lo), hi))
    return tuple(out)


@dataclass(frozen=True)
class TunedLaw:
    """A law's tuned gains and figures (per road) and the passive setting it is compared with.

    ``equal_space``: the best constant current whose working space is no larger on any road
    (``current`` None when none is), with the comfort and tyre-load changes [%] against it.
    """

    law: str
    gains: dict
    figures: dict
    objective: float
    violation: float
    equal_space: dict = field(default_factory=dict)


@dataclass(frozen=True)
class FullCarStudy:
    """Passive family, tuned laws, objective and plant of a full-car study."""

    plant: FullCarPlant
    passive: dict
    tuned: tuple
    objective: object


def tune_law(law, plant, objective, maxiter=10, seed=1):
    """Tune ``law``'s gains by differential evolution on ``objective`` (as the quarter car).

    One batch simulation per generation (``vectorized``), the defaults in the first
    population, a fixed seed: reproducible and never worse than the defaults on ``J``.
    """
    sp = space(law, plant)
    lo = np.array([math.log10(b[0]) if lg else b[0] for b, lg in zip(sp.bounds, sp.log)])
    hi = np.array([math.log10(b[1]) if lg else b[1] for b, lg in zip(sp.bounds, sp.log)])
    x0 = sp.to_search(default_values(law, plant))

    def cost(u):
        u = np.atleast_2d(np.asarray(u).T)
        met = evaluate([law_config(plant, law, sp.from_search(row)) for row in u], plant)
        return objective.penalised(met)

    res = optimize.differential_evolution(cost, list(zip(lo, hi)), maxiter=maxiter, popsize=6,
                                          seed=seed, polish=False, updating='deferred',
                                          vectorized=True, x0=x0, tol=0.0)
    values = sp.from_search(res.x)
    met = evaluate([law_config(plant, law, values)], plant)
    return TunedLaw(law, dict(zip(sp.names, values)),
                    {k: v[0].tolist() for k, v in met.items()},
                    float(objective.value(met)[0]), float(objective.violation(met)[0]))


def equal_space(point, passive, objective):
    """Best passive current using no more working space on any road (module doc)."""
    ws = np.asarray(passive['working_space_rms'])
    fits = np.all(ws <= np.asarray(point['working_space_rms'])[None, :] * (1 + 1e-12), axis=1)
    if not fits.any():
        return {'current': None}
    comfort = objective.comfort(passive)
    k = int(np.flatnonzero(fits)[np.argmin(comfort[fits])])
    mine = objective.comfort({'body_acc_wk_rms': np.asarray(point['body_acc_wk_rms'])})
    tyre_p = objective.road_holding(passive)[k]
    tyre = objective.road_holding({'tyre_load_rms': np.asarray(point['tyre_load_rms'])})
    return {'current': float(passive['current'][k]),
            'comfort_change_pct': float(100.0 * (mine / comfort[k] - 1.0)),
            'tyre_change_pct': float(100.0 * (tyre / tyre_p - 1.0))}


def study(laws=('modal_skyhook', 'skyhook'), plant=None, ws_ratio=0.9, n_passive=21,
          maxiter=10, seed=1):
    """Passive sweep, then each law tuned for seat comfort within the working-space limit."""
    plant = plant or FullCarPlant()
    passive = passive_sweep(plant, n_passive)
    soft = {k: np.asarray(passive[k])[0] for k in KEYS}
    objective = tune.Objective(soft, comfort_weight=1.0, ws_ratio=ws_ratio)
    tune.check_feasible(objective, passive, list(plant.roads))
    tuned = []
    for law in laws:
        t = tune_law(law, plant, objective, maxiter=maxiter, seed=seed)
        tuned.append(replace(t, equal_space=equal_space(t.figures, passive, objective)))
    return FullCarStudy(plant, passive, tuple(tuned), objective)
