"""Step-by-step pieces of :func:`~mr_suspension.sim.simulator.corner_loop` for the ROS 2 nodes.

The offline simulator runs controller, driver, damper and plant in one jitted loop. The node set
splits that loop into three objects that hold their own arrays and run the very same jitted
functions in the very same order, so a lock-step run of the nodes reproduces the simulator:

* :class:`ControllerStepper`: measurement vector -> current command (``controller_step``);
* :class:`ActuatorStepper`: command and stroke motion -> coil/field current, damper force and its
  tangent ``dF/dv`` (``driver_step`` then ``damper_force``);
* :class:`PlantStepper`: damper force and tangent -> next corner state (``plant_step``, road at
  mid-step).

Coupling (one-sample, stable by design): the actuator returns the force ``F_m`` *and* its
tangent ``c_m = dF/dv`` evaluated at the stroke rate ``v_m`` it was given. The plant applies
``F_m + c_m (v - v_m)`` with ``v`` its own present stroke rate (:meth:`PlantStepper.coupled`)
inside the linearly implicit step, so the stiff pre-yield branch of MR laws acts implicitly even
when the force is one sample old; when the force belongs to the present sample (lock-step, or a
fast loop in real time) the correction is exactly zero and the step equals the simulator's.

Pure numerics (no ROS imports).
"""

import math

import numpy as np

from mr_suspension.control import laws
from mr_suspension.core import damper as dmp
from mr_suspension.core import driver as drv
from mr_suspension.core import quarter_car as qc
from mr_suspension.sim.simulator import DELAY_BUFFER


class ControllerStepper:
    """Control law of a :class:`~mr_suspension.sim.simulator.CornerConfig` one step at a time.

    ``step(acc_s, acc_u, stroke, field)`` takes what a car's sensors give (body and wheel
    acceleration with gravity removed [m/s^2], stroke [m], measured current [A], NaN when
    unknown). The velocity slots of the measurement vector (``M_STROKE_RATE``, ``M_VEL_S``,
    ``M_VEL_U``) are NaN: the control core estimates the velocities from the sensors
    (:mod:`mr_suspension.control.estimation`). ``velocities`` fills them for studies with
    ideal measurements (``estimation='ideal'``).
    """

    def __init__(self, config):
        _, _, _, _, self.cid, self.cp = config.arrays()
        self.cs = np.zeros(laws.N_CTRL_STATE)
        self.m = np.zeros(laws.N_MEAS)
        self.dt = config.dt
        self.i_min = float(self.cp[laws.P_IMIN])
        self.i_max = float(self.cp[laws.P_IMAX])
        self.uses_field = laws.uses_field(self.cid, self.cp)

    def step(self, acc_s, acc_u, stroke, field=math.nan, velocities=None):
        """Return the current command [A] for one sample of measurements."""
        m = self.m
        m[laws.M_ACC_S] = acc_s
        m[laws.M_ACC_U] = acc_u
        m[laws.M_STROKE] = stroke
        m[laws.M_FIELD] = field
        if velocities is None:
            velocities = (math.nan, math.nan, math.nan)
        m[laws.M_STROKE_RATE], m[laws.M_VEL_S], m[laws.M_VEL_U] = velocities
        return float(laws.controller_step(self.cid, self.cp, self.cs, m, self.dt))

    def warm_up(self):
        """Compile (or load from cache) the jitted law on scratch state; return self.

        A node calls this before it joins the graph, so that its first samples are not late.
        """
        laws.controller_step(self.cid, self.cp, self.cs.copy(), np.zeros_like(self.m),
                             self.dt)
        return self


class ActuatorStepper:
    """Current driver (Wonder Box), fluid and MR damper one step at a time.

    ``step(i_cmd, x, v)`` advances the driver by one sample with the command, then evaluates
    the damper law at stroke ``x`` and rate ``v``; returns ``(coil, field, force, tangent)``.
    ``delay_steps`` reproduces the simulator's ``control_delay`` (0 by default).
    """

    def __init__(self, config, delay_steps=None):
        _, self.law, self.dp, self.drv_p, _, _ = config.arrays()
        self.ds = np.zeros(dmp.n_state_of(config.damper) + 8)
        self.drv_s = np.zeros(drv.DRIVER_STATE_SIZE)
        self.dt = config.dt
        if delay_steps is None:
            delay_steps = int(round(config.control_delay / config.dt))
        if not 0 <= delay_steps < DELAY_BUFFER:
            raise ValueError(f'ActuatorStepper: delay_steps must be in [0, {DELAY_BUFFER})')
        self.delay_n = delay_steps
        self.dbuf = np.zeros(max(delay_steps, 1))
        self.head = 0

    @property
    def command_ahead(self):
        """True when the force of a step does not depend on that step's command.

        With a driver dead time of at least one sample the coil current lags the command, so
        :meth:`force` can run as soon as the motion arrives and :meth:`command` afterwards
        (the lock-step actuator then takes the controller off the critical path).
        """
        return int(self.drv_p[drv.Q_NDEAD]) > 0

    def _delayed(self, i_cmd):
        if self.delay_n > 0:
            i_apply = self.dbuf[self.head]
            self.dbuf[self.head] = i_cmd
            self.head = (self.head + 1) % self.delay_n
            return i_apply
        return i_cmd

    def force(self, x, v, ahead=0):
        """First half of a step: (coil, field, force, dF/dv) from the driver's delayed output.

        ``ahead`` > 0 evaluates the damper at this motion with the field current of the sample
        ``ahead`` steps later (exact up to the driver's dead time minus one sample,
        :func:`~mr_suspension.core.driver.driver_field_ahead`): the force for a plant that
        applies it ``ahead`` samples late (the lock-step ``coupling_delay``). The returned
        field is the present one.
        """
        coil, field = drv.driver_output(self.drv_p, self.drv_s)
        used = drv.driver_field_ahead(self.drv_p, self.drv_s, ahead) if ahead > 0 else field
        f_d, c_d = dmp.damper_force(self.law, self.dp, self.ds, x, v, used, self.dt)
        return float(coil), float(field), float(f_d), float(c_d)

    def command(self, i_cmd):
        """Second half of a step: feed this step's command into the driver."""
        drv.driver_input(self.drv_p, self.drv_s,
                         drv.clip_command(self.drv_p, self._delayed(i_cmd)))

    def warm_up(self):
        """Compile (or load from cache) the driver and damper functions on scratch state."""
        drv_s, ds = self.drv_s.copy(), self.ds.copy()
        drv.driver_output(self.drv_p, drv_s)
        drv.driver_input(self.drv_p, drv_s, drv.clip_command(self.drv_p, 0.0))
        drv.driver_field_ahead(self.drv_p, drv_s, 1)
        drv.driver_step(self.drv_p, drv_s, 0.0)
        dmp.damper_force(self.law, self.dp, ds, 0.0, 0.0, 0.0, self.dt)
        return self

    def step(self, i_cmd, x, v):
        """Return (coil current, field current, damper force, dF/dv) for one sample."""
        coil, field = drv.driver_step(self.drv_p, self.drv_s, self._delayed(i_cmd))
        f_d, c_d = dmp.damper_force(self.law, self.dp, self.ds, x, v, field, self.dt)
        return float(coil), float(field), float(f_d), float(c_d)


