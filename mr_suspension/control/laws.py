"""Semi-active control laws as jitted step functions with one signature.

``controller_step(cid, p, s, m, dt) -> i_cmd`` with the law id ``cid``, its float64 parameter
array ``p`` (:meth:`ControllerParams.to_array`), its state ``s`` (length ``N_CTRL_STATE``, zeros
at start, updated in place) and the measurement vector ``m`` (length ``N_MEAS``)::

    m[M_ACC_S]        body acceleration [m/s^2], gravity removed (z_s'' about equilibrium)
    m[M_ACC_U]        wheel acceleration [m/s^2], gravity removed (NaN if no sensor)
    m[M_STROKE]       stroke x = z_s - z_u [m] (+ = extension), about the static position
    m[M_STROKE_RATE]  stroke rate [m/s]          (NaN if not measured)
    m[M_VEL_S]        body velocity [m/s]        (NaN if not measured)
    m[M_VEL_U]        wheel velocity [m/s]       (NaN if not measured)
    m[M_FIELD]        field current estimate [A] (NaN if unknown; the last command is used)

State ``s`` (``N_CTRL_STATE`` floats): ``[0, 4)`` estimator (body velocity, stroke rate, last
stroke, initialised flag), ``[4, 8)`` FEBC, ``8`` last command, ``[16, 32)`` scratch of the
inverse model, ``[32, 48)`` the controller's copy of the damper-model state. Parameters ``p``:
``P_*`` below, then the damper-model parameters from ``P_DP`` on (the array length depends on
the damper law; the simulator pads it).

The result is the coil-current command [A], clamped to ``[i_min, i_max]`` by
:func:`clamp_current` (NaN gives ``i_min``). With ``estimation='sensors'`` (default) the laws
use only accelerations and stroke, and estimate the velocities inside ``s``
(:mod:`~mr_suspension.control.estimation`); with ``estimation='ideal'`` the velocity slots are
used where finite (studies with perfect knowledge). Sign convention: the damper force ``F``
resists extension, the body feels ``-F``, the wheel ``+F``, power dissipated ``F v``.

Laws (``F_des`` is mapped to a current by the inverse damper model with the passivity
clip, :func:`~mr_suspension.control.inverse.semi_active_current`):

=================  ===========================================================================
``constant``       ``i = I`` (passive at any current; seed 001 constant-current families)
``skyhook_onoff``  ``i = i_max if v_s v > 0 else i_min`` (Karnopp, Crosby & Harwood 1974)
``skyhook``        ``F_des = c_sky v_s`` (continuous skyhook, Karnopp et al. 1974)
``groundhook``     ``F_des = -c_gnd v_u`` (Valasek et al. 1997)
``hybrid``         ``F_des = alpha F_sky + (1 - alpha) F_gnd``, each clipped to ``F v > 0``
                   (Ahmadian, Song & Goncalves 2004)
``add``            ``i = i_max if a_s v > 0 else i_min`` (acceleration-driven damper,
                   Savaresi, Silani & Bittanti 2005)
``sh_add``         ``i_max`` if ``[v_s^2 - a^2 a_s^2 <= 0 and a_s v > 0]`` or
                   ``[v_s^2 - a^2 a_s^2 > 0 and v_s v > 0]``, else ``i_min``,
                   ``a = 1 / (2 pi f_cross)`` (Savaresi & Spelta 2007)
``pdd``            ``F_des = -k_s x`` i.e. ``c = -k_s x / v`` clipped to ``[c_min, c_max]``
                   (power-driven damper, Morselli & Zanasi 2008)
``clipped_optimal`` ``F_des = -K [x, v_s, z_u - z_r, v_u]`` with the LQ gain ``K`` of the
                   linear quarter car (Dyke, Spencer, Sain & Carlson 1996, with the inverse
                   model in place of their bang-bang force tracking)
``febc``           frequency-estimation-based current schedule (seed 002; see
                   :mod:`~mr_suspension.control.febc`)
=================  ===========================================================================
"""

from dataclasses import asdict, dataclass, field, fields, replace
import math

from numba import njit
import numpy as np

from mr_suspension.control import estimation as est
from mr_suspension.control.febc import febc_step
from mr_suspension.control.inverse import semi_active_current
from mr_suspension.core import damper as dmp
from mr_suspension.core.paramsets import load_damper
from mr_suspension.core.quarter_car import QuarterCarParams
from mr_suspension.core.validation import check_finite, check_nonneg, check_positive, check_range

