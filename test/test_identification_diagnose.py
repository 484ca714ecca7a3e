"""Hidden-effect tests: diagnose must name the effect, its parameters and a held-out gain.

The truths come from the independent rig (``mr_suspension.truth``: its own integrator and
sensors, drawn by ``truthcases``): one drawn damper with the fit's own tanh baseline (an
algebraic yield for the yield shape) and one effect at a time, an ideal driver, the truth's
realistic force noise and no sensor fault; motion and command are measured without noise,
so the force noise is the floor a perfect model reaches. A parameter is compared with the
truth's where the fit has the same one, else with the truth's closed form (the polytropic
gas spring, the exponential magnetisation curve).
"""

import numpy as np
import pytest
import truthcases

from mr_suspension.identification import diagnose, engine, report, synthetic

DURATION = 12.0
DAMPER = 30001  # one drawn damper; each test switches on its own effects
STRENGTH = {'gas_spring': 0.9, 'thermal_fade': 0.9}  # else 0.7: all 4-30x the noise here
ABS_TOL = {'dead_time': 0.002, 'tau_rise': 0.003, 'rho': 0.03, 'hyst_weight': 0.05}
REL_TOL = {'tau': 0.15, 'tau_fall': 0.2, 'x_h': 0.25, 'k_series': 0.3, 'yield_n': 0.25}


def _case(effects, kind='full', duration=DURATION):
    shape = 'algebraic' if 'yield_shape' in effects else 'bingham_tanh'
    effects = tuple(e for e in effects if e != 'yield_shape')
    return truthcases.case(DAMPER, effects, shape=shape,
                           strength={e: STRENGTH.get(e, 0.7) for e in effects},
                           sensor_faults=(), duration=duration, kind=kind,
                           measured_current=False, driver_tau=0.0, input_noise=False)


def _diagnose(case):
    rec = truthcases.record(case.columns)
    res = diagnose.run([rec])
    rep, model = report.build(res, [rec])
    return rec, res, rep, model


def _gas_curve_miss(truth, x, got):
    """Largest miss of the fitted gas force over the stroke, as a share of the truth's span."""
    ref = -truth.gas_p0 * truth.gas_area * (
        (truth.gas_volume / (truth.gas_volume + truth.gas_area * x)) ** truth.gas_n - 1.0)
    fit = got['k_gas1'] * x + got['k_gas2'] * x ** 2 + got.get('k_gas3', 0.0) * x ** 3
    return np.max(np.abs(fit - fit.mean() - ref + ref.mean())) / np.ptp(ref)


def _field_curve_miss(truth, got):
    """Largest miss of the fitted magnetisation curve's shape (at 1 A: 1) over 0-1 A."""
    i = np.linspace(0.0, 1.0, 101)
    ref = truth.i_sat * (1.0 - np.exp(-i / truth.i_sat))
    i_s, m = got['i_sat'], got.get('sat_n', 0.0)
    fit = i_s * np.tanh(i / i_s) if m == 0 else i / (1.0 + (i / i_s) ** m) ** (1.0 / m)
    return np.max(np.abs(fit / fit[-1] - ref / ref[-1]))


def _truth_parameters(effect, truth):
    """Return the fitted parameters the truth sets directly, by the fit's names."""
    return {'current_delay': {'dead_time': truth.dead_time},
            'current_lag': {'tau': truth.tau_rise},
            'current_lag_asymmetric': {'tau_rise': truth.tau_rise, 'tau_fall': truth.tau_fall},
            'hysteresis': {'x_h': truth.x_h, 'hyst_weight': truth.hyst_weight},
            'series_stiffness': {'k_series': truth.k_series},
            'direction_asymmetry': {'rho': truth.rho},
            'yield_shape': {'yield_n': 2.0},  # the truth's w / sqrt(1 + w^2)
            }.get(effect, {})


# Findings on the independent truth, kept as strict expected failures (each turns into a
# failure once the code meets the expectation, so the mark must then go).
SPRING_TIMING = pytest.mark.xfail(strict=True, reason=(
    'finding: a series spring alone is named with a sub-millisecond current lag or a force '
    'channel low-pass beside it (4 of the 5 drawn dampers tried, this one among them)'))


