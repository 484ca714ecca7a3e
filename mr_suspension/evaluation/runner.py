"""Run control laws over scenarios and collect the ride metrics (pure numerics, no ROS).

A *law* is a controller parameter set of ``config/controllers`` (e.g. ``skyhook``) or a bare
law name of :data:`~mr_suspension.control.laws.LAW_IDS`; ``overrides`` such as
``{'skyhook': {'c_sky': 3000}}`` or ``{'*': {'estimation': 'ideal'}}`` change gains. The
controller gets the plant knowledge of the simulated corner
(:meth:`~mr_suspension.control.laws.ControllerParams.with_plant`). ``actuator_scale`` multiplies
every time constant and the dead time of the driver and fluid (0 = ideal actuator) and
``control_delay`` adds the sensor and compute latency [s].
"""

import numpy as np

from mr_suspension.control.laws import ControllerParams
from mr_suspension.core.metrics import ride_metrics
from mr_suspension.evaluation import scenarios as scn
from mr_suspension.sim import corner
from mr_suspension.sim.simulator import simulate

METRICS = ('body_acc_rms', 'body_acc_wk_rms', 'vdv', 'working_space_rms', 'working_space_peak',
           'tyre_load_rms', 'settling_time')
DEFAULT_LAWS = ('passive_0A', 'passive_1A', 'skyhook_onoff', 'skyhook', 'groundhook', 'hybrid',
                'add', 'sh_add', 'pdd', 'clipped_optimal', 'febc')


# Main gain of each law and the values of its trade-off family (city car scale).
GAIN_SWEEPS = {
    'skyhook_onoff': ('i_max', (0.1, 0.2, 0.3, 0.5, 1.0)),
    'skyhook': ('c_sky', (500.0, 1000.0, 2000.0, 4000.0, 8000.0)),
    'groundhook': ('c_ground', (250.0, 500.0, 1000.0, 2000.0, 4000.0)),
    'hybrid': ('c_sky', (500.0, 1000.0, 2000.0, 4000.0, 8000.0)),
    'add': ('i_max', (0.1, 0.2, 0.5, 1.0, 2.0)),
    'sh_add': ('i_max', (0.1, 0.2, 0.5, 1.0, 2.0)),
    'pdd': ('i_max', (0.1, 0.3, 0.5, 1.0, 2.0)),
    'clipped_optimal': ('i_max', (0.1, 0.3, 0.5, 1.0, 2.0)),
    'febc': ('febc_i_body', (0.0, 0.1, 0.3, 0.5, 1.0)),
}


def load_damper(value):
    """Damper parameters from an object, a ``config/dampers`` name or YAML, or a ``model.json``.

    See :func:`mr_suspension.sim.corner.load_damper` (a ``model.json`` is a damper fitted by
    ``mr-suspension diagnose``; a missing one raises ValueError).
    """
    try:
        return corner.load_damper(value)
    except FileNotFoundError as exc:
        if str(value).endswith('.json'):
            raise ValueError(f'damper model {value}: {exc.strerror or exc}') from None
        raise


scaled_driver = corner.scaled_driver


def controller_for(law, overrides=None):
    """Return the controller parameters of a named set or law, with ``overrides`` applied.

    ``overrides`` maps a law or set name (or ``'*'`` for all) to gains, e.g.
    ``{'skyhook': {'c_sky': 3000}}``.
    """
    name = law.law if isinstance(law, ControllerParams) else law
    overrides = overrides or {}
    changes = dict(overrides.get('*', {}))
    changes.update(overrides.get(name, {}))
    return corner.load_controller(law, changes)


def build_config(law, vehicle='city_car', damper='rd1005_bingham', driver='wonder_box',
                 control_delay=0.0, actuator_scale=1.0, overrides=None, dt=1e-3):
    """Corner configuration of ``law`` on the given vehicle, damper and driver (names/objects).

    Built by :func:`mr_suspension.sim.corner.build_corner`, the builder of every entry point.
    """
    return corner.build_corner(controller_for(law, overrides), vehicle, load_damper(damper),
                               driver, dt=dt, control_delay=control_delay,
                               actuator_scale=actuator_scale)


