"""Validation helpers and the common mixin of the frozen parameter dataclasses."""

from dataclasses import asdict, fields
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


def build(cls, data, owner=None):
    """Build a dataclass from a mapping, rejecting unknown keys with a clear ValueError."""
    owner = owner or cls.__name__
    if not isinstance(data, dict):
        raise ValueError(f'{owner}: expected a mapping of parameters, got {type(data).__name__}')
    fields = cls.__dataclass_fields__
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ValueError(f'{owner}: unknown parameter(s) {unknown}; known: {sorted(fields)}')
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
    def from_dict(cls, data):
        """Build from a mapping; unknown keys raise ValueError."""
        return build(cls, dict(data))