@pytest.mark.parametrize('effect', [pytest.param(e, marks=SPRING_TIMING)
                                    if e == 'series_stiffness' else e
                                    for e in engine.EFFECTS])
def test_single_hidden_effect_is_named_with_parameters(effect):
    case = _case((effect,))
    rec, res, rep, model = _diagnose(case)
    floor = case.floor_nrmse
    assert rep['verdict'] == 'named', rep['evidence']['selection_steps']
    assert [c['effect'] for c in rep['causes']] == [effect]
    got = rep['causes'][0]['parameters']
    for k, v in _truth_parameters(effect, case.truth).items():
        if k in ABS_TOL:
            assert abs(got[k] - v) <= ABS_TOL[k], (k, got[k], v)
        else:
            assert got[k] == pytest.approx(v, rel=REL_TOL[k]), (k, got[k], v)
    if effect == 'gas_spring':
        assert _gas_curve_miss(case.truth, rec.displacement[rec.mask], got) < 0.05
    if effect == 'current_saturation':
        assert _field_curve_miss(case.truth, got) < 0.02
    if effect == 'thermal_fade':
        assert got['kappa'] > 0.0  # the damper softens as it heats
    assert rep['gain'] > 0.3
    # Inner cross-validation (the selection's data) and the untouched outer blocks.
    assert rep['inner_cv']['extended_nrmse'] < 1.15 * floor
    assert rep['extended']['heldout_nrmse'] < 1.3 * floor
    assert rep['verdict'] != 'partly_explained'
    assert model['effects'] == [effect]


def test_effect_free_record_gives_none():
    case = _case(())
    rec, res, rep, model = _diagnose(case)
    assert rep['verdict'] == 'none'
    assert rep['causes'] == [] and rep['ambiguous'] == []
    assert abs(rep['gain']) < 1e-12
    assert rep['baseline']['heldout_nrmse'] < 1.1 * case.floor_nrmse


def test_a_stage_that_does_not_apply_returns_the_state_it_got():
    """Checks are pure steps over the frozen Selection: no change where no condition holds."""
    import dataclasses
    sel = diagnose.Selection(ds=None, steps=({'stage': 'x'},))
    ctx = diagnose._Context(full=[], n_folds=5, outer=True, search_rate=0.0, sensors=[],
                            physics=[], fine_allowed=[], share=False, floor=lambda: None,
                            tick=lambda *a: None)
    assert all(stage(sel, ctx) is sel for stage in diagnose.CHECKS)
    assert diagnose.STAGES == diagnose.SELECTION + diagnose.CHECKS
    with pytest.raises(dataclasses.FrozenInstanceError):
        sel.chosen = ['hysteresis']
    later = sel.add(None, {'stage': 'y'}, chosen=['gas_spring'])
    assert [s['stage'] for s in later.steps] == ['x', 'y'] and later.chosen == ['gas_spring']
    assert sel.steps == ({'stage': 'x'},) and sel.chosen == []


@pytest.mark.xfail(strict=True, reason=(
    'finding: the pair is named, but the model stays 1.2-1.4 noise floors on the inner folds '
    '(or a dead time is named too) on each of the 3 drawn dampers tried'))
def test_pair_of_effects_is_found():
    case = _case(('current_lag_asymmetric', 'gas_spring'))
    rec, res, rep, model = _diagnose(case)
    floor = case.floor_nrmse
    assert rep['verdict'] == 'named'
    assert {c['effect'] for c in rep['causes']} == {'current_lag_asymmetric', 'gas_spring'}
    assert rep['inner_cv']['extended_nrmse'] < 1.15 * floor
    assert rep['extended']['heldout_nrmse'] < 1.3 * floor