# Measurement vector layout.
M_ACC_S, M_ACC_U, M_STROKE, M_STROKE_RATE, M_VEL_S, M_VEL_U, M_FIELD = range(7)
N_MEAS = 7

# Controller state layout: estimator [0, 4), FEBC [4, 8), bookkeeping [8, 12),
# inverse scratch [16, 32), damper-model state [32, 48).
S_EST = 0
S_FEBC = 4
S_ILAST = 8
S_RNG, S_GAUSS = 12, 13
S_TMP = 16
S_DMP = 32
N_DMP_STATE = 16
N_CTRL_STATE = S_DMP + N_DMP_STATE

(CTRL_CONSTANT, CTRL_SKYHOOK_ONOFF, CTRL_SKYHOOK, CTRL_GROUNDHOOK, CTRL_HYBRID, CTRL_ADD,
 CTRL_SH_ADD, CTRL_PDD, CTRL_CLIPPED_OPTIMAL, CTRL_FEBC) = range(10)
LAW_IDS = {'constant': CTRL_CONSTANT, 'skyhook_onoff': CTRL_SKYHOOK_ONOFF,
           'skyhook': CTRL_SKYHOOK, 'groundhook': CTRL_GROUNDHOOK, 'hybrid': CTRL_HYBRID,
           'add': CTRL_ADD, 'sh_add': CTRL_SH_ADD, 'pdd': CTRL_PDD,
           'clipped_optimal': CTRL_CLIPPED_OPTIMAL, 'febc': CTRL_FEBC}
INVERSE_LAWS = ('skyhook', 'groundhook', 'hybrid', 'pdd', 'clipped_optimal')
ESTIMATION = {'sensors': 0.0, 'ideal': 1.0}

# Parameter array layout: [i_min, i_max, law-specific..., damper model].
(P_IMIN, P_IMAX, P_CURRENT, P_CSKY, P_CGND, P_ALPHA, P_FCROSS, P_KS, P_K0, P_K1, P_K2, P_K3,
 P_EST, P_FHP, P_FCR, P_FLP, P_MS, P_MU, P_KT, P_F1, P_F2, P_IROAD, P_FTAU, P_XBAND,
 P_IBODY, P_VEPS, P_AEPS, P_NACC, P_NSTROKE, P_NSEED, P_FSTAT, P_DLAW, P_DN,
 P_DP) = range(34)
N_CTRL_FIXED = P_DP


def uses_field(cid, p):
    """Whether law ``cid`` with parameter array ``p`` reads the field-current slot ``M_FIELD``.

    The slot only advances the state of the controller's copy of the damper model
    (:func:`_model_update`), and only the laws that invert that model (``INVERSE_LAWS``) read the
    state, and only for models with state (max-velocity tanh, mechanical, Bouc-Wen, extended).
    Otherwise the command is the same whatever the slot holds, so the controller needs no
    coil-current measurement.
    """
    stateful = (dmp.LAW_TANH_MAXVEL, dmp.LAW_MECHANICAL, dmp.LAW_BOUC_WEN, dmp.LAW_EXTENDED)
    return cid in tuple(LAW_IDS[name] for name in INVERSE_LAWS) and int(p[P_DLAW]) in stateful


# Default inverse model: RD-1005-3 class smooth Bingham (config/dampers/rd1005_bingham.yaml).
DEFAULT_DAMPER_MODEL = {'law': 'bingham', 'f0': 0.0, 'c0': 400.0, 'c1': 1200.0, 'fc0': 20.0,
                        'fc1': 400.0, 'v_y': 0.02}


def _damper_from(model):
    if model is None:
        return dmp.damper_from_dict(DEFAULT_DAMPER_MODEL)
    if isinstance(model, str):
        return load_damper(model)
    if isinstance(model, dict):
        return dmp.damper_from_dict(model)
    dmp.law_id_of(model)
    return model


def _damper_dict(params):
    data = dict(params.to_dict())
    data['law'] = params.law
    return {k: (v if isinstance(v, str) else float(v)) for k, v in data.items()}


