"""Fitted-model files (``model.json``) and predictions with a fitted model.

Layout::

    {"format": "mr_suspension.fitted_damper/1",
     "damper": {"law": "extended", ...ExtendedDamperParams fields (SI)...},
     "current_dynamics": {"dead_time": s, "tau_rise": s, "tau_fall": s},
     "input": {"signal": "current_command" | "voltage_command" | "current", "map": "..."},
     "effects": [...], "fitted_on": [...],
     "fitted_range": {"abs_velocity_p999": m/s, "displacement": [m, m], "abs_input_max": A},
     "hedge": {"damper": {...}, "current_dynamics": {...}, "effects": [...], "weight": 0.5}}

``hedge`` (optional) is a second model that ties with the named one on the held-out data
(``diagnose._hedge``): ``predict`` returns the weighted mean of both; the simulator and the
actuator node run the named model (``damper``).

The current dynamics map onto ``core.driver.DriverParams`` (``tau_rise``, ``tau_fall``,
``dead_time``; fluid time constants 0): the simulator and actuator node run the driver, then
``core.extended.extended_force`` with the damper block.
"""

import json
import math
from pathlib import Path
import warnings

import numpy as np

from mr_suspension.core.driver import fitted_dynamics
from mr_suspension.core.extended import ExtendedDamperParams
from mr_suspension.identification import data as dataio
from mr_suspension.identification import domain, engine
from mr_suspension.identification.denoise import denoise_current

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


HEDGE_WEIGHT = 0.5  # the hedge's share of a prediction (``diagnose.predict_force``: the mean)


def hedge_dict(params, dyn, effects, weight=HEDGE_WEIGHT):
    """Return the ``hedge`` block: a second model whose prediction is averaged in."""
    return {'damper': {'law': 'extended', **params.to_dict()},
            'current_dynamics': {k: float(dyn[k]) for k in ('dead_time', 'tau_rise', 'tau_fall')},
            'effects': list(effects), 'weight': float(weight)}


RANGE_SLACK = 1.1  # a sample beyond this factor of the fitted range is outside it
RANGE_SHARE = 0.01  # share of samples outside the fitted range that earns a warning


def fitted_range(records):
    """Input range of the records a model was fitted on (usable samples only).

    99.9th percentile of ``|v|`` (a noise spike does not widen it), the stroke's extent and
    the largest ``|i|`` of the input. A sigmoid's tail, a loop standing in for a knee or a
    stiffness term are not identifiable outside it: on the benchmark, unseen records whose
    stroke rate reaches 1.5x the training's were predicted at a 95th percentile of 2.5-3.1
    noise floors, the others at 2.1 (docs/diagnose.md, Limits).
    """
    def cat(name):
        return np.concatenate([np.asarray(getattr(r, name), dtype=float)[np.asarray(r.mask)]
                               for r in records])

    v, x, i = cat('velocity'), cat('displacement'), cat('i_in')
    if not v.size:
        raise ValueError('fitted_range: no usable samples')
    return {'abs_velocity_p999': float(np.percentile(np.abs(v), 99.9)),
            'displacement': [float(np.min(x)), float(np.max(x))],
            'abs_input_max': float(np.max(np.abs(i)))}


