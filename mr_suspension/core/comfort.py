"""ISO 2631-1 ride comfort of a full car: Wk heave at a body point, We pitch and roll.

The We weighting (rotational vibration of a seated person: roll, pitch, yaw) is the product
of the ISO 2631-1:1997 Annex A filters (Table A.2; the same parameters as ISO 8041-1:2017
Table 3): band limiting (0.4 Hz high-pass, 100 Hz low-pass, Q = 1/sqrt 2) and
acceleration-velocity transition (f3 = f4 = 1 Hz, Q4 = 0.63), no upward step.

Comfort of a seated person (ISO 2631-1:1997, 8.2.2 / Table 1, seat surface) combines the
weighted r.m.s. values with the multiplying factors k_z = 1 (Wk, vertical), k_rx = 0.63 m/rad
(roll), k_ry = 0.40 m/rad (pitch), k_rz = 0.20 m/rad (yaw) (all We) into the point vibration
total value ``a_v = sqrt(sum (k_j a_wj)^2)`` (Eq. (10) form).

Sources (checked by search): We parameters, ISO 8041 Table 3 as reprinted in the Larson
Davis HVM200 manual, Table 3.1 (manualshive.com/en/manual/larson-davis/hvm200/3698114?page=33)
and in github.com/jmrplens/phonometry src/phonometry/vibration/human/exposure.py; tabulated
factors, ISO 8041-1:2017 Table B.4 (We = 0.1263 at 7.943 Hz, phonometry reference data) and a
transcription of ISO 2631-1:1997 Table 4; k factors, ISO 2631-1 Table 1 / 8.2.2 as tabulated
in jmrplens/phonometry docs/vibration/human/human-vibration.md ("Which weighting on which
axis").
"""

from dataclasses import asdict, dataclass
import math

import numpy as np
from scipy import signal

from mr_suspension.core.metrics import rms, vdv, wk_filter

WE_F1, WE_F2, WE_F3, WE_F4, WE_Q4 = 0.4, 100.0, 1.0, 1.0, 0.63
K_Z = 1.0                                  # vertical, Wk [-]
K_RX, K_RY, K_RZ = 0.63, 0.40, 0.20        # roll, pitch, yaw, We [m/rad]


def iso_weighting_analog(f1, f2, f3, f4, q4, f5=math.inf, q5=1.0, f6=math.inf, q6=1.0):
    """Return an ISO 2631-1 Annex A weighting as (numerator, denominator) polynomials in s.

    ``H = H_h H_l H_t H_s`` with ``w_i = 2 pi f_i``, ``Q1 = Q2 = 1/sqrt 2``:
    high-pass ``s^2 / (s^2 + w1 s/Q1 + w1^2)``, low-pass ``w2^2 / (s^2 + w2 s/Q2 + w2^2)``,
    a-v transition ``(1 + s/w3) / (1 + s/(Q4 w4) + s^2/w4^2)`` and upward step
    ``(s^2 + w5 s/Q5 + w5^2) / (s^2 + w6 s/Q6 + w6^2)``. An infinite ``f3`` (``f4``)
    drops the transition zero (poles), an infinite ``f5`` or ``f6`` the step (Table A.2).
    """
    w1, w2 = 2 * math.pi * f1, 2 * math.pi * f2
    q1 = 1.0 / math.sqrt(2.0)
    num = np.polymul([1.0, 0.0, 0.0], [w2 ** 2])                      # high-pass x low-pass
    den = np.polymul([1.0, w1 / q1, w1 ** 2], [1.0, w2 / q1, w2 ** 2])
    if not math.isinf(f3):                                             # a-v transition
        num = np.polymul(num, [1.0 / (2 * math.pi * f3), 1.0])
    if not math.isinf(f4):
        w4 = 2 * math.pi * f4
        den = np.polymul(den, [1.0 / w4 ** 2, 1.0 / (q4 * w4), 1.0])
    if not (math.isinf(f5) or math.isinf(f6)):                         # upward step
        w5, w6 = 2 * math.pi * f5, 2 * math.pi * f6
        num = np.polymul(num, [1.0, w5 / q5, w5 ** 2])
        den = np.polymul(den, [1.0, w6 / q6, w6 ** 2])
    return num, den


def analog_sos(num, den, dt):
    """Second-order sections of the analogue filter ``num/den`` by the bilinear transform."""
    z, p, k = signal.tf2zpk(num, den)
    zd, pd, kd = signal.bilinear_zpk(z, p, k, 1.0 / dt)
    return signal.zpk2sos(zd, pd, kd)


def we_analog():
    """Return the analogue We weighting as (numerator, denominator) polynomials in s."""
    return iso_weighting_analog(WE_F1, WE_F2, WE_F3, WE_F4, WE_Q4)


