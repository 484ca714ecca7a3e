"""Evidence beside the physics: the learned reference and the fitted domain, in a diagnosis."""

from dataclasses import replace
import warnings

import numpy as np
import pytest
import truthcases

from mr_suspension.identification import diagnose, report


def _fit(columns, **kwargs):
    est = diagnose.Diagnosis(**kwargs)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        res = est.fit([truthcases.record(columns)])
    return est, res


@pytest.fixture(scope='module')
def loop_damper():
    """Diagnose a damper with a pre-yield loop: the catalogue holds its cause."""
    case = truthcases.case(41, ('hysteresis',), duration=8.0)
    est, res = _fit(case.columns)
    return case, est, res


def test_the_reference_does_not_beat_a_model_at_its_floor(loop_damper):
    """The cause is in the catalogue and named: the reference has nothing left to learn."""
    case, _, res = loop_damper
    assert 'hysteresis' in res.physical_causes
    rc = res.reference
    assert rc is not None and not rc.beats
    assert rc.gain < diagnose.REF_GAIN
    assert res.verdict == 'named'


def test_the_reference_catches_a_force_outside_the_catalogue():
    """Fluid inertia (a force m a, no catalogue effect has it) at ~10x the noise.

    The physics cannot draw it; the trees, which see the velocity's recent history, can:
    the verdict is ``partly_explained`` and the report says the reference predicts it.
    """
    case = truthcases.case(42, (), duration=8.0)
    cols = dict(case.columns)
    t, v = cols['time'], cols['velocity']
    acc = np.gradient(v, t)
    noise = case.floor_nrmse * np.std(cols['force'])  # the truth's force noise RMS [N]
    scale = 10.0 * noise / np.std(acc)
    cols['force'] = cols['force'] + scale * acc
    _, res = _fit(cols)
    rc = res.reference
    assert rc.beats, (rc.gain, rc.t)
    assert res.verdict == 'partly_explained'
    rep, _ = report.build(res, [truthcases.record(cols)])
    assert rep['reference']['beats_extended'] is True
    assert 'learned reference' in rep['unexplained']


def test_predict_warns_and_score_leaves_out_what_the_fit_never_saw(loop_damper):
    """A stroke beyond the fitted one: warned once with its time range, left out of score."""
    case, est, res = loop_damper
    rec = truthcases.record(case.unseen().columns, 'unseen')
    x = rec.displacement.copy()
    late = rec.time > rec.time[-1] - 2.0
    x[late] = x[late] * 3.0
    far = replace(rec, displacement=x)
    with pytest.warns(UserWarning, match='outside the domain the model was fitted on: '
                                         'displacement'):
        est.predict(far)
    chk = est.check(far)
    assert 'displacement' in chk.kinds()
    assert not chk.mask[late].all() and chk.mask[~late].mean() > 0.9
    # score on the flagged record = score on its samples inside the domain
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        f = est.predict(far)
        s = est.score(far)
    m = rec.mask & chk.mask
    want = np.sqrt(np.mean((far.force[m] - f[m]) ** 2)) / np.std(far.force[m])
    assert s == pytest.approx(want, rel=1e-12)


def test_validation_leaves_out_and_lists_the_stretches_outside_the_domain(loop_damper):
    """``--validate`` figures skip clipped samples and list them, one line per kind."""
    case, _, res = loop_damper
    rec = truthcases.record(case.unseen().columns, 'unseen')
    top = np.percentile(rec.force, 97)
    clipped = replace(rec, force=np.minimum(rec.force, top))
    rep, _ = report.build(res, [truthcases.record(case.columns)], [clipped])
    v = rep['validation']
    assert any('clipping' in line for line in v['domain'])
    assert 0.0 < v['excluded_share'] < 0.2
    clean, _ = report.build(res, [truthcases.record(case.columns)], [rec])
    assert not any('clipping' in line for line in clean['validation']['domain'])
    assert clean['validation']['excluded_share'] < 0.02