def test_constant_current_single_frequency_is_honest():
    """One motion at constant currents: current effects untestable, no confident guess."""
    rec, res, rep, model = _diagnose(_case(('current_lag',), kind='single'))
    assert {'current_delay', 'current_lag', 'current_lag_asymmetric'} <= set(
        rep['untestable'])
    assert rep['verdict'] == 'none'
    assert 'doe' in rep
    assert 'single_motion' in rep['evidence']['excitation']


def test_single_frequency_hysteresis_vs_series_is_ambiguous_or_right():
    """At one frequency and amplitude hysteresis and series stiffness are nearly collinear.

    Either the pair is reported ambiguous with its separating experiment, or the spring is
    named first among the physical causes with the truth's stiffness (a sensor finding
    beside it does not matter). A 6 s record.
    """
    case = _case(('series_stiffness',), kind='single', duration=6.0)
    rec, res, rep, model = _diagnose(case)
    if rep['verdict'] == 'ambiguous':
        pair = rep['ambiguous'][0]
        assert 'series_stiffness' in pair
        assert rep['separating_experiments']['/'.join(pair)]
    else:
        assert rep['verdict'] == 'named'
        phys = [c for c in rep['causes'] if c['location'] != 'sensor']
        assert phys[0]['effect'] == 'series_stiffness'
        k = phys[0]['parameters']['k_series']
        assert k == pytest.approx(case.truth.k_series, rel=REL_TOL['k_series'])


def test_constant_current_record_is_handled():
    """Constant current: the current dependence is unidentifiable; no crash, no guess."""
    from mr_suspension.identification.data import build_record

    rec = truthcases.record(_case(('current_delay',)).columns)
    cols = {'time': rec.time, 'displacement': rec.displacement, 'velocity': rec.velocity,
            'current_command': np.full(rec.n, 0.5), 'force': rec.force}
    flat = build_record('flat', cols)
    res = diagnose.run([flat])
    rep, _ = report.build(res, [flat])
    assert {'current_delay', 'current_lag', 'current_lag_asymmetric',
            'current_saturation'} <= set(rep['untestable'])
    assert 'current' in rep['evidence']['excitation']
    assert np.isfinite(rep['baseline']['heldout_nrmse'])


@pytest.mark.parametrize('effects', [
    ('series_stiffness', 'current_lag'),
    pytest.param(('current_lag_asymmetric', 'series_stiffness'), marks=pytest.mark.slow)])
def test_threaded_fits_give_the_serial_result(monkeypatch, effects):
    """Fits on threads give the serial run's selection, parameters and held-out errors.

    Independent fits run on threads (kernels drop the GIL); each is deterministic on its own.
    Two forward steps (each child's re-polish runs beside the parent's fairness refit) and an
    asymmetric lag (its symmetric rival beside the full-rate refits).
    Determinism only, no recovery judged: the package generator's record serves.
    """
    rec, _ = synthetic.make_record(effects, seed=3, duration=8.0)
    out = {}
    for jobs in (1, 2):
        monkeypatch.setattr(diagnose, 'JOBS', jobs)
        out[jobs] = diagnose.run([rec])
    a, b = out[1], out[2]
    assert a.causes == b.causes and a.steps == b.steps
    np.testing.assert_array_equal(a.final.theta, b.final.theta)
    assert a.final.eta == b.final.eta
    assert a.heldout == b.heldout


def test_longest_fits_start_first_and_results_keep_the_callers_order(monkeypatch):
    # A long fit started last runs alone at the end of a step (the timing record lost about
    # 0.4 s per step so): the threads take the longest candidates first, while results and
    # progress ticks keep the order the caller gave.
    import threading
    import time

    monkeypatch.setattr(diagnose, 'JOBS', 2)
    started, lock = [], threading.Lock()

    def job(name):
        def run():
            with lock:
                started.append(name)
            time.sleep(0.05)
            return name.upper()
        return run

    names = ['channel_delay', 'current_lag', 'yield_shape', 'gas_spring', 'hysteresis']
    ticks = []
    out = diagnose._parallel({n: (n, job(n)) for n in names}, ticks.append)
    assert set(started[:2]) == {'hysteresis', 'yield_shape'}
    assert list(out) == names and ticks == names
    assert [out[n] for n in names] == [n.upper() for n in names]


