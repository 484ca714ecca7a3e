"""Real rig data (vrths): diagnose the sine tests, validate on the earthquake record.

Pinned from the measured figures in docs/diagnose.md (the CI subset: the 1, 3 and 5 Hz sine
tests at all five currents, 15 records): verdict ``named``, first cause
``series_stiffness`` with k1 of a few MN/m, held-out gain about 50 %, earthquake validation
gain about 29 %. The thresholds sit slightly below the measured values.
"""

from pathlib import Path

from mr_suspension.identification import data as dataio
from mr_suspension.identification import diagnose, report

SHARED = Path(__file__).resolve().parents[1].parent / 'shared'
SINE = SHARED / 'data' / 'vrths' / 'preprocessed_sine'
QUAKE = SHARED / 'data' / 'vrths' / 'validation' / 'validacion.mat'


def test_vrths_verdict_and_gain():
    prefixes = ('10mm1Hz', '5mm3Hz', '2mm5Hz')
    files = sorted(p for p in SINE.iterdir() if p.name.startswith(prefixes))
    assert len(files) == 15
    records = dataio.load_records(files)
    quake = dataio.load_records([QUAKE])
    res = diagnose.run(records)
    rep, model = report.build(res, records, quake)
    assert rep['verdict'] == 'named'
    assert rep['causes'][0]['effect'] == 'series_stiffness'
    assert 1.5e6 < rep['causes'][0]['parameters']['k_series'] < 2e7
    assert {'current_delay', 'current_lag', 'current_lag_asymmetric'} <= set(rep['untestable'])
    assert rep['gain'] >= 0.40
    assert rep['validation']['gain'] >= 0.20
    assert rep['validation']['extended_nrmse'] < rep['validation']['baseline_nrmse']
