"""The effect catalogue: what the diagnosis may add to the nominal model, as data.

Each :class:`Effect` says where it lives (``sensor``, ``driver``, ``damper``, ``vehicle``, or
``current``: the current chain, the fluid's with a measured coil current and the lumped
driver-plus-fluid chain's with a command), its fitted parameters (with units and plausible
ranges from the parameter classes, :func:`parameters`), how it enters the model, which effect
it nests (is the general case of) and which it cannot be named beside. The rig problem
(force from motion and current, :mod:`~mr_suspension.identification.diagnose`) and the car
problem (body acceleration from a corner's sensors,
:mod:`~mr_suspension.identification.vehicle`) each have their list; the selection reads its
candidates, exclusions and nestings from here, the reports their texts and the separating
experiments.
"""

from dataclasses import dataclass, fields

from mr_suspension.core.driver import DriverParams
from mr_suspension.core.extended import ExtendedDamperParams
from mr_suspension.core.quarter_car import QuarterCarParams

LOCATIONS = ('sensor', 'driver', 'damper', 'vehicle', 'current')


@dataclass(frozen=True)
class Effect:
    """One candidate effect of a problem's catalogue.

    ``params``: the fitted (nonlinear) parameters; ``linear``: force terms solved by least
    squares with the baseline; ``stage``: ``model`` (selected on the modelled signal),
    ``coil`` (judged on the measured coil current) or ``road`` (the wheel equation);
    ``nests``: the effect this one generalises (named only when it pays on top of it);
    ``excludes``: effects it is never named beside; ``how``: the manoeuvre that makes it
    testable where the data cannot.
    """

    name: str
    location: str
    params: tuple
    enters: str
    linear: tuple = ()
    stage: str = 'model'
    nests: str = None
    excludes: tuple = ()
    how: str = ''

    def __post_init__(self):
        if self.location not in LOCATIONS:
            raise ValueError(f'{self.name}: location must be one of {LOCATIONS}')


# Units and ranges of parameters no parameter class holds: name -> (lo, hi, unit, meaning).
_OWN = {
    'delay': (-0.05, 0.05, 's', 'force channel shift against the motion channels'),
    'f_ch': (1.0, 1000.0, 'Hz', 'force channel anti-alias cut-off'),
    'tau_lag': (0.0, 1.0, 's', 'field current time constant'),
    'imu_timing': (-0.002, 0.002, 's', 'body IMU offset in time from stroke and current'),
}


def parameters(effect):
    """``(name, unit, lo, hi, meaning)`` of each parameter of ``effect`` (an :class:`Effect`).

    Ranges are the plausibility limits of the class that holds the parameter
    (``ExtendedDamperParams``, ``QuarterCarParams``, ``DriverParams``).
    """
    table = dict(_OWN)
    for cls in (DriverParams, QuarterCarParams, ExtendedDamperParams):
        table.update({f.name: f.metadata['range'][:4] for f in fields(cls)})
    return tuple((p,) + (table[p][2], table[p][0], table[p][1], table[p][3])
                 for p in effect.params + effect.linear)


RIG = (
    Effect('channel_delay', 'sensor', ('delay',),
           'force channel shifted in time against the motion channels (filter, skew)'),
    Effect('channel_filter', 'sensor', ('f_ch',),
           'force channel low-passed (2nd-order Butterworth anti-alias filter, cut-off '
           'f_ch)'),
    Effect('driver_delay', 'driver', ('dead_time',),
           'driver dead time (command -> measured coil current) differs from nominal',
           stage='coil'),
    Effect('driver_lag', 'driver', ('tau_rise', 'tau_fall'),
           'driver rise/fall time constants differ from nominal',
           stage='coil'),
    Effect('current_delay', 'current', ('dead_time',),
           'dead time between the current command and the field'),
    Effect('current_lag', 'current', ('tau_lag',),
           'first-order lag of the field current (one time constant)'),
    Effect('current_lag_asymmetric', 'current', ('tau_rise', 'tau_fall'),
           'first-order lag with different rise and fall time constants (driver plus fluid'
           ' demagnetisation, seed 000)', nests='current_lag', excludes=('current_lag',)),
    Effect('current_saturation', 'damper', ('i_sat', 'sat_n'),
           'yield force saturating with current, Fy = fy0 + fy1 i_s tanh(i/i_s)'),
    Effect('hysteresis', 'damper', ('x_h', 'hyst_n', 'hyst_r'),
           'rate-independent pre-yield loop: a share w_h of the yield force follows a '
           'Bouc-Wen state (length x_h, exponent n_h, unloading shape r_h; Dahl: 1, 1, 0)',
           excludes=('yield_shape',)),
    Effect('series_stiffness', 'damper', ('k_series',),
           'compliance k1 in series with the damping element (seed 000)'),
    Effect('gas_spring', 'damper', (),
           'accumulator force kg1 x + kg2 x^2 (seed 000 k2)',
           linear=('k_gas1', 'k_gas2', 'k_gas3')),
    Effect('thermal_fade', 'damper', ('kappa', 'tau_thermal'),
           'force falling as (1 - kappa E) with stored heat E from dissipated energy'),
    Effect('direction_asymmetry', 'damper', ('rho',),
           'different force in rebound and compression: viscous force x (1 + rho '
           'tanh(v/v_y)), yield force x (1 + rho y)'),
    Effect('yield_shape', 'damper', ('yield_n',),
           'yield sigmoid w / (1 + |w|^n)^(1/n) instead of tanh(w), w = v / v_y',
           excludes=('hysteresis',)),
)