class _Fit:
    """A fit as the selection rule reads it: held-out errors, prediction, block labels."""

    def __init__(self, test_b, prediction, block_id, block_fold):
        self.test_b = np.asarray(test_b, dtype=float)
        self.test = np.bincount(block_fold, weights=self.test_b)
        self.prediction = np.asarray(prediction, dtype=float)
        self.block_id = block_id


def _local_effect(gain_sign):
    """20 blocks of 50 samples in 5 folds; the child moves 6 blocks (2 folds untouched)."""
    rng = np.random.default_rng(4)
    block_fold = np.arange(20) % 5
    block_id = np.repeat(np.arange(20), 50)
    parent_b = 1000.0 * (1.0 + 0.3 * rng.random(20))
    child_b = parent_b * (1.0 + 0.02 * rng.standard_normal(20))  # untouched: noise only
    acts = [0, 1, 5, 6, 10, 11]  # folds 0 and 1 hold every moved block
    child_b[acts] = parent_b[acts] * np.exp(-gain_sign * rng.uniform(0.3, 0.6, 6))
    pred_p = np.zeros(1000)
    pred_c = pred_p.copy()
    for j in acts:
        pred_c[block_id == j] = 3.0  # 50 * 9 = 450 >= 0.1 * the block's error
    return (_Fit(child_b, pred_c, block_id, block_fold),
            _Fit(parent_b, pred_p, block_id, block_fold))


def test_active_block_rule_sees_an_effect_that_acts_in_part_of_a_record():
    """A gain in every block the effect moves passes although three folds gain nothing."""
    child, parent = _local_effect(+1)
    pooled, t, _ = diagnose.fold_stats(child.test, parent.test)
    assert pooled >= diagnose.G_MIN and t < diagnose.T_MIN  # the fold t alone misses it
    ta, n = diagnose.active_stats(child, parent)
    assert n == 6 and ta > 5.0
    assert diagnose._pays(child, parent)[0]
    # A loss where it acts is no evidence, whatever the fold figures.
    child, parent = _local_effect(-1)
    ta, n = diagnose.active_stats(child, parent)
    assert n == 6 and ta < 0 and not diagnose._pays(child, parent)[0]


def test_active_block_rule_needs_enough_moved_blocks():
    child, parent = _local_effect(+1)
    child.prediction[parent.block_id >= 5] = 0.0  # now only blocks 0 and 1 move
    assert diagnose.active_stats(child, parent) == (0.0, 2)


def _fold_gain(gain, t):
    """Parent and child of five equal folds: fold gains of mean ``gain`` and fold t ``t``."""
    z = np.array([-1.5, -0.5, 0.0, 0.5, 1.5])
    d = gain + z * gain * np.sqrt(z.size) / (t * np.std(z, ddof=1))
    block_fold = np.arange(5)
    block_id = np.zeros(10, dtype=int)  # nothing moves: no active-block evidence
    parent = _Fit(np.full(5, 1000.0), np.zeros(10), block_id, block_fold)
    child = _Fit(1000.0 * (1.0 - d), np.zeros(10), block_id, block_fold)
    return child, parent


@pytest.mark.parametrize('gain, t, named', [
    (0.05, 2.5, False),  # a small gain at the full rate needs T_FINE
    (0.05, 3.2, True),
    (0.25, 2.5, True),  # a gain of G_FINE or more needs only the selection's T_MIN
    (0.25, 1.8, False),
])
def test_full_rate_bar_depends_on_the_gain(gain, t, named):
    child, parent = _fold_gain(gain, t)
    pooled, t_fold, _ = diagnose.fold_stats(child.test, parent.test)
    assert pooled == pytest.approx(gain) and t_fold == pytest.approx(t)
    assert diagnose._pays(child, parent, diagnose.T_FINE)[0] is named
    assert diagnose._pays(child, parent)[0] is (t >= diagnose.T_MIN)  # the selection's bar
