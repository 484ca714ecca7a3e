"""Current driver (LORD Wonder Box RD-3002-3) and MR-fluid magnetisation dynamics (seed 000 §5).

Chain (seed 000, Fig. 9 and §5.3): command current -> driver input voltage (the ECU inverts the
nominal static map) -> static voltage-to-current map -> first-order lag with separate rise and
fall time constants -> dead time -> coil current -> fluid magnetisation lag (fast on rising,
slow on falling current) -> field current that the force law sees.
"""

from dataclasses import dataclass, replace
import math

from numba import njit
import numpy as np

from mr_suspension.core.validation import check_declared, check_range, param, ParamsMixin

DEAD_TIME_BUFFER = 512
DEAD_TIME_MAX = 0.25  # [s]; a fitted or configured dead time beyond it is an input error
LAG_MAX = 1.0  # [s]; largest plausible driver or fluid time constant
# Driver state layout: [lag output, fluid output, ring head, ring buffer (DEAD_TIME_BUFFER)].
DRV_LAG, DRV_FLUID, DRV_HEAD, DRV_BUF = 0, 1, 2, 3
DRIVER_STATE_SIZE = DRV_BUF + DEAD_TIME_BUFFER


@dataclass(frozen=True)
class DriverParams(ParamsMixin):
    """Wonder Box and fluid parameters (SI). Seed 000 §5.2–5.3 and Tables 4–5.

    Static map: ``i = 0`` for ``V <= v_dead``, else ``i = i_max s / (1 + s^knee)^(1/knee)`` with
    ``s = gain (V - v_dead) / i_max``: nearly linear beyond the ~0.5 V dead zone, saturating near
    ``i_max`` (2 A max, Table 2). Lag ``tau_rise``/``tau_fall`` and ``dead_time`` are the Wonder
    Box; ``fluid_tau_rise``/``fluid_tau_fall`` the fluid (about 16 ms falling, hardly any rising;
    about 25 ms falling in total). A time constant of 0 means no lag.
    """

    v_dead: float = param(0.5, 0.0, 50.0, 'V', 'driver dead zone')
    gain: float = param(0.5, 1.0e-3, 100.0, 'A/V', 'driver gain')
    i_max: float = param(2.0, 1.0e-3, 50.0, 'A', 'saturation current')
    knee: float = param(6.0, 0.5, 100.0, '', 'saturation knee exponent')
    v_max: float = param(5.0, 0.01, 100.0, 'V', 'largest driver input voltage')
    tau_rise: float = param(0.007, 0.0, LAG_MAX, 's', 'driver rise time constant')
    tau_fall: float = param(0.004, 0.0, LAG_MAX, 's', 'driver fall time constant')
    dead_time: float = param(0.003, 0.0, DEAD_TIME_MAX, 's', 'driver dead time')
    fluid_tau_rise: float = param(0.0, 0.0, LAG_MAX, 's', 'fluid rise time constant')
    fluid_tau_fall: float = param(0.016, 0.0, LAG_MAX, 's', 'fluid fall time constant')

    def __post_init__(self):
        check_declared(self)
        if self.v_max <= self.v_dead:
            raise ValueError(f'DriverParams: v_max ({self.v_max:g} V) must exceed v_dead '
                             f'({self.v_dead:g} V); raise v_max or lower v_dead')

    @property
    def i_range(self):
        """Largest current the driver can deliver at ``v_max`` [A]."""
        return float(static_current(self.to_array(), self.v_max))


@njit(cache=True)
def static_current(p, volt):
    """Map voltage [V] to current [A]: the static Wonder Box block (seed 000, Fig. 9)."""
    if not volt > p[0]:
        return 0.0
    if volt > p[4]:
        volt = p[4]
    s = p[1] * (volt - p[0]) / p[2]
    return p[2] * s / (1.0 + s ** p[3]) ** (1.0 / p[3])


@njit(cache=True)
def command_voltage(p, i_cmd):
    """Inverse static map: the voltage the ECU applies for a current command (clamped)."""
    if not i_cmd > 0.0:
        return 0.0
    r = i_cmd / p[2]
    i_top = static_current(p, p[4]) / p[2]
    if r >= i_top:
        return p[4]
    s = r / (1.0 - r ** p[3]) ** (1.0 / p[3])
    return p[0] + s * p[2] / p[1]