@dataclass(frozen=True)
class ControllerParams:
    """Control law name, current range [A], gains, estimator settings and plant knowledge.

    Gains: ``current`` [A] (constant law), ``c_sky``, ``c_ground`` [N s/m], ``alpha`` [-]
    (hybrid weight of skyhook), ``f_cross`` [Hz] (SH-ADD switch), ``lqr_gains`` (clipped
    optimal, ``F_des = -K [x, v_s, z_u - z_r, v_u]``; empty = computed from ``lqr_weights`` =
    (body acceleration, stroke, tyre deflection, force) for the plant below), FEBC bands
    ``febc_f1 < febc_f2`` [Hz], body-band and wheel-hop currents ``febc_i_body``,
    ``febc_i_road`` [A], smoothing ``febc_tau`` [s], crossing hysteresis ``febc_x_band`` [m].
    Estimation: ``'sensors'`` or
    ``'ideal'``, body-velocity leak ``f_hp``, stroke-rate crossover ``f_cr`` and derivative
    cutoff ``f_lp`` [Hz]; ``v_eps`` [m/s] and ``a_eps`` [m/s^2] are the resolutions below
    which a velocity or acceleration counts as zero (at rest, sensor and round-off noise must
    not toggle the on-off laws). ``noise_acc`` [m/s^2 RMS] and ``noise_stroke`` [m RMS] add
    reproducible white sensor noise (seed ``noise_seed``) for studies; 0 in normal use.
    Plant knowledge (PDD, clipped optimal, tyre-deflection estimate):
    ``m_s, m_u`` [kg], ``k_s, k_t, c_t``; ``damper_model``: the inverse model (damper YAML
    mapping with ``law``, a ``config/dampers`` name, or ``None`` for an RD-1005 class Bingham
    law). :meth:`with_plant` copies all of these from the simulated corner.
    """

    law: str = 'constant'
    i_min: float = 0.0
    i_max: float = 2.0
    current: float = 0.0
    c_sky: float = 2500.0
    c_ground: float = 1500.0
    alpha: float = 0.5
    f_cross: float = 2.0
    lqr_gains: tuple = ()
    lqr_weights: tuple = (1.0, 1.0e3, 1.0e3, 1.0e-6)
    febc_f1: float = 2.0
    febc_f2: float = 6.0
    febc_i_body: float = 0.5
    febc_i_road: float = 1.0
    febc_tau: float = 0.3
    febc_x_band: float = 5e-4
    estimation: str = 'sensors'
    f_hp: float = 0.1
    f_cr: float = 2.0
    f_lp: float = 40.0
    v_eps: float = 1e-4
    a_eps: float = 1e-3
    noise_acc: float = 0.0
    noise_stroke: float = 0.0
    noise_seed: int = 1
    m_s: float = 110.0
    m_u: float = 18.0
    k_s: float = 11000.0
    k_t: float = 110000.0
    c_t: float = 50.0
    damper_model: object = field(default=None)

    def __post_init__(self):
        owner = 'ControllerParams'
        if self.law not in LAW_IDS:
            raise ValueError(f'{owner}: unknown law {self.law!r}; known {sorted(LAW_IDS)}')
        if self.estimation not in ESTIMATION:
            raise ValueError(f'{owner}: estimation must be one of {sorted(ESTIMATION)}, '
                             f'got {self.estimation!r}')
        check_nonneg(owner, i_min=self.i_min, current=self.current, c_sky=self.c_sky,
                     c_ground=self.c_ground, febc_i_road=self.febc_i_road,
                     febc_i_body=self.febc_i_body, v_eps=self.v_eps, a_eps=self.a_eps,
                     noise_acc=self.noise_acc, noise_stroke=self.noise_stroke,
                     febc_x_band=self.febc_x_band, c_t=self.c_t)
        check_positive(owner, i_max=self.i_max, f_cross=self.f_cross, febc_f1=self.febc_f1,
                       febc_f2=self.febc_f2, febc_tau=self.febc_tau, f_hp=self.f_hp,
                       f_cr=self.f_cr, f_lp=self.f_lp, m_s=self.m_s, m_u=self.m_u,
                       k_s=self.k_s, k_t=self.k_t)
        if self.i_min > self.i_max:
            raise ValueError(f'{owner}: i_min must be <= i_max')
        # Plausible ranges: plant knowledge as the vehicle's (core.quarter_car), gains generous.
        for name in ('m_s', 'm_u', 'k_s', 'k_t', 'c_t'):
            lo, hi, unit, hint, _ = QuarterCarParams.__dataclass_fields__[name].metadata['range']
            check_range(owner, name, getattr(self, name), lo, hi, unit, hint)
        check_range(owner, 'i_max', self.i_max, 1.0e-3, 50.0, 'A', 'largest current')
        for name in ('c_sky', 'c_ground'):
            check_range(owner, name, getattr(self, name), 0.0, 1.0e6, 'N s/m', 'damping gain')
        seed = self.noise_seed
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f'{owner}: noise_seed must be an integer >= 0, got {seed!r}')
        if not 0.0 <= self.alpha <= 1.0:
            raise ValueError(f'{owner}: alpha must be in [0, 1], got {self.alpha!r}')
        if self.febc_f1 >= self.febc_f2:
            raise ValueError(f'{owner}: febc_f1 must be < febc_f2')
        gains = tuple(float(g) for g in self.lqr_gains)
        if len(gains) not in (0, 4):
            raise ValueError(f'{owner}: lqr_gains needs 4 values [x, v_s, z_u - z_r, v_u]')
        check_finite(owner, **{f'lqr_gains[{k}]': g for k, g in enumerate(gains)})
        weights = tuple(float(w) for w in self.lqr_weights)
        if len(weights) != 4:
            raise ValueError(f'{owner}: lqr_weights needs 4 values (acc, stroke, tyre, force)')
        check_nonneg(owner, **{f'lqr_weights[{k}]': w for k, w in enumerate(weights)})
        if weights[3] <= 0.0:
            raise ValueError(f'{owner}: the force weight lqr_weights[3] must be > 0')
        object.__setattr__(self, 'lqr_gains', gains)
        object.__setattr__(self, 'lqr_weights', weights)
        model = _damper_from(self.damper_model)
        if self.damper_model is not None and not isinstance(self.damper_model, str):
            object.__setattr__(self, 'damper_model', _damper_dict(model))
        object.__setattr__(self, '_model', model)

    @property
    def law_id(self):
        """Integer id for the jitted dispatcher."""
        return LAW_IDS[self.law]

    @property
    def inverse_model(self):
        """Damper parameter object used by the inverse model."""
        return self._model

    def gains(self):
        """LQ gain ``K`` of the clipped-optimal law (given, or from ``lqr_weights``)."""
        if self.lqr_gains:
            return np.array(self.lqr_gains)
        from mr_suspension.control.optimal import lqr_gain
        return lqr_gain(self.m_s, self.m_u, self.k_s, self.k_t, self.c_t, *self.lqr_weights)

    def to_array(self):
        """Return the jitted law's parameter array ``p`` (layout ``P_*``).

        Computed once per (frozen) instance: the clipped-optimal gain needs a Riccati solve,
        about 10 ms, which a batch of thousands of corners sharing a controller must not
        repeat. A copy is returned.
        """
        cached = self.__dict__.get('_array')
        if cached is None:
            cached = self._build_array()
            object.__setattr__(self, '_array', cached)
        return cached.copy()

    def _build_array(self):
        from mr_suspension.control.inverse import static_force
        model = self._model
        dp = model.to_array()
        law = dmp.law_id_of(model)
        if law != dmp.LAW_TANH_MAXVEL and dmp.n_state_of(model) > N_DMP_STATE:
            raise ValueError(f'ControllerParams: the inverse keeps at most {N_DMP_STATE} '
                             f'damper-model states, {model.law} needs {dmp.n_state_of(model)}')
        k = self.gains() if self.law == 'clipped_optimal' else np.zeros(4)
        head = [self.i_min, self.i_max, self.current, self.c_sky, self.c_ground, self.alpha,
                self.f_cross, self.k_s, k[0], k[1], k[2], k[3], ESTIMATION[self.estimation],
                self.f_hp, self.f_cr, self.f_lp, self.m_s, self.m_u, self.k_t, self.febc_f1,
                self.febc_f2, self.febc_i_road, self.febc_tau, self.febc_x_band,
                self.febc_i_body, self.v_eps, self.a_eps, self.noise_acc,
                self.noise_stroke, float(int(self.noise_seed) % 2 ** 32),
                static_force(model),
                float(dmp.law_id_of(model)), float(dp.size)]
        return np.concatenate([np.array(head, dtype=np.float64), dp])

    def to_dict(self):
        """Return a plain dict (YAML/JSON friendly; tuples as lists)."""
        data = asdict(self)
        data['lqr_gains'] = list(self.lqr_gains)
        data['lqr_weights'] = list(self.lqr_weights)
        return data

    @classmethod
    def from_dict(cls, data):
        """Build from a mapping; unknown keys raise ValueError."""
        data = dict(data)
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f'ControllerParams: unknown parameter(s) {unknown}; '
                             f'known: {sorted(known)}')
        for key in ('lqr_gains', 'lqr_weights'):
            if key in data and data[key] is not None:
                data[key] = tuple(data[key])
        return cls(**data)

    def replace(self, **changes):
        """Return a copy with fields replaced."""
        return replace(self, **changes)

    def with_plant(self, car=None, damper=None, driver=None):
        """Copy with the plant knowledge of a corner (vehicle, damper model, driver range).

        ``car``: :class:`~mr_suspension.core.quarter_car.QuarterCarParams` (masses,
        stiffnesses, tyre damping); ``damper``: damper parameters for the inverse model;
        ``driver``: :class:`~mr_suspension.core.driver.DriverParams` (``i_max`` is limited to
        what it can deliver).
        """
        changes = {}
        if car is not None:
            changes.update(m_s=car.m_s, m_u=car.m_u, k_s=car.k_s, k_t=car.k_t, c_t=car.c_t)
        if damper is not None:
            changes['damper_model'] = _damper_dict(_damper_from(damper))
        if driver is not None:
            i_max = min(self.i_max, driver.i_range)
            changes['i_max'] = i_max
            changes['i_min'] = min(self.i_min, i_max)
            changes['current'] = min(self.current, i_max)
            changes['febc_i_road'] = min(self.febc_i_road, i_max)
            changes['febc_i_body'] = min(self.febc_i_body, i_max)
        return replace(self, **changes)


