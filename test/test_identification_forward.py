"""Forward validation: what is kept back, its figures, and a run whose damper drifts."""

import numpy as np
import pytest
import truthcases

from mr_suspension.identification import data as dataio
from mr_suspension.identification import diagnose, forward


def _sine_record(name, seconds, amp=0.01, freq=2.0, current=1.0, dt=1e-3):
    t = np.arange(int(seconds / dt)) * dt
    x = amp * np.sin(2 * np.pi * freq * t)
    v = amp * 2 * np.pi * freq * np.cos(2 * np.pi * freq * t)
    f = 2000.0 * v + 400.0 * current * np.tanh(v / 0.02)
    return truthcases.record({'time': t, 'displacement': x, 'velocity': v, 'force': f,
                              'current': np.full(t.size, current)}, name=name)


def test_a_long_record_keeps_back_its_final_fifth():
    """Records of at least FORWARD_MIN_S keep back their end; shorter ones are fitted whole."""
    long = _sine_record('long', forward.FORWARD_MIN_S + 10)
    short = _sine_record('short', 0.5 * forward.FORWARD_MIN_S)
    sp = forward.split([long, short], dataio.window)
    assert [r.name for r in sp.train] == ['long', 'short']
    assert sp.train[0].n + (sp.held[0][0].n - sp.held[0][1]) == long.n
    assert sp.held[0][1] == int(round(long.n * (1 - forward.FORWARD_SHARE)))
    assert sp.seconds == pytest.approx(forward.FORWARD_SHARE * long.duration, rel=1e-3)
    assert forward.split([short], dataio.window).held == ()


def test_a_set_keeps_back_whole_records_inside_the_rest():
    """A set of records keeps back a fifth of them; none outside the others' speed or current.

    A programme of five currents per test: every fifth record would be the highest current
    of each test; kept back are records whose current the rest still covers.
    """
    recs = [_sine_record(f'{a}-{c}', 4.0, amp=a, current=c)
            for a in (0.005, 0.01, 0.02) for c in (0.0, 0.25, 0.5, 0.75, 1.0)]
    sp = forward.split(recs, dataio.window)
    assert len(sp.held) == 3 and len(sp.train) == 12
    assert all(k == 0 for _, k in sp.held)
    cur = [float(np.max(r.i_in)) for r in sp.train]
    amp = [float(np.max(r.displacement)) for r in sp.train]
    for r, _ in sp.held:
        assert np.max(r.i_in) <= max(cur) and np.max(r.displacement) <= 1.05 * max(amp)
    assert sp == forward.split(recs, dataio.window)  # the same choice every time
    # The record with the only top current (and the only stroke) is never kept back.
    top = recs[:-1] + [_sine_record('top', 4.0, amp=0.05, current=2.0)]
    assert 'top' not in [r.name for r, _ in forward.split(top, dataio.window).held]


def test_block_score_and_compare():
    """Score and uncertainty from blocks; figures apart by more than it: the pessimistic one."""
    rng = np.random.default_rng(5)
    f = [rng.normal(0, 100.0, 1000) for _ in range(6)]
    e = [rng.normal(0, 10.0, 1000) for _ in range(6)]
    small = forward.block_score(e, f)
    big = forward.block_score([rng.normal(0, 20.0, 1000) for _ in range(6)], f)
    same = forward.block_score([1.01 * x for x in e[::-1]], f)
    assert small.nrmse == pytest.approx(0.1, rel=0.05)
    assert 0 < small.se < 0.01
    assert forward.compare(small, big) == 'forward'
    assert forward.compare(big, small) == 'outer'
    assert forward.compare(small, same) == 'pooled'
    assert forward.compare(None, small) == 'forward'
    assert forward.block_score([], []) is None


def test_drift_names_the_channel_that_follows_it():
    """A force scale that follows the temperature (not monotone in time) is put on it."""
    t = np.arange(60000) * 1e-3
    temp = 40 + 10 * np.sin(2 * np.pi * t / 60.0) ** 2 + 0.1 * t
    fh = 1000 * np.sin(2 * np.pi * 2 * t)
    f = fh * (1 + 0.01 * (temp - 40))
    d = forward.drift([(t, f, fh, np.ones(t.size, dtype=bool), temp)])
    assert d['channel'] == 'temperature'
    assert d['scale_change'] == pytest.approx(0.01 * (temp.max() - temp.min()), rel=0.25)
    flat = forward.drift([(t, fh, fh, np.ones(t.size, dtype=bool), None)])
    assert flat['scale_change'] < 1e-9 and flat['channel'] is None


def test_a_damper_that_stiffens_over_the_run_is_reported_on_its_kept_back_end(monkeypatch):
    """Truth force scaled up along the run (no catalogue effect does that): see its end.

    The outer blocks interleave with the fitted ones and average the change away; the end of
    the run, kept back, is predicted clearly worse, and the report says so and by how much.
    (A 15 s record, records of 14 s on keeping back their end: the rule, not the length.)
    """
    monkeypatch.setattr(forward, 'FORWARD_MIN_S', 14.0)
    case = truthcases.case(31, (), duration=15.0)
    cols = dict(case.columns)
    t = cols['time']
    cols['force'] = cols['force'] * (1.0 + 0.3 * (t / t[-1]) ** 2)
    res = diagnose.Diagnosis().fit([truthcases.record(cols)])
    ho = res.heldout
    assert ho['headline'] == 'forward' and ho['source'].startswith('kept-back')
    assert ho['forward']['extended_nrmse'] > ho['outer_blocks']['extended_nrmse']
    assert ho['forward_over_blocks'] > 1.2
    assert ho['drift']['scale_change'] > 0.05
    assert ho['drift']['channel'] == 'time'


def test_keep_back_off_scores_the_outer_blocks_only():
    """``keep_back=False``: everything is fitted, the figures come from the outer blocks."""
    rec = _sine_record('long', forward.FORWARD_MIN_S + 5)
    on = diagnose.Diagnosis(effects=()).fit([rec]).heldout
    off = diagnose.Diagnosis(effects=(), keep_back=False).fit([rec]).heldout
    assert 'forward' in on and on['headline'] in ('outer', 'forward', 'pooled')
    assert 'forward' not in off and off['source'] == 'outer blocks'
