"""Load parameter sets from the YAML files in ``config/`` (one file per vehicle, damper, ...).

A name such as ``seed001_military`` is looked up as ``config/<kind>/<name>.yaml``; a path to a
YAML (or JSON) file is read directly. The config directory is found in this order:
``$MR_SUSPENSION_CONFIG``, the source tree (``<repo>/config``), then the ament share directory
of an installed package.
"""

import os
from pathlib import Path

import yaml

from mr_suspension.control.laws import ControllerParams
from mr_suspension.core.damper import damper_from_dict
from mr_suspension.core.driver import DriverParams, from_fitted_model
from mr_suspension.core.quarter_car import QuarterCarParams

KINDS = ('vehicles', 'dampers', 'drivers', 'controllers', 'scenarios')


def config_dir():
    """Return the directory holding the packaged YAML parameter sets."""
    env = os.environ.get('MR_SUSPENSION_CONFIG')
    if env:
        return Path(env)
    here = Path(__file__).resolve().parents[2] / 'config'
    if here.is_dir():
        return here
    try:
        from ament_index_python.packages import get_package_share_directory
        return Path(get_package_share_directory('mr_suspension')) / 'config'
    except Exception:  # noqa: B902 - ament index missing or package not installed
        raise FileNotFoundError('cannot find the mr_suspension config directory; '
                                'set MR_SUSPENSION_CONFIG') from None


def available(kind):
    """Names of the parameter sets of ``kind`` (e.g. ``'vehicles'``)."""
    if kind not in KINDS:
        raise ValueError(f'unknown config kind {kind!r}; known: {KINDS}')
    return sorted(p.stem for p in (config_dir() / kind).glob('*.yaml'))


def load_yaml(kind, name_or_path):
    """Read the mapping of a named parameter set or a YAML file path."""
    path = Path(str(name_or_path))
    if path.suffix not in ('.yaml', '.yml', '.json'):
        path = config_dir() / kind / f'{name_or_path}.yaml'
    if not path.is_file():
        names = available(kind) if kind in KINDS else []
        raise FileNotFoundError(f'no {kind} parameter set {name_or_path!r} ({path}); '
                                f'available: {names}')
    try:
        with open(path, encoding='utf-8') as fh:
            data = yaml.safe_load(fh)
    except yaml.YAMLError as exc:
        raise ValueError(f'{path}: not valid YAML ({exc})') from None
    if not isinstance(data, dict):
        raise ValueError(f'{path}: expected a mapping of parameters')
    data.pop('description', None)
    data.pop('source', None)
    return data


def load_vehicle(name):
    """Load quarter-car parameters from ``config/vehicles``."""
    return QuarterCarParams.from_dict(load_yaml('vehicles', name))


def load_damper(name):
    """Load a damper law and parameters from ``config/dampers`` (key ``law`` selects it).

    A ``model.json`` written by ``mr-suspension diagnose`` also works: its fitted extended
    damper is used, so simulator and nodes run with the corrected damper.
    """
    data = load_yaml('dampers', name)
    if isinstance(data.get('damper'), dict):
        data = data['damper']
    return damper_from_dict(data)


def load_driver(name):
    """Load current-driver (Wonder Box) and fluid parameters from ``config/drivers``.

    A ``diagnose`` ``model.json`` gives the Wonder Box with the fitted current dynamics.
    """
    data = load_yaml('drivers', name)
    if 'current_dynamics' in data:
        return from_fitted_model(data)
    return DriverParams.from_dict(data)


def load_controller(name):
    """Load a controller law and its gains from ``config/controllers``."""
    return ControllerParams.from_dict(load_yaml('controllers', name))
