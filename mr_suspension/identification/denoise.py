"""A measured coil current cleaned of its white noise by the command through a fitted driver.

Used on the records of a fit (``diagnose``) and of a prediction with a fitted model
(``Diagnosis.predict``, ``model_io.predict``), so that both see the same current.
"""

from dataclasses import replace

import numpy as np

from mr_suspension.identification import engine, sensors

CURRENT_NOISE_MIN = 1e-3  # white current noise (share of its range) worth removing


def denoise_current(record, driver):
    """Measured coil current fused with the command through the fitted driver.

    The command through ``driver`` (dead time, rise/fall lags: ``engine.field_current``) is a
    second, noise-free measurement of the coil current, wrong only by the driver model's
    error; the measured current carries white noise. Their difference ``r = i_m - i_d`` holds
    both: its band is found as a motion's (``sensors.motion_band``: where its spectrum stands
    above its white level, at least ``sensors.BAND_MIN``), and ``i = i_d + LP(r)`` (zero-phase,
    4th order) keeps the model error in that band and drops the noise above it. A driver model
    that misses fast dynamics widens the band and so removes less. Returns the record with
    the fused ``i_in`` and a description in ``meta['current_source']``, or the record itself
    without a measured current, a command or a driver, or when the noise above the band is
    below ``CURRENT_NOISE_MIN`` of the current's range.
    """
    if (not driver or record.input_kind != 'current' or record.command is None
            or not np.ptp(record.command) > 0):
        return record
    i_d = engine.field_current(np.ascontiguousarray(record.command, dtype=float), record.dt,
                               driver['dead_time'], driver['tau_rise'], driver['tau_fall'])
    r = record.i_in - i_d
    cut, white = sensors.motion_band(r, record.dt)
    if not white > CURRENT_NOISE_MIN * float(np.ptp(record.i_in)):
        return record
    cut = sensors.BAND_MIN if cut is None else cut
    i_f = i_d + sensors.lowpass(r, record.dt, cut, order=4)
    source = (f'measured coil current fused with the command through the fitted driver '
              f'(difference low-passed at {cut:.3g} Hz, zero-phase; {1e3 * white:.3g} mA RMS '
              'white noise removed)')
    return replace(record, i_in=i_f, meta={**record.meta, 'current_source': source})