def we_gain(freq):
    """Magnitude of the analogue We weighting at ``freq`` [Hz] (0.880 at 1 Hz)."""
    num, den = we_analog()
    _, h = signal.freqs(num, den, worN=2 * np.pi * np.asarray(freq, dtype=float))
    return np.abs(h)


def we_sos(dt):
    """Second-order sections of the We weighting discretised by the bilinear transform."""
    return analog_sos(*we_analog(), dt)


def we_filter(acc, dt):
    """We-weighted angular acceleration [rad/s^2] (causal filter, like a rate-gyro chain)."""
    return signal.sosfilt(we_sos(dt), np.asarray(acc, dtype=float))


def point_acceleration(a_z, pitch_acc, roll_acc, x, y):
    """Vertical acceleration of the body point (x forward, y left of the CG) [m/s^2].

    ``a = a_z - x theta'' + y phi''`` for small angles in ISO 8855 axes (z up; pitch theta
    positive nose down, roll phi positive left side up, both by the right-hand rule).
    """
    return (np.asarray(a_z, dtype=float) - x * np.asarray(pitch_acc, dtype=float)
            + y * np.asarray(roll_acc, dtype=float))


@dataclass(frozen=True)
class Comfort:
    """ISO 2631-1 comfort figures at one body point (SI units).

    ``heave_wk_rms`` [m/s^2] Wk-weighted vertical r.m.s. at the point, ``pitch_we_rms`` and
    ``roll_we_rms`` [rad/s^2] We-weighted r.m.s., ``total`` [m/s^2] the point vibration
    total value ``sqrt((k_z a_wz)^2 + (k_ry a_wpitch)^2 + (k_rx a_wroll)^2)`` and ``vdv_z``
    [m/s^1.75] the vibration dose value of the Wk-weighted vertical acceleration.
    """

    heave_wk_rms: float
    pitch_we_rms: float
    roll_we_rms: float
    total: float
    vdv_z: float

    def to_dict(self):
        """Return the figures as a plain ``dict`` of floats."""
        return asdict(self)


def _signal(name, value):
    arr = np.asarray(value, dtype=float)
    if arr.ndim != 1:
        raise ValueError(f'{name} must be a 1-D array, got shape {arr.shape}')
    if not np.all(np.isfinite(arr)):
        raise ValueError(f'{name} contains non-finite samples')
    return arr


def comfort(a_z, pitch_acc, roll_acc, dt, x=0.0, y=0.0, *, t_start=0.0):
    """ISO 2631-1 comfort at the body point (x, y) of the CG [m] (0, 0: at the CG).

    ``a_z`` [m/s^2] is the CG vertical acceleration, ``pitch_acc`` and ``roll_acc``
    [rad/s^2] the body angular accelerations (ISO 8855 signs, see
    :func:`point_acceleration`), sampled every ``dt`` [s]. The whole record is filtered;
    samples before ``t_start`` [s] (the weighting filters' start transient) are left out of
    the r.m.s. and VDV. A driver's seat position gives the seat figure (seat dynamics aside).
    """
    a_z = _signal('a_z', a_z)
    pitch_acc = _signal('pitch_acc', pitch_acc)
    roll_acc = _signal('roll_acc', roll_acc)
    if not a_z.size == pitch_acc.size == roll_acc.size:
        raise ValueError(f'a_z, pitch_acc and roll_acc differ in length '
                         f'({a_z.size}, {pitch_acc.size}, {roll_acc.size})')
    dt = float(dt)
    if not (math.isfinite(dt) and dt > 0.0):
        raise ValueError(f'dt must be finite and > 0, got {dt}')
    x, y, t_start = float(x), float(y), float(t_start)
    if not (math.isfinite(x) and math.isfinite(y)):
        raise ValueError(f'the point (x, y) = ({x}, {y}) must be finite')
    if not (math.isfinite(t_start) and t_start >= 0.0):
        raise ValueError(f't_start must be finite and >= 0, got {t_start}')
    start = int(math.ceil(t_start / dt - 1e-9))
    if a_z.size - start < 2:
        raise ValueError(f'need at least 2 samples after t_start, got {a_z.size - start}')
    heave = wk_filter(point_acceleration(a_z, pitch_acc, roll_acc, x, y), dt)[start:]
    pitch = we_filter(pitch_acc, dt)[start:]
    roll = we_filter(roll_acc, dt)[start:]
    a_wz, a_wp, a_wr = rms(heave), rms(pitch), rms(roll)
    total = math.sqrt((K_Z * a_wz) ** 2 + (K_RY * a_wp) ** 2 + (K_RX * a_wr) ** 2)
    return Comfort(heave_wk_rms=a_wz, pitch_we_rms=a_wp, roll_we_rms=a_wr, total=total,
                   vdv_z=vdv(heave, dt))
