"""Fitted-model files (``model.json``) and predictions with a fitted model.

Layout::

    {"format": "mr_suspension.fitted_damper/1",
     "damper": {"law": "extended", ...ExtendedDamperParams fields (SI)...},
     "current_dynamics": {"dead_time": s, "tau_rise": s, "tau_fall": s},
     "input": {"signal": "current_command" | "voltage_command" | "current", "map": "..."},
     "effects": [...], "fitted_on": [...]}

The current dynamics map onto ``core.driver.DriverParams`` (``tau_rise``, ``tau_fall``,
``dead_time``; fluid time constants 0): the simulator and actuator node run the driver, then
``core.extended.extended_force`` with the damper block.
"""

import json
from pathlib import Path

from mr_suspension.core.driver import fitted_dynamics
from mr_suspension.core.extended import ExtendedDamperParams
from mr_suspension.identification import engine

FORMAT = 'mr_suspension.fitted_damper/1'
INPUT_MAPS = {
    'current_command': 'the current command is taken as the coil current (static map only)',
    'voltage_command': 'driver voltage through core.driver.static_current (DriverParams defaults)',
    'current': 'the measured coil current is the input (driver dynamics not included)',
}


def model_dict(params, dyn, effects, input_kind, fitted_on=(), extra=None):
    """Return the JSON-ready model dictionary."""
    d = {'format': FORMAT, 'damper': {'law': 'extended', **params.to_dict()},
         'current_dynamics': {k: float(dyn[k]) for k in ('dead_time', 'tau_rise', 'tau_fall')},
         'input': {'signal': input_kind, 'map': INPUT_MAPS.get(input_kind, '')},
         'effects': list(effects), 'fitted_on': list(fitted_on)}
    if extra:
        d.update(extra)
    return d


def save_model(path, model):
    """Write a model dictionary as JSON."""
    Path(path).write_text(json.dumps(model, indent=2) + '\n')


def load_model(path):
    """Read and validate a ``model.json``; return the dictionary.

    Wrong types, missing keys, NaN or implausible values raise a one-line ValueError naming the
    file and the key.
    """
    try:
        model = json.loads(Path(path).read_text(encoding='utf-8'))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
        raise ValueError(f'{path}: cannot read fitted model ({reason}); give the model.json '
                         'written by mr-suspension diagnose') from None
    return check_model(model, path)


def check_model(model, path='model.json'):
    """Validate a model mapping (see :func:`load_model`); return it."""
    if not isinstance(model, dict) or 'damper' not in model:
        raise ValueError(f'{path}: not a fitted model file (no "damper" block); give the '
                         'model.json written by mr-suspension diagnose')
    damper = model['damper']
    if not isinstance(damper, dict):
        raise ValueError(f'{path}: "damper" must be a mapping of parameters, got '
                         f'{type(damper).__name__}')
    if damper.get('law') != 'extended':
        raise ValueError(f'{path}: damper law must be "extended", got {damper.get("law")!r}')
    try:
        ExtendedDamperParams.from_dict(damper, source=path)
        if 'current_dynamics' not in model:
            raise ValueError('missing required key current_dynamics')
        fitted_dynamics(model['current_dynamics'])
    except ValueError as exc:
        msg = str(exc)
        raise ValueError(msg if str(path) in msg else f'{path}: {msg}') from None
    inp = model.get('input', {})
    signal = inp.get('signal') if isinstance(inp, dict) else inp
    if not isinstance(inp, dict) or (signal is not None and signal not in INPUT_MAPS):
        raise ValueError(f'{path}: input.signal must be one of {sorted(INPUT_MAPS)}, got '
                         f'{signal!r}')
    return model


def load_fitted_model(path):
    """Return ``(ExtendedDamperParams, current_dynamics dict)`` from a ``model.json``."""
    model = load_model(path)
    return (ExtendedDamperParams.from_dict(model['damper']),
            fitted_dynamics(model['current_dynamics']))


def fitted_driver(path, base=None):
    """Return ``core.driver.DriverParams`` carrying a fitted model's current dynamics.

    See :func:`mr_suspension.core.driver.from_fitted_model`; ``path`` is a model.json path or
    the loaded mapping.
    """
    from mr_suspension.core.driver import from_fitted_model

    return from_fitted_model(load_model(path) if not isinstance(path, dict) else path, base)


def predict(model, record):
    """Force [N] predicted by a model dictionary on a record (same path as the fit)."""
    check_model(model)
    params = ExtendedDamperParams.from_dict(model['damper'])
    if model.get('driver'):
        # As in the fit: a measured coil current is cleaned by the command through the
        # fitted driver (diagnose.denoise_current).
        from mr_suspension.identification.diagnose import denoise_current
        record = denoise_current(record, model['driver'])
    return engine.simulate(record, params, fitted_dynamics(model['current_dynamics']))