# Prepared (dt-specific) driver array layout, see :func:`prepare`.
Q_ITOP, Q_ARISE, Q_AFALL, Q_NDEAD, Q_FRISE, Q_FFALL = range(6)
Q_STATIC = 6  # the static-map parameters follow (DriverParams.to_array()[:5])


def _alpha(tau, dt):
    return 1.0 if tau <= 0.0 else 1.0 - math.exp(-dt / tau)


def prepare(params, dt):
    """Return the driver array for step ``dt``.

    Layout: largest deliverable current, ZOH lag factors ``1 - exp(-dt/tau)``, dead time in
    samples, then the static-map parameters.
    """
    p = params.to_array()
    n_dead = int(round(params.dead_time / dt))
    if n_dead > DEAD_TIME_BUFFER:
        raise ValueError(f'DriverParams: dead_time {params.dead_time} s exceeds '
                         f'{DEAD_TIME_BUFFER} steps of {dt} s')
    head = [float(static_current(p, params.v_max)), _alpha(params.tau_rise, dt),
            _alpha(params.tau_fall, dt), float(n_dead), _alpha(params.fluid_tau_rise, dt),
            _alpha(params.fluid_tau_fall, dt)]
    return np.concatenate([np.array(head), p[:5]])


@njit(cache=True)
def lag_step(y, u, a_rise, a_fall):
    """One step of a first-order lag with rise/fall factors: ``y + a (u - y)``.

    ``a = 1 - exp(-dt/tau)`` with ``tau`` the rise constant if ``u > y``, else the fall one
    (exact for a piecewise-constant input); used by the driver lag and the fluid lag.
    """
    return y + (a_rise if u > y else a_fall) * (u - y)


@njit(cache=True)
def driver_input(q, s, u):
    """Feed the static-map output ``u`` [A] of this step into the lag and the dead-time buffer.

    ``y += (1 - exp(-dt/tau)) (u - y)`` with ``tau = tau_rise`` if ``u > y`` else ``tau_fall``
    (exact for a piecewise-constant input); ``y`` enters the ring buffer of
    ``round(dead_time / dt)`` samples. Call after :func:`driver_output` of the same step.
    """
    y = lag_step(s[DRV_LAG], u, q[Q_ARISE], q[Q_AFALL])
    s[DRV_LAG] = y
    nd = int(q[Q_NDEAD])
    if nd > 0:
        head = int(s[DRV_HEAD])
        s[DRV_BUF + head] = y
        head += 1
        s[DRV_HEAD] = 0 if head >= nd else head


@njit(cache=True)
def driver_output(q, s):
    """Return (coil, field) [A] of this step from the lag output ``dead_time`` ago.

    With a dead time of at least one sample the coil current does not depend on this step's
    command, so the damper force can be computed before the command arrives (the actuator node
    uses that in lock-step). The fluid lag has its own rise/fall constants.
    """
    if int(q[Q_NDEAD]) > 0:
        coil = s[DRV_BUF + int(s[DRV_HEAD])]
    else:
        coil = s[DRV_LAG]
    f = lag_step(s[DRV_FLUID], coil, q[Q_FRISE], q[Q_FFALL])
    s[DRV_FLUID] = f
    return coil, f


@njit(cache=True)
def driver_field_ahead(q, s, ahead):
    """Return the field current [A] ``ahead`` samples after the one :func:`driver_output` read.

    Call after :func:`driver_output` of the present sample, before its :func:`driver_input`. The
    dead-time ring holds the lag outputs of the next ``n_dead - 1`` samples already, so for
    ``ahead <= n_dead - 1`` the result is exact whatever the commands still to come (the fluid
    lag is advanced on a local copy; ``s`` is unchanged); a larger ``ahead`` is clipped to
    ``n_dead - 1`` (0 without a dead time: the present field).
    """
    nd = int(q[Q_NDEAD])
    f = s[DRV_FLUID]
    head = int(s[DRV_HEAD])
    for m in range(1, min(ahead, nd - 1) + 1):
        f = lag_step(f, s[DRV_BUF + (head + m) % nd], q[Q_FRISE], q[Q_FFALL])
    return f


