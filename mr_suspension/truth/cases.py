"""Ready-made benchmark cases: a drawn damper on a drawn rig, measured by drawn sensors.

``make_case(seed, ...)`` draws, from independent streams of ``seed``: the truth
(``rig.draw_truth``) and the sensor spec (``sensors.draw_sensor``), which belong to the damper
and the rig, and, per ``record`` index, the programme and the noise. ``record=1, 2, ...`` (or
``Case.unseen()``) is therefore the same damper on the same rig under another programme and
noise: an unseen record for validation. Every record starts with a cold damper.
"""

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from mr_suspension.truth import rig, sensors
from mr_suspension.truth.redraw import Redrawable

COLUMN_ORDER = ('time', 'displacement', 'velocity', 'force', 'current_command', 'current')


@dataclass(frozen=True, eq=False)
class Case(Redrawable):
    """One synthetic rig record with its truth.

    ``columns`` (package column names, SI, rows as written), ``truth`` (``rig.RigTruth``),
    ``clean_force`` (noise-free force at the kept rows), ``reference_force`` (the same through
    the force channel's delay or filter), ``sensor`` (``{'spec': SensorSpec, 'info': dict}``),
    ``floor_nrmse``, ``noise_rms`` [N], ``contributions`` (per effect, RMS of its force
    contribution / ``noise_rms``), ``contributions_n`` (the same in N),
    ``driver_contribution`` (ideal vs real driver, / ``noise_rms``), ``clean`` (every
    ``rig.simulate`` output at all samples), ``args`` (to regenerate).
    """

    seed: int
    record: int
    columns: dict
    truth: rig.RigTruth
    clean_force: np.ndarray
    reference_force: np.ndarray
    sensor: dict
    floor_nrmse: float
    noise_rms: float
    contributions: dict
    contributions_n: dict
    driver_contribution: float
    clean: dict = field(repr=False)
    args: dict = field(repr=False)

    @property
    def effects(self):
        """Effects present in the truth."""
        return self.truth.effects

    def write_csv(self, path):
        """Write the columns as a CSV with a header (``nan`` for dropouts); return the path."""
        path = Path(path)
        names = [c for c in COLUMN_ORDER if c in self.columns]
        table = np.column_stack([self.columns[c] for c in names])
        np.savetxt(path, table, delimiter=',', header=','.join(names), comments='',
                   fmt='%.10g')
        return path


def _rng(seed, *tags):
    return np.random.default_rng([int(seed), *tags])


def make_case(seed, effects=(), sensor_faults=(), duration=20.0, rate=1000.0, kind='full',
              shape=None, strength=None, measured_current=None, record=0, sensor_clean=False,
              substeps=10, i_max=1.0, driver_tau=None, current_site='field', input_noise=True):
    """Draw a case (see the module docstring); ``sensor_faults=None`` draws 0-3 faults.

    ``effects`` and ``shape``/``strength``/``driver_tau``/``current_site`` go to
    ``rig.draw_truth``; ``kind``, ``duration`` [s], ``rate`` [Hz] to ``rig.programme``;
    ``sensor_faults``, ``sensor_clean`` and ``measured_current`` (None = random) to
    ``sensors.draw_sensor``. ``input_noise=False`` keeps the drawn spec, faults and force noise
    but measures displacement, velocity and current without noise (the same draws otherwise):
    what a model could reach with perfect motion and current sensors.
    """
    if int(seed) != seed or seed < 0:
        raise ValueError(f'make_case: seed must be a non-negative integer, got {seed}')
    if int(record) != record or record < 0:
        raise ValueError(f'make_case: record must be a non-negative integer, got {record}')
    args = {'seed': int(seed), 'effects': tuple(effects),
            'sensor_faults': None if sensor_faults is None else tuple(sensor_faults),
            'duration': duration, 'rate': rate, 'kind': kind, 'shape': shape,
            'strength': strength, 'measured_current': measured_current, 'record': int(record),
            'sensor_clean': sensor_clean, 'substeps': substeps, 'i_max': i_max,
            'driver_tau': driver_tau, 'current_site': current_site, 'input_noise': input_noise}
    truth = rig.draw_truth(_rng(seed, 1), effects, shape=shape, strength=strength, i_max=i_max,
                           driver_tau=driver_tau, current_site=current_site)
    spec = sensors.draw_sensor(_rng(seed, 2), faults=sensor_faults, clean=sensor_clean,
                               rate=rate, measured_current=measured_current)
    if not input_noise:
        spec = replace(spec, displacement_noise=0.0, velocity_noise=0.0, current_noise=0.0)
    t, x, i_cmd = rig.programme(_rng(seed, 3, record), duration, rate, kind, i_max=i_max)
    clean = rig.simulate(truth, t, x, i_cmd, substeps)
    cols, info = sensors.apply(_rng(seed, 4, record), t, clean, spec)
    contrib = rig.contributions(truth, t, x, i_cmd, substeps, base=clean)
    drv = rig.driver_contribution(truth, t, x, i_cmd, substeps, base=clean)
    nr = info['noise_rms']
    scale = nr if nr > 0 else float('nan')
    rows = info['rows']
    return Case(seed=int(seed), record=int(record), columns=cols, truth=truth,
                clean_force=clean['force'][rows], reference_force=info['reference_force'],
                sensor={'spec': spec, 'info': info}, floor_nrmse=info['floor_nrmse'],
                noise_rms=nr, contributions={k: v / scale for k, v in contrib.items()},
                contributions_n=contrib, driver_contribution=drv / scale, clean=clean,
                args=args)


def _noise(case):
    """Force noise (measured - delayed/filtered clean) and force std over the valid rows."""
    info = case.sensor['info']
    valid = np.asarray(info['valid'], dtype=bool)
    force = np.asarray(case.columns['force'], dtype=float)
    return (force - info['reference_force'])[valid], float(np.std(force[valid]))


def transfer_floor(train, unseen):
    """NRMSE that a perfect model fitted on ``train`` reaches on ``unseen`` (same damper).

    ``unseen.floor_nrmse`` is the noise about the unseen record's own mean, but a fitted model
    carries the training record's mean noise (offset plus the mean of its drift) in its static
    force ``f0``; a drifting force channel shifts that mean from record to record, and no
    model can know the shift. So: RMS of ``e_unseen - mean(e_train)`` over the unseen valid
    rows, over the unseen force std. Equal to ``unseen.floor_nrmse`` without drift.
    """
    e_t, _ = _noise(train)
    e_u, s_u = _noise(unseen)
    if not (e_t.size and e_u.size and s_u > 0):
        return float('nan')
    return float(np.sqrt(np.mean((e_u - np.mean(e_t)) ** 2)) / s_u)


Case.make = make_case  # what ``unseen`` draws again
