"""Find the packaged YAML parameter sets in ``config/`` and build the plant's from them.

A name such as ``seed001_military`` is looked up as ``config/<kind>/<name>.yaml``; a path to a
YAML (or JSON) file is read directly. The config directory is ``$MR_SUSPENSION_CONFIG`` if set,
else ``config/`` of the package data (:func:`share_dir`). Vehicles, dampers and drivers are
built here (plant level: the control laws load an inverse damper model by name);
:mod:`~mr_suspension.sim.config` adds the controller sets.
"""

import os
from pathlib import Path
import sys

import yaml

from mr_suspension.core.damper import damper_from_dict
from mr_suspension.core.driver import DriverParams, from_fitted_model
from mr_suspension.core.full_car import FullCarParams
from mr_suspension.core.quarter_car import QuarterCarParams

KINDS = ('vehicles', 'dampers', 'drivers', 'controllers', 'scenarios')


PACKAGE = 'mr_suspension'


def share_candidates():
    """Directories that may hold the package data (``config/``, ``msg_defs/``), in search order.

    The source tree (``<repo>``, recognised by its ``package.xml``); the ament index when
    ``ament_index_python`` is importable and ``AMENT_PREFIX_PATH`` is set (colcon install
    space); ``<sys.prefix>/share/mr_suspension`` (where ``data_files`` go in a venv or wheel
    install); the ``share/mr_suspension`` of the prefix this copy of the package is installed
    under (``pip install --prefix``/``--user``).
    """
    here = Path(__file__).resolve()
    out = []
    if (here.parents[2] / 'package.xml').is_file():
        out.append(here.parents[2])
    if os.environ.get('AMENT_PREFIX_PATH'):
        try:
            from ament_index_python.packages import get_package_share_directory
            out.append(Path(get_package_share_directory(PACKAGE)))
        except Exception:  # noqa: B902 - not importable, or the package is not in the index
            pass
    out.append(Path(sys.prefix) / 'share' / PACKAGE)
    # <prefix>/lib/pythonX.Y/site-packages/mr_suspension/core/paramsets.py -> <prefix>
    if len(here.parents) > 5:
        out.append(here.parents[5] / 'share' / PACKAGE)
    return out


def share_dir(sub='config'):
    """Return the first data directory holding ``sub`` (``'config'`` or ``'msg_defs'``)."""
    tried = []
    for base in share_candidates():
        if (base / sub).is_dir():
            return base / sub
        tried.append(str(base / sub))
    raise FileNotFoundError(f'cannot find the mr_suspension {sub} directory (tried '
                            f'{", ".join(tried)}); reinstall the package or set '
                            'MR_SUSPENSION_CONFIG')


def config_dir():
    """Return the directory holding the packaged YAML parameter sets."""
    env = os.environ.get('MR_SUSPENSION_CONFIG')
    if env:
        return Path(env)
    return share_dir('config')


def available(kind):
    """Names of the parameter sets of ``kind`` (e.g. ``'vehicles'``)."""
    if kind not in KINDS:
        raise ValueError(f'unknown config kind {kind!r}; known: {KINDS}')
    return sorted(p.stem for p in (config_dir() / kind).glob('*.yaml'))


def load_yaml(kind, name_or_path):
    """Read the mapping of a named parameter set or a YAML file path."""
    return _load(kind, name_or_path)[0]


def _load(kind, name_or_path):
    """Return ``(mapping, path)`` of a named parameter set or a YAML/JSON file path."""
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
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ValueError(f'{path}: not valid YAML ({first}); fix the file') from None
    except IsADirectoryError:
        raise ValueError(f'{path}: is a directory; give a YAML file') from None
    if not isinstance(data, dict):
        raise ValueError(f'{path}: expected a mapping of parameters (key: value lines), got '
                         f'{type(data).__name__}')
    data.pop('description', None)
    data.pop('source', None)
    return data, path


def build_set(kind, name, make):
    """Load ``name`` of ``kind`` and build it with ``make(data, path)``; errors name the file."""
    data, path = _load(kind, name)
    try:
        return make(data, path)
    except (ValueError, TypeError) as exc:
        msg = str(exc)
        raise ValueError(msg if str(path) in msg else f'{path}: {msg}') from None


def load_vehicle(name):
    """Load quarter-car parameters from ``config/vehicles`` (every parameter is required)."""
    def make(data, path):
        if 'front' in data and 'rear' in data:
            raise ValueError(f'{path}: is a full car (front and rear corners); load it with '
                             'load_full_car, name one corner (<name>:front_left, ...) or give '
                             'a quarter-car file')
        return QuarterCarParams.from_dict(data, source=path)
    return build_set('vehicles', name, make)


def load_full_car(name):
    """Load full-car parameters (body, axles, ``front`` and ``rear`` corners) from a file."""
    return build_set('vehicles', name, lambda d, p: FullCarParams.from_dict(d, source=p))


def load_damper(name):
    """Load a damper law and parameters from ``config/dampers`` (key ``law`` selects it).

    A ``model.json`` written by ``mr-suspension diagnose`` also works: its fitted extended
    damper is used, so simulator and nodes run with the corrected damper.
    """
    def make(data, path):
        if 'damper' in data:
            data = data['damper']
        elif str(path).endswith('.json'):
            raise ValueError(f'{path}: not a fitted model file (no "damper" block); give the '
                             'model.json written by mr-suspension diagnose')
        return damper_from_dict(data, source=path)
    return build_set('dampers', name, make)


def load_driver(name):
    """Load current-driver (Wonder Box) and fluid parameters from ``config/drivers``.

    A ``diagnose`` ``model.json`` gives the Wonder Box with the fitted current dynamics.
    """
    def make(data, path):
        if 'current_dynamics' in data:
            return from_fitted_model(data)
        return DriverParams.from_dict(data, source=path)
    return build_set('drivers', name, make)