GAIN_DESCRIPTIONS = {
    'law': 'control law: ' + ', '.join(sorted(LAW_IDS)),
    'i_min': 'lowest current command [A]',
    'i_max': 'highest current command [A] (also limited by the driver range)',
    'current': 'constant law: current [A]',
    'c_sky': 'skyhook / hybrid: skyhook damping [N s/m]',
    'c_ground': 'groundhook / hybrid: groundhook damping [N s/m]',
    'alpha': 'hybrid: skyhook share in [0, 1]',
    'f_cross': 'SH-ADD: skyhook/ADD switching frequency [Hz]',
    'lqr_gains': 'clipped optimal: K on [x, v_s, z_u - z_r, v_u] (empty = from lqr_weights)',
    'lqr_weights': 'clipped optimal: LQ weights (body acc, stroke, tyre deflection, force)',
    'febc_f1': 'FEBC: upper edge of the body band [Hz]',
    'febc_f2': 'FEBC: lower edge of the wheel-hop band [Hz]',
    'febc_i_body': 'FEBC: current in the body band [A]',
    'febc_i_road': 'FEBC: current in the wheel-hop band [A]',
    'febc_tau': 'FEBC: frequency smoothing time constant [s]',
    'febc_x_band': 'FEBC: zero-crossing hysteresis [m]',
    'estimation': "velocity source: 'sensors' (estimated) or 'ideal' (measurement slots)",
    'f_hp': 'estimator: body-velocity leak corner [Hz]',
    'f_cr': 'estimator: stroke-rate complementary crossover [Hz]',
    'f_lp': 'estimator: stroke-rate derivative cutoff without wheel accelerometer [Hz]',
    'v_eps': 'velocity resolution [m/s]: smaller velocities count as zero (no switching on '
             'noise)',
    'a_eps': 'acceleration resolution [m/s^2]: smaller accelerations count as zero',
    'noise_acc': 'studies: white noise added to both accelerometers [m/s^2 RMS] (0 = off)',
    'noise_stroke': 'studies: white noise added to the stroke sensor [m RMS] (0 = off)',
    'noise_seed': 'studies: seed of the reproducible sensor noise',
    'm_s': 'plant knowledge: body mass [kg]',
    'm_u': 'plant knowledge: wheel mass [kg]',
    'k_s': 'plant knowledge: spring stiffness [N/m] (PDD, clipped optimal)',
    'k_t': 'plant knowledge: tyre stiffness [N/m]',
    'c_t': 'plant knowledge: tyre damping [N s/m]',
    'damper_model': 'inverse damper model: config/dampers name or mapping (None = RD-1005)',
}