def run(laws=DEFAULT_LAWS, scenarios=('quick',), vehicle='city_car',
        damper='rd1005_bingham', driver='wonder_box', control_delay=0.0, actuator_scale=1.0,
        overrides=None, dt=1e-3, keep=False):
    """Simulate every law on every scenario; return a list of row dicts (and results if keep).

    Each row: ``law``, ``scenario`` and the :data:`METRICS` (SI units). With ``keep`` a dict
    ``{(law, scenario): SimResult}`` is returned as well.
    """
    names = scn.expand(scenarios)
    roads = [scn.make(n, dt) for n in names]
    rows = []
    kept = {}
    for law in laws:
        config = build_config(law, vehicle, damper, driver, control_delay, actuator_scale,
                              overrides, dt)
        label = law if isinstance(law, str) else law.law
        for sc in roads:
            res = simulate(config, sc.road)
            met = ride_metrics(res, t_event=sc.t_event)
            row = {'law': label, 'scenario': sc.name}
            row.update({k: met[k] for k in METRICS})
            if sc.kind != 'transient':
                row['settling_time'] = float('nan')
            row['i_mean'] = float(np.mean(res.i_cmd))
            rows.append(row)
            if keep:
                kept[(label, sc.name)] = res
    return (rows, kept) if keep else rows


def batch_metrics(configs, road):
    """Online metrics of many configurations on one road (parallel, no time histories).

    Units as in :func:`~mr_suspension.core.metrics.ride_metrics`
    (:func:`mr_suspension.sim.corner.batch_metrics`).
    """
    return corner.batch_metrics(configs, [road])


def passive_sweep(values, scenario='iso_C_20', vehicle='city_car',
                  damper='rd1005_bingham', dt=1e-3, kind='current'):
    """Metrics of passive settings: constant currents of the MR damper or linear dampers.

    ``kind='current'``: ``values`` are currents [A] with the damper ``damper`` and an ideal
    driver; ``kind='linear'``: ``values`` are viscous coefficients [N s/m] of a linear damper.
    Returns the dict of metric arrays of :func:`~mr_suspension.sim.simulator.simulate_batch`.
    """
    from mr_suspension.core.damper import LinearDamperParams
    sc = scn.make(scenario, dt)
    configs = []
    for val in values:
        if kind == 'current':
            configs.append(build_config(ControllerParams(law='constant', current=float(val)),
                                        vehicle, damper, 'ideal', dt=dt))
        elif kind == 'linear':
            configs.append(build_config(ControllerParams(law='constant'), vehicle,
                                        LinearDamperParams(c=float(val)), 'ideal', dt=dt))
        else:
            raise ValueError("passive_sweep: kind must be 'current' or 'linear'")
    return batch_metrics(configs, sc.road)


def tune(law, param, values, scenario='iso_C_20', objective='body_acc_wk_rms',
         vehicle='city_car', damper='rd1005_bingham', driver='wonder_box',
         control_delay=0.0, dt=1e-3, overrides=None):
    """Grid search of one gain; returns ``(best_value, values, objective_values, metrics)``."""
    values = list(values)
    if not values:
        raise ValueError('tune: no values')
    sc = scn.make(scenario, dt)
    configs = []
    for val in values:
        ov = {k: dict(v) for k, v in (overrides or {}).items()}
        ov.setdefault(law, {})[param] = val
        configs.append(build_config(law, vehicle, damper, driver, control_delay, 1.0, ov, dt))
    met = batch_metrics(configs, sc.road)
    if objective not in met:
        raise ValueError(f'tune: objective must be one of {sorted(met)}')
    obj = met[objective]
    return values[int(np.argmin(obj))], values, obj, met
