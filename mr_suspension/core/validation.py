"""Validation helpers and the common mixin of the frozen parameter dataclasses."""

from dataclasses import asdict, field, fields
import math

import numpy as np


def check_finite(owner, **values):
    """Raise ValueError naming ``owner`` and the field if any value is not a finite number."""
    for name, value in values.items():
        try:
            ok = math.isfinite(float(value))
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise ValueError(f'{owner}: {name} must be a finite number, got {value!r}')


def check_positive(owner, **values):
    """Raise ValueError unless every value is finite and > 0."""
    check_finite(owner, **values)
    for name, value in values.items():
        if value <= 0.0:
            raise ValueError(f'{owner}: {name} must be > 0, got {value!r}')


def check_nonneg(owner, **values):
    """Raise ValueError unless every value is finite and >= 0."""
    check_finite(owner, **values)
    for name, value in values.items():
        if value < 0.0:
            raise ValueError(f'{owner}: {name} must be >= 0, got {value!r}')


def as_number(owner, name, value):
    """Return ``value`` as a finite float; a string, list, bool or NaN raises ValueError."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number)):
        raise ValueError(f'{owner}: {name} must be a number, got {value!r}; write a plain '
                         'number such as 0.5')
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f'{owner}: {name} must be a finite number, got {value!r}')
    return v


def check_range(owner, name, value, lo, hi, unit='', hint='', off=None):
    """Raise ValueError unless ``value`` is a finite number in ``[lo, hi]`` (or equals ``off``).

    The one-line message names the parameter, the value, what it means (``hint``) and the range
    to use instead. ``off`` is an extra allowed value that switches an effect off (e.g. 0).
    """
    v = as_number(owner, name, value)
    if (off is not None and v == off) or lo <= v <= hi:
        return v
    u = f' {unit}' if unit else ''
    what = f' ({hint})' if hint else ''
    alt = f', or {off:g} for off' if off is not None else ''
    raise ValueError(f'{owner}: {name} = {v:g}{u}{what} is not plausible; use a value from '
                     f'{lo:g} to {hi:g}{u}{alt}')


def param(default, lo, hi, unit='', hint='', off=None, required=True):
    """Dataclass field with its plausible range ``[lo, hi]`` (see :func:`check_declared`).

    ``required``: a parameter file must give it (no silent default); ``off``: an extra allowed
    value meaning the effect is off.
    """
    return field(default=default, metadata={'range': (lo, hi, unit, hint, off),
                                            'required': required})


def check_declared(obj):
    """Check every field of dataclass ``obj`` against the range declared with :func:`param`."""
    owner = type(obj).__name__
    for f in fields(obj):
        rng = f.metadata.get('range')
        if rng is not None:
            lo, hi, unit, hint, off = rng
            check_range(owner, f.name, getattr(obj, f.name), lo, hi, unit, hint, off)


def required_keys(cls):
    """Names of the fields of ``cls`` that a parameter file must give."""
    return [f.name for f in fields(cls) if f.metadata.get('required', False)]


def build(cls, data, owner=None, source=None):
    """Build a dataclass from a mapping, rejecting unknown keys with a clear ValueError.

    ``source`` (the file the mapping came from): every required key must be present, so a
    parameter file with a missing key is an error naming the key and the file, never a default.
    """
    owner = owner or cls.__name__
    if not isinstance(data, dict):
        raise ValueError(f'{owner}: expected a mapping of parameters, got {type(data).__name__}')
    names = cls.__dataclass_fields__
    unknown = sorted(set(data) - set(names))
    if unknown:
        raise ValueError(f'{owner}: unknown parameter(s) {unknown}; known: {sorted(names)}')
    if source is not None:
        missing = [k for k in required_keys(cls) if k not in data]
        if missing:
            raise ValueError(f'{source}: missing required key(s) {", ".join(missing)} of '
                             f'{owner}; add them to the file')
    return cls(**data)


class ParamsMixin:
    """Array conversion and dict round trip for the frozen parameter dataclasses."""

    def to_array(self):
        """Return the parameters as a float64 array in field order (the jitted ``p``)."""
        return np.array([float(getattr(self, f.name)) for f in fields(self)], dtype=np.float64)

    def to_dict(self):
        """Return the parameters as a plain dict (YAML/JSON friendly)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data, source=None):
        """Build from a mapping; unknown keys (and, with ``source``, missing ones) raise."""
        if not isinstance(data, dict):
            raise ValueError(f'{source or cls.__name__}: expected a mapping of parameters, got '
                             f'{type(data).__name__}')
        return build(cls, dict(data), source=source)