@njit(cache=True)
def clamp_current(p, i):
    """Clamp a command to ``[i_min, i_max]``; NaN gives ``i_min`` (the safe soft setting)."""
    if not i == i:
        return p[P_IMIN]
    if i < p[P_IMIN]:
        return p[P_IMIN]
    if i > p[P_IMAX]:
        return p[P_IMAX]
    return i


@njit(cache=True)
def _model_update(p, s, x, v, i, dt):
    """Advance the controller's copy of the damper-model state with the applied current."""
    law = int(p[P_DLAW])
    if law == dmp.LAW_TANH_MAXVEL:
        # Window peak |v| as a max-hold with exponential release over the window length.
        av = abs(v)
        rel = math.exp(-dt / p[P_DP + 4])
        peak = s[S_DMP] * rel
        s[S_DMP] = av if av > peak else peak
    elif law == dmp.LAW_MECHANICAL or law == dmp.LAW_BOUC_WEN or law == dmp.LAW_EXTENDED:
        n = int(p[P_DN])
        dmp.damper_force(law, p[P_DP:P_DP + n], s[S_DMP:S_DMP + N_DMP_STATE], x, v, i, dt)


@njit(cache=True)
def _inverse(p, s, x, v, f_des, dt):
    n = int(p[P_DN])
    return semi_active_current(int(p[P_DLAW]), p[P_DP:P_DP + n], s[S_DMP:S_DMP + N_DMP_STATE],
                               s[S_TMP:S_DMP], x, v, f_des, p[P_FSTAT], p[P_IMIN], p[P_IMAX],
                               dt)


