"""The one corner builder: vehicle, damper, driver and a controller that knows its plant.

Every entry point builds its :class:`~mr_suspension.sim.simulator.CornerConfig` here: the
``simulate``/``demo``/``tune`` commands (:mod:`mr_suspension.cli`), the node set
(:func:`mr_suspension.nodes.common.corner_config`) and the evaluation
(:func:`mr_suspension.evaluation.runner.build_config`). The controller always gets the plant
knowledge of the simulated corner (:meth:`~mr_suspension.control.laws.ControllerParams.with_plant`:
masses and stiffnesses for PDD, clipped optimal and the tyre-deflection estimate, the damper law
for the inverse model, the driver's current range), so a law cannot run with another car's
masses or another damper's inverse.

:func:`batch_metrics` wraps :func:`~mr_suspension.sim.simulator.simulate_batch` so that its
metrics mean what :func:`~mr_suspension.core.metrics.ride_metrics` means (``ntf_min`` is the
normalised minimum tyre force ``min F_t / F_t0``, ``tyre_force_min`` the force in N).
Pure numerics: no ROS imports.
"""

from dataclasses import replace
import math
from pathlib import Path

import numpy as np

from mr_suspension.control.laws import ControllerParams, LAW_IDS
from mr_suspension.core.damper import law_id_of
from mr_suspension.core.driver import DriverParams
from mr_suspension.core.full_car import AXLES, CORNERS
from mr_suspension.core.quarter_car import QuarterCarParams
from mr_suspension.sim import config as cfg
from mr_suspension.sim.simulator import CornerConfig, simulate_batch


def _is_path(value):
    return Path(str(value)).suffix in ('.yaml', '.yml', '.json')


def load_vehicle(value):
    """Vehicle parameters from an object, a ``config/vehicles`` name or a YAML path.

    ``<full car>:<corner>`` (a corner of :data:`~mr_suspension.core.full_car.CORNERS` or an
    axle, ``front`` or ``rear``) is that corner of a full-car set as a quarter car, its sprung
    mass the body's static share (e.g. ``lisa_full_car:front_left``): what the corner nodes of
    a full car use.
    """
    if isinstance(value, QuarterCarParams):
        return value
    name, sep, corner = str(value).rpartition(':')
    if sep and corner in CORNERS + AXLES:
        index = CORNERS.index(corner) if corner in CORNERS else 2 * AXLES.index(corner)
        return cfg.load_full_car(name).corner(index)
    if sep and name in cfg.available('vehicles'):
        raise ValueError(f'vehicle {value!r}: unknown corner {corner!r}; give one of '
                         f'{", ".join(CORNERS + AXLES)}')
    return cfg.load_vehicle(value)


def load_damper(value):
    """Damper parameters from an object, a ``config/dampers`` name or YAML, or a ``model.json``.

    A ``model.json`` is a damper fitted by ``mr-suspension diagnose`` (extended law), read by
    :func:`~mr_suspension.core.paramsets.load_damper`; its current dynamics are not used here
    (the driver set models them).
    """
    if not isinstance(value, (str, Path)):
        law_id_of(value)  # raises ValueError for anything that is not a damper
        return value
    return cfg.load_damper(value)


def load_driver(value):
    """Driver parameters from an object, a ``config/drivers`` name or a YAML/``model.json``."""
    if isinstance(value, DriverParams):
        return value
    if not isinstance(value, (str, Path)):
        raise ValueError('driver must be a DriverParams, a config/drivers name or a YAML path')
    return cfg.load_driver(value)


def load_controller(value, gains=None):
    """Return the controller parameters (no plant knowledge yet) with ``gains`` overridden.

    ``value``: :class:`ControllerParams`, a mapping, a ``config/controllers`` name or YAML path,
    or a bare law name of :data:`~mr_suspension.control.laws.LAW_IDS` (its default gains). A set
    name wins over a law name of the same spelling.
    """
    if isinstance(value, ControllerParams):
        ctrl = value
    elif isinstance(value, dict):
        ctrl = _from_dict(value)
    elif _is_path(value) or str(value) in cfg.available('controllers'):
        ctrl = cfg.load_controller(value)
    elif str(value) in LAW_IDS:
        ctrl = ControllerParams(law=str(value))
    else:
        raise ValueError(f'unknown controller {value!r}; controller sets: '
                         f'{cfg.available("controllers")}, laws: {sorted(LAW_IDS)}')
    if gains:
        ctrl = _from_dict({**ctrl.to_dict(), **gains})
    return ctrl


def _from_dict(data):
    try:
        return ControllerParams.from_dict(data)
    except TypeError as exc:
        raise ValueError(str(exc)) from None


def scaled_driver(driver, scale):
    """Driver with all lags and the dead time multiplied by ``scale`` (>= 0; 0 = ideal)."""
    if not (math.isfinite(scale) and scale >= 0.0):
        raise ValueError(f'actuator scale must be a finite number >= 0, got {scale!r}')
    if scale == 1.0:
        return driver
    return replace(driver, tau_rise=driver.tau_rise * scale, tau_fall=driver.tau_fall * scale,
                   dead_time=min(driver.dead_time * scale, 0.25),
                   fluid_tau_rise=driver.fluid_tau_rise * scale,
                   fluid_tau_fall=driver.fluid_tau_fall * scale)


def build_corner(controller='skyhook_onoff', vehicle='city_car', damper='rd1005_bingham',
                 driver='wonder_box', dt=1e-3, control_delay=0.0, actuator_scale=1.0,
                 gains=None):
    """Return the :class:`CornerConfig` of a controller on a vehicle, damper and driver.

    Each part is a parameter object, a ``config/<kind>`` name or a file path (see the
    ``load_*`` functions); ``gains`` override controller fields before the plant knowledge is
    copied in. ``actuator_scale`` multiplies the driver and fluid time constants and dead time,
    ``control_delay`` [s] is the sensor and compute latency, ``dt`` [s] the step.
    """
    car = load_vehicle(vehicle)
    dmp = load_damper(damper)
    drv = scaled_driver(load_driver(driver), actuator_scale)
    ctrl = load_controller(controller, gains).with_plant(car, dmp, drv)
    return CornerConfig(car=car, damper=dmp, driver=drv, controller=ctrl, dt=dt,
                        control_delay=control_delay)


def batch_metrics(configs, roads, road_index=None):
    """Online metrics of many corners (:func:`simulate_batch`) with the units of ``ride_metrics``.

    ``ntf_min`` is the normalised minimum tyre force ``min F_t / F_t0`` (F_t0 = (m_s + m_u) g,
    as in :func:`~mr_suspension.core.metrics.ride_metrics`); ``tyre_force_min`` is ``min F_t``
    in N. The batch kernel reports the force under ``ntf_min``; it is renamed and normalised
    here unless the kernel already gives ``tyre_force_min``.
    """
    configs = list(configs)
    met = simulate_batch(configs, roads, road_index)
    if 'tyre_force_min' not in met:
        f_t0 = np.array([c.car.static_tyre_load for c in configs])
        met['tyre_force_min'] = np.asarray(met.pop('ntf_min'))
        met['ntf_min'] = met['tyre_force_min'] / f_t0
    return met
