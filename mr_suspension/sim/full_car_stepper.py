"""Step-by-step pieces of :func:`~mr_suspension.sim.full_car_sim.full_car_loop` for the nodes.

The full-car counterpart of :mod:`~mr_suspension.sim.stepper`: the body and the four wheels
(:class:`FullCarPlantStepper`) and the modal law (:class:`ModalControllerStepper`) hold their
own arrays and run the simulator's jitted functions in its order, so that a lock-step run of
the full-car plant with per-corner
:class:`~mr_suspension.sim.stepper.ActuatorStepper` and
:class:`~mr_suspension.sim.stepper.ControllerStepper` (or the modal stepper) reproduces
:func:`~mr_suspension.sim.full_car_sim.simulate` to round-off.

The body IMU sits at the centre of gravity with ISO 8855 axes (x forward, y left, z up): its
vertical acceleration (gravity removed here), pitch rate (about y, positive nose down) and
roll rate (about x, positive left side up), the inputs of
:func:`~mr_suspension.control.modal.modal_step`. Pure numerics (no ROS imports).
"""

import math

import numpy as np

from mr_suspension.control import laws
from mr_suspension.control.modal import modal_step, N_MODAL_STATE
from mr_suspension.core import full_car as fc
from mr_suspension.core.car_road import CarRoad
from mr_suspension.sim.full_car_sim import FullCarConfig
from mr_suspension.sim.stepper import RoadClock

N_CORNERS = fc.N_CORNERS


def _check_config(config, owner):
    if not isinstance(config, FullCarConfig):
        raise ValueError(f'{owner}: config must be a FullCarConfig, got '
                         f'{type(config).__name__}')


class FullCarPlantStepper(RoadClock):
    """Full car (body heave, pitch, roll and four wheels) over a :class:`CarRoad`, one step a time.

    Sample ``k`` is the state at ``t_k = k dt``; :meth:`step` advances to ``k + 1`` with each
    wheel on its road at mid-step, exactly as the simulator. The mean accelerations and the tyre
    forces of the last step are kept (zero and the static loads at ``k = 0``); corner ``i``'s
    body acceleration is that of the body point above it.
    """

    def __init__(self, config, road):
        _check_config(config, 'FullCarPlantStepper')
        if not isinstance(road, CarRoad):
            raise ValueError(f'FullCarPlantStepper: road must be a CarRoad (four wheels), got '
                             f'{type(road).__name__}')
        if abs(road.dt - config.dt) > 1e-12 * config.dt:
            raise ValueError(f'road sampled at dt={road.dt} but the plant steps at '
                             f'dt={config.dt}')
        arr = config.arrays()
        self.body_map, self.mb, self.arb = arr['t'], arr['mb'], arr['arb']
        self.car_ps = arr['car_ps']
        self.nb = int(self.arb[0])
        self.coupled_body = config.coupled
        self.q = np.zeros(fc.N_FULL_STATE)
        self.acc = np.zeros(2 * fc.N_BODY_MAX)
        self.road = road
        self.dt = config.dt
        self.k = 0
        corners = [config.car.corner(i) for i in range(N_CORNERS)]
        self.static_tyre_load = np.array([c.static_tyre_load for c in corners])
        self.f_t = self.static_tyre_load.copy()
        self.f_d = np.zeros(N_CORNERS)
        self.g = corners[0].g
        self._f = np.zeros(N_CORNERS)
        self._c = np.zeros(N_CORNERS)
        self._zr = np.zeros(N_CORNERS)
        self._zrd = np.zeros(N_CORNERS)
        n = fc.N_BODY_MAX + N_CORNERS
        self._wm = np.zeros((3, n, n))
        self._wv = np.zeros((12, n))

    def motion(self, i):
        """Stroke and stroke rate ``(x_i, v_i)`` of corner ``i`` [m, m/s] (+ = extension)."""
        x, v = fc.corner_motion(self.body_map, self.nb, self.q, i)
        return float(x), float(v)

    def stroke(self, i):
        """Stroke of corner ``i`` [m]."""
        return self.motion(i)[0]

    def stroke_rate(self, i):
        """Stroke rate of corner ``i`` [m/s]."""
        return self.motion(i)[1]

    def body_point(self, i):
        """Height and vertical velocity of the body point above corner ``i`` [m, m/s]."""
        z, v = fc.body_point(self.body_map, self.nb, self.q, i)
        return float(z), float(v)

    def wheel(self, i):
        """Height and vertical velocity of wheel ``i`` [m, m/s]."""
        return float(self.q[fc.WHEEL0 + i]), float(self.q[fc.RATE0 + fc.WHEEL0 + i])

    def a_s(self, i):
        """Mean vertical acceleration of the body point above corner ``i`` over the last step."""
        return float(sum(self.body_map[i, j] * self.acc[j] for j in range(self.nb)))

    def a_u(self, i):
        """Mean acceleration of wheel ``i`` over the last step [m/s^2]."""
        return float(self.acc[fc.WHEEL0 + i])

    def imu(self):
        """Body IMU at the CG: ``(a_z, pitch rate, roll rate)`` [m/s^2, rad/s, rad/s].

        ``a_z``: mean vertical acceleration of the last step, gravity removed; the rates at the
        present sample. Uncoupled body (four independent masses): the first mass, no rotation.
        """
        if not self.coupled_body:
            return float(self.acc[0]), 0.0, 0.0
        return (float(self.acc[0]), float(self.q[fc.RATE0 + 1]),
                float(self.q[fc.RATE0 + 2]))

    def road_now(self, i):
        """Road height and rate under wheel ``i`` at the present sample [m, m/s]."""
        k = min(self.k, self.road.n_steps)
        return float(self.road.z[i, k]), float(self.road.zdot[i, k])

    def coupled(self, i, f_m, c_m, v_m):
        """Force to apply at corner ``i`` now from ``f_m``, tangent ``c_m`` evaluated at ``v_m``.

        As :meth:`~mr_suspension.sim.stepper.PlantStepper.coupled`: first-order extrapolation
        along the tangent to the corner's present stroke rate (zero correction when the force
        belongs to the present sample).
        """
        return f_m + c_m * (self.stroke_rate(i) - v_m)

    def warm_up(self):
        """Compile (or load from cache) the jitted functions on scratch state; return self."""
        q = self.q.copy()
        fc.full_car_step(self.body_map, self.mb, self.arb, self.car_ps, q, self._f, self._c,
                         self._zr, self._zrd, self.dt, self.acc.copy(), self.f_t.copy(),
                         self._wm, self._wv)
        fc.corner_motion(self.body_map, self.nb, self.q, 0)
        fc.body_point(self.body_map, self.nb, self.q, 0)
        return self

    def step(self, forces, tangents):
        """Advance one step with the four damper forces [N] and tangents [N s/m]."""
        k = self.k
        if k >= self.road.n_steps:
            raise IndexError('FullCarPlantStepper: the road is used up')
        z, zd = self.road.z, self.road.zdot
        for i in range(N_CORNERS):
            self._f[i] = forces[i]
            self._c[i] = tangents[i]
            self._zr[i] = 0.5 * (z[i, k] + z[i, k + 1])
            self._zrd[i] = 0.5 * (zd[i, k] + zd[i, k + 1])
        fc.full_car_step(self.body_map, self.mb, self.arb, self.car_ps, self.q, self._f,
                         self._c, self._zr, self._zrd, self.dt, self.acc, self.f_t, self._wm,
                         self._wv)
        self.f_d[:] = self._f
        self.k = k + 1
        if not math.isfinite(float(np.sum(self.acc)) + float(np.sum(self.q))):
            raise FloatingPointError('full-car plant diverged (non-finite state); check '
                                     'parameters')