@njit(cache=True)
def inverse_command(p, s, x, v, f_des, dt):
    """Return the passivity-clipped inverse model's current for ``f_des`` (as the laws do)."""
    return _inverse(p, s, x, v, f_des, dt)


@njit(cache=True)
def _uniform(s):
    """Next uniform in (0, 1) of the LCG ``r = (1664525 r + 1013904223) mod 2^32`` in ``s``."""
    r = (1664525 * int(s[S_RNG]) + 1013904223) % 4294967296
    s[S_RNG] = float(r)
    return (r + 0.5) / 4294967296.0


@njit(cache=True)
def sensor_noise(p, s):
    """Return a standard normal sample (Box-Muller on :func:`_uniform`), seeded by ``p``."""
    if s[S_RNG] == 0.0 and s[S_GAUSS] == 0.0:
        s[S_RNG] = p[P_NSEED] + 1.0
    u1 = _uniform(s)
    u2 = _uniform(s)
    s[S_GAUSS] += 1.0
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


@njit(cache=True)
def _measure(p, s, m, dt):
    """Sensor noise, velocity estimates and resolution of one sample of measurements ``m``.

    Returns ``(x, a_s, a_u, v_s, v, v_u, i_field)`` as every law reads them.
    """
    x = m[M_STROKE]
    a_s = m[M_ACC_S]
    a_u = m[M_ACC_U]
    if p[P_NACC] > 0.0:
        a_s += p[P_NACC] * sensor_noise(p, s)
        a_u += p[P_NACC] * sensor_noise(p, s)
    if p[P_NSTROKE] > 0.0:
        x += p[P_NSTROKE] * sensor_noise(p, s)
    vs_hat, v_hat = est.estimate_step(s[S_EST:S_EST + 4], a_s, a_u, x, dt, p[P_FHP],
                                      p[P_FCR], p[P_FLP])
    v_s = vs_hat
    v = v_hat
    if p[P_EST] == 1.0:
        if m[M_VEL_S] == m[M_VEL_S]:
            v_s = m[M_VEL_S]
        if m[M_STROKE_RATE] == m[M_STROKE_RATE]:
            v = m[M_STROKE_RATE]
        elif m[M_VEL_U] == m[M_VEL_U] and m[M_VEL_S] == m[M_VEL_S]:
            v = m[M_VEL_S] - m[M_VEL_U]
    v_u = v_s - v
    if p[P_EST] == 1.0 and m[M_VEL_U] == m[M_VEL_U]:
        v_u = m[M_VEL_U]
    if not x == x:
        x = 0.0
    if not a_s == a_s:
        a_s = 0.0
    # Resolution: values below it count as zero, so noise at rest cannot switch the laws.
    if abs(v_s) < p[P_VEPS]:
        v_s = 0.0
    if abs(v) < p[P_VEPS]:
        v = 0.0
    if abs(v_u) < p[P_VEPS]:
        v_u = 0.0
    if abs(a_s) < p[P_AEPS]:
        a_s = 0.0
    # Keep the inverse model's state in step with the damper (field estimate or last command).
    i_field = m[M_FIELD] if m[M_FIELD] == m[M_FIELD] else s[S_ILAST]
    return x, a_s, a_u, v_s, v, v_u, i_field