RIG_SEPARATING = {
    frozenset(('current_delay', 'current_lag')):
        'current steps at constant speed: a dead time shifts the force edge, a lag rounds it',
    frozenset(('current_delay', 'current_lag_asymmetric')):
        'current steps up and down at constant speed (rise and fall edges separately)',
    frozenset(('hysteresis', 'series_stiffness')):
        'harmonic tests at several frequencies at one amplitude: the series-compliance lag '
        'grows with frequency, a rate-independent hysteresis loop does not',
    frozenset(('gas_spring', 'series_stiffness')):
        'slow ramps and held displacement offsets: a gas spring holds force at zero velocity',
    frozenset(('hysteresis', 'yield_shape')):
        'harmonic tests at several amplitudes at one frequency: a pre-yield loop shows as a '
        'force lag at reversals, a yield shape is the same on loading and unloading',
    frozenset(('gas_spring', 'hysteresis')):
        'harmonic tests about several displacement offsets',
    frozenset(('current_saturation', 'direction_asymmetry')):
        'harmonic tests at more than three current levels up to the maximum current',
    frozenset(('thermal_fade', 'gas_spring')):
        'a long high-power run with a repeated identical test before and after',
}

_CURRENT_HOW = ('drive a rough road with the controller switching the current in steps '
                '(>= 4 steps each way), e.g. on-off skyhook')
_REVERSING = 'strokes reversing direction (any rough road)'
_LARGE = 'strokes of more than 1 cm (a bump or pothole)'

CAR = (
    Effect('imu_timing', 'sensor', ('imu_timing',),
           'the body IMU samples are offset in time from the stroke and current (a '
           'step-mean acceleration: half a sample; an anti-alias filter delay)',
           how='stroke content above 2 Hz'),
    Effect('strut_friction', 'vehicle', ('f_fric', 'v_fric'),
           'strut (seal, bushing) friction F = f_fric tanh(v / v_fric)', how=_REVERSING),
    Effect('bump_stop', 'vehicle', ('k_bs', 'x_bs'),
           'progressive stop k_bs (|x| - x_bs)^2 sign(x) beyond a clearance', how=_LARGE),
    Effect('spring_nonlinearity', 'vehicle', ('k_s3',),
           'progressive spring k_s x + k_s3 x^3', how=_LARGE),
    Effect('top_mount', 'vehicle', ('k_tm', 'c_tm'),
           'compliant top mount: the strut force reaches the body through a Kelvin-Voigt '
           'mount (k_tm, c_tm) from a strut-top mass of 1 % of m_s',
           how='stroke content above 5 Hz (a rough road)'),
    Effect('current_delay', 'current', ('dead_time',),
           'field current = command delayed by a different dead time', how=_CURRENT_HOW),
    Effect('current_lag', 'current', ('tau_rise', 'tau_fall'),
           'different (lumped) first-order current lag', how='as current_delay'),
    Effect('current_lag_asymmetric', 'current', ('tau_rise', 'tau_fall'),
           'lumped current lag with separate rise and fall time constants',
           nests='current_lag', excludes=('current_lag',), how='as current_delay'),
    Effect('current_saturation', 'damper', ('i_sat',),
           'the field saturates with current: c1 and fy1 see i_s tanh(i / i_s)',
           how='drive with at least three distinct current levels up to the max'),
    Effect('direction_asymmetry', 'damper', ('rho',),
           'damper force scaled by 1 + rho tanh(v / v_y) (rebound vs bump)', how=_REVERSING),
    Effect('sprung_mass', 'vehicle', ('m_s',),
           'sprung mass differs from the nominal (wheel equation, needs a road)', stage='road',
           how='a quarter-car rig run with the shaker displacement recorded (road column), '
               'or a known ballast change'),
)

CAR_SEPARATING = {
    frozenset(('strut_friction', 'direction_asymmetry')): 'slow strokes (< 0.05 m/s) both ways '
    'at two current levels: friction does not scale with current',
    frozenset(('strut_friction', 'top_mount')): 'a slow harmonic stroke (0.5 Hz) and a fast '
    'one (8 Hz) at one amplitude',
    frozenset(('bump_stop', 'spring_nonlinearity')): 'a slow quasi-static stroke over the '
    'whole travel (ramp unloading, or a rig run)',
    frozenset(('current_delay', 'current_lag')): 'current steps up and down while driving '
    'steadily on a rough road',
    frozenset(('strut_friction', 'fy0')): 'the damper alone on a rig at 0 A (its current-free '
    'yield force), or the strut without the damper: what the car adds to the rig figure is '
    'the strut friction',
    frozenset(('strut_friction', 'c0')): 'the damper alone on a rig at 0 A (its viscous '
    'coefficient)',
    frozenset(('spring_nonlinearity', 'k_s')): 'a slow quasi-static stroke over the whole '
    'travel (ramp unloading, or a rig run)',
}


def where(effect, coil):
    """Where ``effect`` lives in a report: its location, the current chain's resolved.

    The current chain is the fluid's (``damper``) when the measured coil current is the
    input (``coil``), else the lumped driver-plus-fluid chain (``driver``).
    """
    if effect.location == 'current':
        return 'damper' if coil else 'driver'
    return effect.location


def by_name(catalogue):
    """``{name: Effect}`` of a catalogue."""
    return {e.name: e for e in catalogue}


def names(catalogue, locations=LOCATIONS, stage='model'):
    """Names of the effects at ``locations`` judged in ``stage``, in catalogue order."""
    return tuple(e.name for e in catalogue if e.location in locations and e.stage == stage)


def nested(catalogue):
    """``{(simpler, general)}``: pairs where the general effect nests the simpler one."""
    return {(e.nests, e.name) for e in catalogue if e.nests}


def exclusive(catalogue):
    """Return the sets of effects never named together (an effect with those it excludes)."""
    out = []
    for e in catalogue:
        group = {e.name, *e.excludes}
        if len(group) > 1 and group not in out:
            out.append(group)
    return tuple(out)
