"""Load parameter sets from the YAML files in ``config/`` (one file per vehicle, damper, ...).

A name such as ``seed001_military`` is looked up as ``config/<kind>/<name>.yaml``; a path to a
YAML (or JSON) file is read directly. The config directory is ``$MR_SUSPENSION_CONFIG`` if set,
else ``config/`` of the package data (:func:`share_dir`). The plant's sets (vehicles, dampers,
drivers) come from :mod:`~mr_suspension.core.paramsets`; the controller sets, which need the
control laws, are read here.
"""

from mr_suspension.control.laws import ControllerParams, LAW_IDS
from mr_suspension.core.paramsets import (available, build_set, config_dir, KINDS, load_damper,
                                          load_driver, load_full_car, load_vehicle, load_yaml,
                                          PACKAGE, share_candidates, share_dir)

__all__ = ['available', 'config_dir', 'configure', 'KINDS', 'load_controller', 'load_damper',
           'load_driver', 'load_full_car', 'load_vehicle', 'load_yaml', 'PACKAGE',
           'share_candidates', 'share_dir']


def load_controller(name):
    """Load a controller law and its gains from ``config/controllers`` (key ``law`` required)."""
    def make(data, path):
        if 'law' not in data:
            raise ValueError(f'{path}: missing required key law; add e.g. "law: skyhook"')
        for key in ('lqr_gains', 'lqr_weights'):
            if data.get(key) is not None and not isinstance(data[key], (list, tuple)):
                raise ValueError(f'{path}: {key} must be a list of 4 numbers, got '
                                 f'{data[key]!r}')
        return ControllerParams.from_dict(data)
    return build_set('controllers', name, make)


def configure(controller, car=None, damper=None, driver=None, **gains):
    """Return the controller of a corner: set or params, gains overridden, plant knowledge.

    ``controller``: a ``config/controllers`` name, a bare law name, a mapping or
    :class:`~mr_suspension.control.laws.ControllerParams`; ``gains``: any fields of
    :data:`~mr_suspension.control.laws.GAIN_DESCRIPTIONS`; ``car``, ``damper``, ``driver`` as
    in :meth:`~mr_suspension.control.laws.ControllerParams.with_plant`. This is what the
    controller node and the evaluation use, so both run the same law with the same knowledge.
    """
    if isinstance(controller, str):
        if controller in LAW_IDS and controller not in available('controllers'):
            controller = ControllerParams(law=controller)
        else:
            controller = load_controller(controller)
    elif isinstance(controller, dict):
        controller = ControllerParams.from_dict(controller)
    if gains:
        controller = ControllerParams.from_dict({**controller.to_dict(), **gains})
    return controller.with_plant(car, damper, driver)