def outside_range(rng, record, stroke=True):
    """Shares of a record's usable samples outside ``rng`` (``fitted_range``) and a message.

    A sample is outside when its ``|v|`` exceeds ``RANGE_SLACK`` times the fitted 99.9th
    percentile, its stroke lies beyond ``RANGE_SLACK`` times the fitted extent about its
    centre, or its ``|i|`` exceeds ``RANGE_SLACK`` times the fitted maximum. Returns
    ``(shares, message)``; the message is None unless a share reaches ``RANGE_SHARE``.
    ``stroke`` False: the stroke is not judged (it enters the force through a gas spring
    only; another offset or amplitude is no extrapolation for the rate-driven terms).
    """
    m = np.asarray(record.mask)
    v = np.abs(np.asarray(record.velocity, dtype=float)[m])
    x = np.asarray(record.displacement, dtype=float)[m]
    i = np.abs(np.asarray(record.i_in, dtype=float)[m])
    lo, hi = rng['displacement']
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    n = max(v.size, 1)
    shares = {
        'velocity': float(np.count_nonzero(v > RANGE_SLACK * rng['abs_velocity_p999']) / n),
        'displacement': float(np.count_nonzero(np.abs(x - centre) > RANGE_SLACK * half) / n),
        'input': float(np.count_nonzero(i > RANGE_SLACK * rng['abs_input_max']) / n)}
    what = {'velocity': f"faster than {rng['abs_velocity_p999']:.3g} m/s",
            'displacement': f'a stroke beyond {lo:.3g}..{hi:.3g} m',
            'input': f"an input above {rng['abs_input_max']:.3g} A"}
    out = [f'{100 * sh:.1f} % {what[k]}' for k, sh in shares.items()
           if sh >= RANGE_SHARE and (stroke or k != 'displacement')]
    if not out:
        return shares, None
    return shares, (f'{record.name}: outside the range the model was fitted on ('
                    + '; '.join(out) + '): the prediction extrapolates there')


def warn_outside(rng, record, params):
    """Warn (``UserWarning``) when ``record`` leaves ``rng`` for a model with ``params``.

    The stroke is judged only when the model carries a gas spring (``outside_range``).
    """
    gas = params.k_gas1 or params.k_gas2 or params.k_gas3
    msg = outside_range(rng, record, stroke=bool(gas))[1]
    if msg:
        warnings.warn(msg)


def _check_range_block(rng, path):
    try:
        vals = [rng['abs_velocity_p999'], *rng['displacement'], rng['abs_input_max']]
        ok = len(rng['displacement']) == 2 and all(math.isfinite(float(a)) for a in vals)
    except (TypeError, KeyError, ValueError):
        ok = False
    if not ok:
        raise ValueError(f'{path}: fitted_range must hold finite abs_velocity_p999, '
                         f'displacement [min, max] and abs_input_max, got {rng!r}')


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
    if 'fitted_range' in model:
        _check_range_block(model['fitted_range'], path)
    if model.get('domain') is not None:
        try:
            domain.Domain.from_dict(model['domain'])
        except (ValueError, TypeError, AttributeError) as exc:
            raise ValueError(f'{path}: domain: {exc}') from None
    if model.get('hedge') is not None:
        hedge = model['hedge']
        w = hedge.get('weight') if isinstance(hedge, dict) else None
        if not (isinstance(w, (int, float)) and 0.0 <= w <= 1.0):
            raise ValueError(f'{path}: hedge must be a model block with a weight in [0, 1], '
                             f'got {hedge!r:.80}')
        check_model({k: v for k, v in hedge.items() if k != 'weight'}, f'{path} (hedge)')
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
    """Force [N] predicted by a model dictionary on a record (same path as the fit).

    Warns (``UserWarning``), one line per kind with its time ranges, where the record leaves
    the model's fitted ``domain`` (``domain.check``); a model without one: its
    ``fitted_range``.
    """
    check_model(model)
    params = ExtendedDamperParams.from_dict(model['damper'])
    if model.get('domain'):
        for line in domain.check(record, model['domain']).lines():
            warnings.warn(f'{record.name}: outside the domain the model was fitted on: {line}')
    elif 'fitted_range' in model:
        warn_outside(model['fitted_range'], record, params)
    record = dataio.for_prediction(record)  # as Diagnosis.predict
    if model.get('driver'):
        # As in the fit: a measured coil current is cleaned by the command through the
        # fitted driver.
        record = denoise_current(record, model['driver'])
    f = engine.simulate(record, params, fitted_dynamics(model['current_dynamics']))
    hedge = model.get('hedge')
    if hedge:
        fh = engine.simulate(record, ExtendedDamperParams.from_dict(hedge['damper']),
                             fitted_dynamics(hedge['current_dynamics']))
        f = (1.0 - hedge['weight']) * f + hedge['weight'] * fh
    return f