@njit(cache=True)
def _finish(p, s, x, v, i_field, i, dt):
    """Clamp the command, advance the controller's damper-model copy, remember the command."""
    i = clamp_current(p, i)
    _model_update(p, s, x, v, i_field, dt)
    s[S_ILAST] = i
    return i


@njit(cache=True)
def measure(p, s, m, dt):
    """Advance the corner's estimation with measurements ``m``; return what the laws read.

    ``(x, a_s, a_u, v_s, v, v_u, i_field)``; with :func:`force_command` the two halves of a
    step of a force law whose ``f_des`` is computed outside the corner.
    """
    return _measure(p, s, m, dt)


@njit(cache=True)
def force_command(p, s, x, v, i_field, f_des, dt):
    """Return the current command for a desired damper force ``f_des`` [N].

    The corner's inverse model with the passivity clip and clamp, as the force laws of
    :func:`controller_step`; ``x, v, i_field`` from :func:`measure` of the same sample.
    """
    return _finish(p, s, x, v, i_field, _inverse(p, s, x, v, f_des, dt), dt)


@njit(cache=True)
def force_step(p, s, m, f_des, dt):
    """Return the current command for ``f_des`` [N] (:func:`measure`, :func:`force_command`)."""
    x, a_s, a_u, v_s, v, v_u, i_field = _measure(p, s, m, dt)
    return force_command(p, s, x, v, i_field, f_des, dt)


@njit(cache=True)
def controller_step(cid, p, s, m, dt):
    """Return the current command of law ``cid`` for measurements ``m`` (module doc)."""
    x, a_s, a_u, v_s, v, v_u, i_field = _measure(p, s, m, dt)
    i = p[P_IMIN]
    if cid == CTRL_CONSTANT:
        i = p[P_CURRENT]
    elif cid == CTRL_SKYHOOK_ONOFF:
        i = p[P_IMAX] if v_s * v > 0.0 else p[P_IMIN]
    elif cid == CTRL_SKYHOOK:
        i = _inverse(p, s, x, v, p[P_CSKY] * v_s, dt)
    elif cid == CTRL_GROUNDHOOK:
        i = _inverse(p, s, x, v, -p[P_CGND] * v_u, dt)
    elif cid == CTRL_HYBRID:
        f_sky = p[P_CSKY] * v_s
        if f_sky * v <= 0.0:
            f_sky = 0.0
        f_gnd = -p[P_CGND] * v_u
        if f_gnd * v <= 0.0:
            f_gnd = 0.0
        i = _inverse(p, s, x, v, p[P_ALPHA] * f_sky + (1.0 - p[P_ALPHA]) * f_gnd, dt)
    elif cid == CTRL_ADD:
        i = p[P_IMAX] if a_s * v > 0.0 else p[P_IMIN]
    elif cid == CTRL_SH_ADD:
        a = 1.0 / (2.0 * math.pi * p[P_FCROSS])
        if v_s * v_s - a * a * a_s * a_s <= 0.0:
            on = a_s * v > 0.0
        else:
            on = v_s * v > 0.0
        i = p[P_IMAX] if on else p[P_IMIN]
    elif cid == CTRL_PDD:
        i = _inverse(p, s, x, v, -p[P_KS] * x, dt)
    elif cid == CTRL_CLIPPED_OPTIMAL:
        if not a_u == a_u:
            a_u = 0.0
        d_tyre = -(p[P_MS] * a_s + p[P_MU] * a_u) / p[P_KT]
        f_des = -(p[P_K0] * x + p[P_K1] * v_s + p[P_K2] * d_tyre + p[P_K3] * v_u)
        i = _inverse(p, s, x, v, f_des, dt)
    elif cid == CTRL_FEBC:
        i = febc_step(s[S_FEBC:S_FEBC + 4], x, dt, p[P_F1], p[P_F2], p[P_IBODY], p[P_IMIN],
                      p[P_IROAD], p[P_FTAU], p[P_XBAND])
    return _finish(p, s, x, v, i_field, i, dt)