@njit(cache=True)
def driver_step_current(q, s, u):
    """Advance driver and fluid one step from the static-map output ``u`` [A].

    Lag and dead time (:func:`driver_input`) then fluid (:func:`driver_output`); with a dead
    time the output is read before this step's input enters the buffer, as a ring buffer
    does. Returns (coil current, field current) [A].
    """
    if int(q[Q_NDEAD]) > 0:
        coil, f = driver_output(q, s)
        driver_input(q, s, u)
        return coil, f
    driver_input(q, s, u)
    return driver_output(q, s)


@njit(cache=True)
def driver_step_voltage(q, s, volt):
    """Advance one step from a driver input voltage [V] (static map, lag, dead time, fluid)."""
    return driver_step_current(q, s, static_current(q[Q_STATIC:], volt))


@njit(cache=True)
def driver_step(q, s, i_cmd):
    """Advance one step from a current command [A].

    The ECU applies ``command_voltage(i_cmd)`` and the driver's static map returns
    ``static_current`` of it, which is ``i_cmd`` clipped to ``[0, i_top]``; that identity is used
    directly (no pow calls on the hot path).
    """
    return driver_step_current(q, s, clip_command(q, i_cmd))


@njit(cache=True)
def clip_command(q, i_cmd):
    """Apply the static map to an ECU current command: clip to ``[0, i_top]`` (NaN -> 0)."""
    if not i_cmd > 0.0:
        return 0.0
    if i_cmd > q[Q_ITOP]:
        return q[Q_ITOP]
    return i_cmd


def driver_state(current=0.0):
    """Return a driver state array at rest with all stages at ``current`` [A]."""
    s = np.zeros(DRIVER_STATE_SIZE)
    s[DRV_LAG] = current
    s[DRV_FLUID] = current
    s[DRV_BUF:] = current
    return s


@njit(cache=True)
def driver_series(q, i_cmd):
    """Run the driver over a command array from rest; returns (coil, field) arrays."""
    s = np.zeros(DRIVER_STATE_SIZE)
    n = i_cmd.shape[0]
    coil = np.empty(n)
    field = np.empty(n)
    for k in range(n):
        coil[k], field[k] = driver_step(q, s, i_cmd[k])
    return coil, field


def fitted_dynamics(block, name='current_dynamics'):
    """Return ``{dead_time, tau_rise, tau_fall}`` of a fitted-model block, checked (>= 0)."""
    if not isinstance(block, dict):
        raise ValueError(f'fitted model {name}: expected a mapping')
    out = {}
    for k in ('dead_time', 'tau_rise', 'tau_fall'):
        if k not in block:
            raise ValueError(f'fitted model {name}: missing key {k}; add it (seconds)')
        hi = DEAD_TIME_MAX if k == 'dead_time' else LAG_MAX
        out[k] = check_range(f'fitted model {name}', k, block[k], 0.0, hi, 's',
                             'current dead time' if k == 'dead_time' else 'current lag')
    return out


def from_fitted_model(model, base=None):
    """Return DriverParams carrying the current dynamics of a ``diagnose`` model.json mapping.

    Command input: the fitted dead time and rise/fall lags are the whole chain (driver fields,
    fluid lags 0). Measured-current input with an identified ``driver`` block: that block is the
    driver and the fitted lags are the fluid (a fitted dead time is added to the driver's: a
    dead time commutes with the lags). The static map comes from ``base``.
    """
    if not isinstance(model, dict) or 'current_dynamics' not in model:
        raise ValueError('fitted model: no "current_dynamics" block')
    dyn = fitted_dynamics(model['current_dynamics'])
    base = base or DriverParams()
    drv = model.get('driver')
    inp = model.get('input')
    if isinstance(inp, dict) and inp.get('signal') == 'current' and drv:
        drv = fitted_dynamics(drv, 'driver')
        return replace(base, tau_rise=drv['tau_rise'], tau_fall=drv['tau_fall'],
                       dead_time=min(drv['dead_time'] + dyn['dead_time'], DEAD_TIME_MAX),
                       fluid_tau_rise=dyn['tau_rise'], fluid_tau_fall=dyn['tau_fall'])
    return replace(base, tau_rise=dyn['tau_rise'], tau_fall=dyn['tau_fall'],
                   dead_time=dyn['dead_time'], fluid_tau_rise=0.0,
                   fluid_tau_fall=0.0)
