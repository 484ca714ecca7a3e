"""Control laws as jitted step functions with one signature.

``controller_step(cid, p, s, m, dt) -> i_cmd`` with the law id ``cid``, its float64 parameter
array ``p``, its state ``s`` (updated in place) and the measurement vector ``m`` laid out as
``M_*`` below (what the controller node estimates from a car's sensors; the offline simulator
fills the same slots). The result is the coil-current command [A], clamped to ``[i_min, i_max]``
by :func:`clamp_current`.
"""

from dataclasses import asdict, dataclass

from numba import njit
import numpy as np

from mr_suspension.core.validation import check_nonneg, check_positive

# Measurement vector layout.
M_ACC_S, M_ACC_U, M_STROKE, M_STROKE_RATE, M_VEL_S, M_VEL_U, M_FIELD = range(7)
N_MEAS = 7
N_CTRL_STATE = 16

CTRL_CONSTANT = 0
CTRL_SKYHOOK_ONOFF = 1

# Parameter layout common to all laws: [i_min, i_max, law-specific...].
P_IMIN, P_IMAX = 0, 1


@dataclass(frozen=True)
class ControllerParams:
    """Control law name, current range [A] and law gains."""

    law: str = 'constant'
    i_min: float = 0.0
    i_max: float = 2.0
    current: float = 0.0

    def __post_init__(self):
        check_nonneg('ControllerParams', i_min=self.i_min, current=self.current)
        check_positive('ControllerParams', i_max=self.i_max)
        if self.i_min > self.i_max:
            raise ValueError('ControllerParams: i_min must be <= i_max')
        if self.law not in LAW_IDS:
            raise ValueError(f'ControllerParams: unknown law {self.law!r}; known {sorted(LAW_IDS)}')

    @property
    def law_id(self):
        """Integer id for the jitted dispatcher."""
        return LAW_IDS[self.law]

    def to_array(self):
        """Return ``[i_min, i_max, current]`` as float64."""
        return np.array([self.i_min, self.i_max, self.current], dtype=np.float64)

    def to_dict(self):
        """Return a plain dict."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data):
        """Build from a mapping."""
        return cls(**dict(data))


LAW_IDS = {'constant': CTRL_CONSTANT, 'skyhook_onoff': CTRL_SKYHOOK_ONOFF}


@njit(cache=True)
def clamp_current(p, i):
    """Clamp a command to ``[i_min, i_max]``; NaN gives ``i_min`` (the safe soft setting)."""
    if not i == i:
        return p[P_IMIN]
    if i < p[P_IMIN]:
        return p[P_IMIN]
    if i > p[P_IMAX]:
        return p[P_IMAX]
    return i


@njit(cache=True)
def controller_step(cid, p, s, m, dt):
    """Return the current command of law ``cid`` for measurements ``m``."""
    if cid == CTRL_SKYHOOK_ONOFF:
        # On-off skyhook (Karnopp 1974): maximum current when v_s (v_s - v_u) > 0.
        i = p[P_IMAX] if m[M_VEL_S] * m[M_STROKE_RATE] > 0.0 else p[P_IMIN]
        return clamp_current(p, i)
    return clamp_current(p, p[2])