class ModalControllerStepper:
    """Modal sky-hook of a :class:`FullCarConfig` (``modal`` set) one sample at a time.

    ``step(imu, corners)`` takes the body IMU ``(a_z, pitch rate, roll rate)`` (gravity
    removed) and per corner ``(acc_s, acc_u, stroke, field)`` as
    :meth:`~mr_suspension.sim.stepper.ControllerStepper.step` does (velocity slots NaN: each
    corner estimates its stroke rate from its sensors); returns the four current commands.
    """

    def __init__(self, config):
        _check_config(config, 'ModalControllerStepper')
        if config.modal is None:
            raise ValueError('ModalControllerStepper: the config has no modal law (modal=None)')
        arr = config.arrays()
        self.g_map = arr['g']
        self.mp = arr['mp']
        self.cps = arr['cps']
        self.css = np.zeros((N_CORNERS, laws.N_CTRL_STATE))
        self.ms = np.zeros(N_MODAL_STATE)
        self.meas = np.full((N_CORNERS, laws.N_MEAS), math.nan)
        self.imu = np.zeros(3)
        self.out = np.zeros(N_CORNERS)
        self.dt = config.dt
        self.i_min = tuple(float(p[laws.P_IMIN]) for p in self.cps)
        self.i_max = tuple(float(p[laws.P_IMAX]) for p in self.cps)
        inverse = laws.LAW_IDS['skyhook']  # the modal force goes through each corner's inverse
        self.uses_field = any(laws.uses_field(inverse, p) for p in self.cps)

    def step(self, imu, corners):
        """Return the four current commands [A] for one sample (class doc)."""
        self.imu[:] = imu
        m = self.meas
        for i, (acc_s, acc_u, stroke, field) in enumerate(corners):
            m[i, laws.M_ACC_S] = acc_s
            m[i, laws.M_ACC_U] = acc_u
            m[i, laws.M_STROKE] = stroke
            m[i, laws.M_FIELD] = field
        modal_step(self.g_map, self.mp, self.ms, self.imu, self.cps, self.css, m, self.dt,
                   self.out)
        return [float(v) for v in self.out]

    def warm_up(self):
        """Compile (or load from cache) the jitted law on scratch state; return self."""
        modal_step(self.g_map, self.mp, self.ms.copy(), np.zeros(3), self.cps, self.css.copy(),
                   np.zeros_like(self.meas), self.dt, self.out.copy())
        return self
