"""Validation records of another programme: which causes transfer, scored by cross-fitting."""

import warnings

import numpy as np
import pytest
import truthcases

from mr_suspension.identification import diagnose, report, transfer


def test_block_mse_partitions_each_half():
    rng = np.random.default_rng(3)
    errors = [rng.normal(size=1001), rng.normal(size=40)]
    sums, counts, half = transfer.block_mse(errors)
    assert counts.sum() == 1041
    assert sums.sum() == pytest.approx(sum(float(e @ e) for e in errors))
    # Each record gives its first half to blocks labelled 0, its second to blocks labelled 1.
    assert counts[half == 0].sum() == 500 + 20 and counts[half == 1].sum() == 501 + 20
    assert len(sums) == 4 * transfer.N_BLOCKS


def _stats(mses, n=100):
    counts = np.full(len(next(iter(mses.values()))), n)
    return {k: (np.asarray(v, dtype=float) * n, counts) for k, v in mses.items()}


def test_choose_needs_a_consistent_gain():
    ext = [1.0, 1.1, 0.9, 1.0, 1.2, 0.8, 1.0, 1.0]
    steady = [x - 0.2 for x in ext]  # better on every block
    lucky = [1.05, 1.15, 0.95, 1.05, 1.25, 0.85, 1.05, -2.0]  # better through one block only
    use = np.ones(8, dtype=bool)
    assert transfer.choose(_stats({'extended': ext, 'b': steady}), use) == 'b'
    assert transfer.choose(_stats({'extended': ext, 'b': lucky}), use) == 'extended'
    assert transfer.choose(_stats({'extended': ext, 'b': [x + 0.1 for x in ext]}), use) \
        == 'extended'
    # Among candidates that pay, the lowest MSE; only the blocks used count.
    better = [x - 0.3 for x in ext]
    assert transfer.choose(_stats({'extended': ext, 'b': steady, 'c': better}), use) == 'c'
    half = np.arange(8) < 4
    mixed = [x - 0.2 for x in ext[:4]] + [x + 0.5 for x in ext[4:]]
    assert transfer.choose(_stats({'extended': ext, 'b': mixed}), half) == 'b'
    assert transfer.choose(_stats({'extended': ext, 'b': mixed}), ~half) == 'extended'


@pytest.fixture(scope='module')
def loop_fit():
    """Diagnose a damper with a pre-yield loop; its other programme is kept for validation."""
    case = truthcases.case(61, ('hysteresis',), duration=8.0)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        res = diagnose.Diagnosis().fit([truthcases.record(case.columns)])
    return case, res


def test_validation_figures_agree_with_the_model_handed_on(loop_fit):
    case, res = loop_fit
    unseen = [truthcases.record(case.unseen().columns, 'unseen')]
    damper = [e for e in res.causes if e in transfer.engine.EFFECTS]
    val, _ = transfer.validate(res, unseen, damper)
    assert val.candidates[transfer.EXTENDED] == pytest.approx(val.selected_nrmse)
    assert val.candidates[transfer.BASELINE] == pytest.approx(val.baseline_nrmse)
    assert set(val.causes) | set(val.dropped) == set(damper)
    assert not set(val.causes) & set(val.dropped)
    if val.choices == (transfer.EXTENDED, transfer.EXTENDED):
        # Both halves keep the selected model: the cross-fitted figure is its own.
        assert val.extended_nrmse == pytest.approx(val.selected_nrmse)
    rep, model = report.build(res, [truthcases.record(case.columns)], unseen)
    v = rep['validation']
    assert model['effects'] == v['causes'] == list(val.causes)
    assert v['gain'] == pytest.approx(1.0 - v['extended_nrmse'] / v['baseline_nrmse'])
    # The loop is real on both programmes of this damper: it is kept and it pays there.
    assert 'hysteresis' in v['causes'] and v['gain'] > 0.0


def test_records_wholly_outside_the_domain_get_no_figures(loop_fit, monkeypatch):
    """Nothing inside the fitted domain: the report says so and keeps the diagnosis."""
    case, res = loop_fit
    unseen = [truthcases.record(case.unseen().columns, 'unseen')]

    class Outside:
        mask = np.zeros(unseen[0].n, dtype=bool)

    monkeypatch.setattr(diagnose, 'domain_lines',
                        lambda res, r: (Outside, [f'{r.name}: every sample outside']))
    val, lines = transfer.validate(res, unseen, list(res.physical_causes))
    assert val is None and lines == ('unseen: every sample outside',)
    rep, model = report.build(res, [truthcases.record(case.columns)], unseen)
    assert 'no sample' in rep['validation']['note'] and 'baseline_nrmse' not in rep['validation']
    assert model['effects'] == [e for e in res.causes if e in transfer.engine.EFFECTS]
    assert '## Validation records' in report.markdown(rep, [])