class RoadClock:
    """Sample count of a plant stepper driven over a road (``road``, ``k``, ``dt``)."""

    @property
    def n_steps(self):
        """Number of steps the road covers."""
        return self.road.n_steps

    @property
    def done(self):
        """True once the road is used up."""
        return self.k >= self.road.n_steps

    @property
    def t(self):
        """Time of the present sample [s]."""
        return self.k * self.dt


class PlantStepper(RoadClock):
    """Quarter car driven over a road, one fixed step at a time.

    Sample ``k`` is the state at ``t_k = k dt``; :meth:`step` advances to ``k + 1`` with the road
    at mid-step, exactly as the simulator. ``a_s``, ``a_u`` and ``f_t`` hold the mean body and
    wheel acceleration and the tyre force of the last step (``0, 0, static load`` at ``k = 0``).
    """

    def __init__(self, config, road):
        if abs(road.dt - config.dt) > 1e-12 * config.dt:
            raise ValueError(f'road sampled at dt={road.dt} but the plant steps at '
                             f'dt={config.dt}')
        self.car_p = config.arrays()[0]
        self.q = np.zeros(qc.N_STATE)  # body, wheel, then the strut top (top mount only)
        self.road = road
        self.dt = config.dt
        self.k = 0
        self.a_s = 0.0
        self.a_u = 0.0
        self.static_tyre_load = config.car.static_tyre_load
        self.f_t = self.static_tyre_load
        self.f_d = 0.0
        self.g = config.car.g

    @property
    def stroke(self):
        """Strut stroke ``x = z_s - z_u`` (``z_t - z_u`` with a top mount) [m] (+ = extension)."""
        return float(qc.strut_motion(self.car_p, self.q)[0])

    @property
    def stroke_rate(self):
        """Strut stroke rate ``v = v_s - v_u`` (``v_t - v_u`` with a top mount) [m/s]."""
        return float(qc.strut_motion(self.car_p, self.q)[1])

    def road_now(self):
        """Road height and rate at the present sample [m, m/s]."""
        k = min(self.k, self.road.n_steps)
        return float(self.road.z[k]), float(self.road.zdot[k])

    def coupled(self, f_m, c_m, v_m):
        """Force to apply now from a force ``f_m`` and tangent ``c_m`` evaluated at rate ``v_m``.

        First-order extrapolation along the tangent to the present stroke rate; zero correction
        when the force belongs to the present sample.
        """
        return f_m + c_m * (self.stroke_rate - v_m)

    def warm_up(self):
        """Compile (or load from cache) the jitted plant step on scratch state; return self."""
        qc.plant_step(self.car_p, self.q.copy(), 0.0, 0.0, 0.0, 0.0, self.dt)
        qc.strut_motion(self.car_p, self.q)
        return self

    def step(self, f_d, c_d):
        """Advance one step with damper force ``f_d`` [N] and tangent ``c_d`` [N s/m]."""
        k = self.k
        if k >= self.road.n_steps:
            raise IndexError('PlantStepper: the road is used up')
        z_r = 0.5 * (self.road.z[k] + self.road.z[k + 1])
        zr_dot = 0.5 * (self.road.zdot[k] + self.road.zdot[k + 1])
        a_s, a_u, f_t = qc.plant_step(self.car_p, self.q, f_d, c_d, z_r, zr_dot, self.dt)
        self.a_s = float(a_s)
        self.a_u = float(a_u)
        self.f_t = float(f_t)
        self.f_d = float(f_d)
        self.k = k + 1
        if not math.isfinite(self.a_s + self.a_u + float(np.sum(self.q))):
            raise FloatingPointError('plant diverged (non-finite state); check parameters')
        return self.a_s, self.a_u, self.f_t
