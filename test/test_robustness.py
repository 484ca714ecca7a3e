"""The diagnosis does not rest on round-off: a small subset of ``benchmarks/bench_robust.py``.

Each record is diagnosed as is, with every measured channel perturbed by a relative 1e-9 (a
million times below its noise) and with one fit thread instead of two; the causes and the
verdict must be the same. The whole check (every benchmark record, and kernels compiled for
a generic CPU) is the benchmark script's.
"""

import warnings

import numpy as np
import pytest
import truthcases

from mr_suspension.identification import data as dataio
from mr_suspension.identification import diagnose


def _perturbed(columns, seed, eps=1e-9):
    rng = np.random.default_rng(seed)
    return {k: (v if k == 'time' else v * (1.0 + eps * rng.uniform(-1.0, 1.0, np.shape(v))))
            for k, v in ((k, np.asarray(v, dtype=float)) for k, v in columns.items())}


def _outcome(columns, jobs, monkeypatch):
    monkeypatch.setattr(diagnose, 'JOBS', jobs)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        res = diagnose.Diagnosis().fit([dataio.build_record('robust', columns)])
    return res.causes, res.verdict, res.heldout['extended_nrmse']


@pytest.mark.parametrize('n, effects', [
    (40001, ('hysteresis',)),
    pytest.param(40002, ('current_lag', 'series_stiffness'), marks=pytest.mark.slow)])
def test_causes_and_verdict_survive_round_off_and_the_thread_count(n, effects, monkeypatch):
    case = truthcases.case(n, effects, sensor_faults=None, duration=6.0,
                           measured_current=None)
    causes, verdict, nrmse = _outcome(case.columns, 2, monkeypatch)
    assert causes, 'the truth carries an effect: the check must be of a real selection'
    for cols, jobs in ((_perturbed(case.columns, n), 2), (case.columns, 1)):
        c, v, e = _outcome(cols, jobs, monkeypatch)
        assert (c, v) == (causes, verdict)
        assert e == pytest.approx(nrmse, rel=1e-4)
