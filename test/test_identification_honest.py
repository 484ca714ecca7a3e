"""Diagnose on records it did not make (issue #11): sensor delay, driver, floor, verdicts.

Truths come from ``mr_suspension.truth`` (own integrator, other model shapes, realistic
sensors) or from numpy written here, never from the fitting kernels.
"""

import copy
import warnings

import numpy as np
import pytest

from mr_suspension.core.config import load_driver
from mr_suspension.identification import data as dataio
from mr_suspension.identification import diagnose, engine, model_io, noise, report, sensors
from mr_suspension.truth import cases


def _record(columns, name='case'):
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        return dataio.build_record(name, columns)


def _sine_record(noise_rms, seed=0, extra=None, duration=12.0, rate=1000.0):
    """Sine stroke at three amplitudes and currents, a Bingham-like force + white noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(duration * rate)) / rate
    amp = np.where(t < duration / 3, 0.01, np.where(t < 2 * duration / 3, 0.02, 0.006))
    x = amp * np.sin(2 * np.pi * 1.5 * t)
    v = np.gradient(x, 1.0 / rate)
    i = np.where((t % 4.0) < 2.0, 0.3, 0.9)
    f = (800 + 1500 * i) * v + (60 + 700 * i) * np.tanh(v / 0.012)
    if extra is not None:
        f = f + extra(t, x, v, i)
    f_noisy = f + noise_rms * rng.standard_normal(t.size)
    return {'time': t, 'displacement': x, 'velocity': v, 'force': f_noisy,
            'current_command': i}, f


@pytest.mark.parametrize('sigma, rel', [(2.0, 0.25), (10.0, 0.15), (40.0, 0.15)])
def test_noise_floor_from_repeated_inputs(sigma, rel):
    """Floor within ``rel`` of the added noise.

    1.5 Hz is no whole number of samples: repeats are off by up to 1/3 ms, which adds about
    1 N (0.1 % of the force std) to the smallest noise.
    """
    cols, clean = _sine_record(sigma, seed=int(sigma))
    rec = _record(cols)
    est = noise.estimate([rec])
    assert est is not None
    assert est.rms == pytest.approx(sigma, rel=rel)
    assert est.nrmse == pytest.approx(sigma / np.std(rec.force), rel=rel)


def test_noise_floor_not_estimable_without_repeats():
    rng = np.random.default_rng(3)
    t = np.arange(8000) / 1000.0
    x = np.cumsum(rng.standard_normal(t.size)) * 1e-4
    x -= np.linspace(x[0], x[-1], t.size)
    rec = _record({'time': t, 'displacement': x, 'force': 2e4 * np.gradient(x, 1e-3)
                   + rng.standard_normal(t.size), 'current_command': rng.uniform(0, 1, t.size)})
    assert noise.estimate([rec]) is None


def test_unmodelled_effect_is_partly_explained():
    """A force term no catalogue effect has (cubic stroke stiffening x^3 v): not 'named'."""
    cols, _ = _sine_record(3.0, seed=4,
                           extra=lambda t, x, v, i: 4e8 * x ** 2 * v * (1 + np.sin(t)))
    rec = _record(cols)
    res = diagnose.run([rec])
    assert res.floor is not None
    assert res.verdict == 'partly_explained', (res.causes, res.heldout)
    assert res.heldout['extended_over_floor'] > diagnose.PARTLY_FACTOR
    rep, _ = report.build(res, [rec])
    assert 'unexplained' in rep and rep['residual_map']['current']['nrmse']


def test_channel_delay_alone_is_a_sensor_finding():
    """Effect-free damper and ideal driver (truth integrator), force channel lagging 1.5 ms."""
    case = cases.make_case(7, (), sensor_faults=(), duration=10.0, shape='bingham_tanh',
                           sensor_clean=True, measured_current=False, driver_tau=0.0)
    cols = dict(case.columns)
    t = cols['time']
    cols['force'] = np.interp(t - 0.0015, t, cols['force'])
    res = diagnose.run([_record(cols)])
    assert 'channel_delay' in res.causes and res.locations['channel_delay'] == 'sensor'
    assert res.physical_causes == ()
    assert res.delay == pytest.approx(0.0015, abs=0.0003)
    assert 'channel_filter' not in res.causes  # a pure shift is no low-pass
    assert res.verdict in ('none', 'partly_explained')


def test_force_lead_below_a_decimated_sample_is_judged_at_the_full_rate():
    """Benchmark seed 0 case 30: a Bouc-Wen damper (truth integrator), the force leading 2.4 ms.

    0.6 of a 250 Hz step: on top of the loop the lead lost at the search rate (fold gains
    0.16, 0.79, 0.78, -0.83, 0.83; t 1.1) and the model stayed at 15 floors on an unseen
    record; at the full rate it gains 95-98 % in every fold.
    """
    case = cases.make_case(30, (), sensor_faults=None, duration=12.0, measured_current=None)
    assert 'channel_delay' in case.sensor['spec'].faults
    est = diagnose.Diagnosis()
    res = est.fit([_record(case.columns)])
    assert 'channel_delay' in res.causes and 'hysteresis' in res.causes
    assert res.delay == pytest.approx(case.sensor['spec'].force_delay, abs=0.0003)
    unseen = case.unseen()
    assert est.score(_record(unseen.columns)) < 4.0 * cases.transfer_floor(case, unseen)


def test_force_lead_behind_a_dead_time_and_a_series_spring_is_found_along_their_valley():
    """A 0.8 ms force lead, an 8.4 ms dead time and a 2.2e6 N/m series spring (truth).

    The lead makes the current's force come 0.8 ms early and the motion's too: the selection
    took 8 ms of dead time, no lead and a 10 % stiffer spring to make up for it (2.26
    floors on an unseen record). The delay judged at the full rate on top of that, the
    parent held, gains nothing; from restarts along the dead-time / delay valley it is found.
    """
    case = cases.make_case(14, ('current_delay', 'series_stiffness'),
                           sensor_faults=('channel_delay',), duration=12.0, strength=0.5)
    spec, truth = case.sensor['spec'], case.truth
    assert spec.force_delay < -0.5e-3 and truth.dead_time > 5e-3
    est = diagnose.Diagnosis()
    res = est.fit([_record(case.columns)])
    assert {'channel_delay', 'current_delay', 'series_stiffness'} <= set(res.causes)
    assert res.delay == pytest.approx(spec.force_delay, abs=0.25e-3)
    assert res.final.eta['k_series'] == pytest.approx(truth.k_series, rel=0.05)
    unseen = case.unseen()
    assert est.score(_record(unseen.columns)) < 1.5 * cases.transfer_floor(case, unseen)


@pytest.mark.parametrize('seed, shape, rel',
                         [(100300, 'algebraic', 0.05), (225, 'arctan', 0.15)])
def test_a_spring_named_with_the_static_shape_where_a_loop_stood_for_it(seed, shape, rel):
    """Benchmark seed 1 case 297 and seed 0 case 225: a yield shape behind a series spring.

    297: algebraic yield, 8.3e4 N/m, no velocity channel; named the spring and a pre-yield
    loop (5.8 floors on an unseen record). 225: arctan yield, 5e7 N/m; named a 30 um loop
    carrying 7 % of the yield force and the static shape (4.09 floors). The spring and the
    static shape fitted on the simulated error (the spring started at the loop's pre-yield
    stiffness where none was named) win on the inner folds.
    """
    case = cases.make_case(seed, ('series_stiffness',), sensor_faults=None, duration=12.0,
                           measured_current=None)
    assert case.truth.shape == shape
    est = diagnose.Diagnosis()
    res = est.fit([_record(case.columns)])
    assert set(res.physical_causes) == {'series_stiffness', 'yield_shape'}
    assert res.final.eta['k_series'] == pytest.approx(case.truth.k_series, rel=rel)
    unseen = case.unseen()
    assert est.score(_record(unseen.columns)) < 1.5 * cases.transfer_floor(case, unseen)


def test_a_soft_spring_and_a_gas_spring_are_not_named_a_loop():
    """Benchmark seed 0 case 4: algebraic yield behind 2.9e5 N/m, with a strong gas spring.

    The gas spring was dropped by a backward check and a 52 mm pre-yield loop (wider than the
    stroke: a stiffness) took its place beside the spring (6.04 floors on an unseen record).
    Judged by output error, the static shape with the gas spring wins where the loop stood.
    """
    case = cases.make_case(4, ('series_stiffness', 'gas_spring'), sensor_faults=None,
                           duration=12.0, measured_current=None)
    est = diagnose.Diagnosis()
    res = est.fit([_record(case.columns)])
    assert {'series_stiffness', 'gas_spring'} <= set(res.physical_causes)
    assert 'hysteresis' not in res.physical_causes
    assert res.final.eta['k_series'] == pytest.approx(case.truth.k_series, rel=0.1)
    unseen = case.unseen()
    assert est.score(_record(unseen.columns)) < 2.0 * cases.transfer_floor(case, unseen)


def test_gas_spring_follows_a_strong_polytropic_accumulator():
    """Truth: ``-p0 A ((V0 / (V0 + A x))^n - 1)`` at a gas column V0 / A = 52 mm, +-16 mm.

    The stroke reaches 30 % of the column; the best quadratic through the truth's curve
    misses it by 3 % of its span, the fitted gas spring with its cubic term freed stays
    within 2 %.
    """
    case = cases.make_case(4, ('gas_spring',), sensor_faults=(), duration=6.0,
                           shape='bingham_tanh', strength=1.0, measured_current=True,
                           sensor_clean=True)
    tr = case.truth
    rec = _record(case.columns)
    fit = engine.fit(engine.Dataset([rec], n_folds=5), ('gas_spring',),
                     start_eta={'gas_cubic': 1.0})
    x = rec.displacement
    with np.errstate(all='raise'):
        truth = -tr.gas_p0 * tr.gas_area * ((tr.gas_volume / (tr.gas_volume + tr.gas_area * x))
                                            ** tr.gas_n - 1.0)
    k = fit.effect_params('gas_spring')
    got = k['k_gas1'] * x + k['k_gas2'] * x ** 2 + k.get('k_gas3', 0.0) * x ** 3
    span = np.ptp(truth)

    def miss(curve):  # the offset belongs to f0
        return np.max(np.abs(curve - curve.mean() - truth + truth.mean()))

    assert miss(np.polyval(np.polyfit(x, truth, 2), x)) > 0.025 * span
    assert miss(got) < 0.02 * span


def test_a_strong_gas_spring_beside_a_loop_gets_its_cubic_term():
    """Benchmark seed 1 case 149: Bouc-Wen damper, asymmetry, gas column 2-3x the stroke.

    With the quadratic gas spring the training error stayed 4.6x the noise (a cubic-shaped
    residual over the stroke) and an unseen record came out at 3.76 floors; the cubic term,
    freed on top of the named gas spring, pays on the inner folds.
    """
    case = cases.make_case(100003 + 149, ('gas_spring', 'direction_asymmetry'),
                           sensor_faults=None, duration=12.0, measured_current=None)
    assert case.truth.shape == 'bouc_wen'
    est = diagnose.Diagnosis()
    res = est.fit([_record(case.columns)])
    assert {'gas_spring', 'direction_asymmetry'} <= set(res.physical_causes)
    step = [s for s in res.steps if s.get('stage') == 'gas spring cubic term (nested)']
    assert step and step[0]['candidates']['gas_cubic']['accepted']
    assert res.final.params().k_gas3 != 0.0
    unseen = case.unseen()
    assert est.score(_record(unseen.columns)) < 2.0 * cases.transfer_floor(case, unseen)


def test_output_error_fit_recovers_a_soft_spring_and_the_yield_shape():
    """Truth integrator, algebraic yield behind a soft spring; the fit starts 40 % off."""
    case = cases.make_case(7, ('series_stiffness',), sensor_faults=(), duration=4.0,
                           shape='algebraic', strength=0.9, measured_current=False,
                           sensor_clean=True)
    tr = case.truth
    ds = engine.Dataset([_record(case.columns)], n_folds=5)
    effects = ('series_stiffness', 'yield_shape')
    eta = {**engine.neutral_eta(), 'k_series': 1.4 * tr.k_series, 'v_y': 0.6 * tr.v_y,
           'yield_n': 1.5}
    theta = np.array([tr.f0, 0.7 * tr.c0, 0.7 * tr.c1, 1.3 * tr.fy0, 1.3 * tr.fy1])
    _, _, cost0 = engine.output_error_fit(ds, effects, eta, theta, (), 10 ** 5, 0)
    got, th, cost = engine.output_error_fit(ds, effects, eta, theta,
                                            ('k_series', 'v_y', 'yield_n'), 10 ** 5, 100)
    assert cost < 0.01 * cost0
    assert got['k_series'] == pytest.approx(tr.k_series, rel=0.05)
    assert got['v_y'] == pytest.approx(tr.v_y, rel=0.1)
    assert got['yield_n'] == pytest.approx(2.0, rel=0.1)  # the truth's w / sqrt(1 + w^2)
    assert th[1] == pytest.approx(tr.c0, rel=0.05) and th[3] == pytest.approx(tr.fy0, rel=0.1)


def test_delay_seen_only_at_the_full_rate_comes_before_the_physics_it_hid():
    """Benchmark seed 1 case 66: no damper effect, the force 0.63 ms behind (stamps rounded).

    At 250 Hz the delay gained 0.26 at fold t 1.4 (one fold 38 % worse, on the decimated
    current edges), a pre-yield loop and a 2 ms dead time took its place, and the delay then
    gained nothing on top of them; on the full-rate baseline it gains 0.58 at t 10.
    """
    case = cases.make_case(100003 + 66, (), sensor_faults=None, duration=12.0,
                           measured_current=None)
    assert 'channel_delay' in case.sensor['spec'].faults
    est = diagnose.Diagnosis()
    res = est.fit([_record(case.columns)])
    assert 'channel_delay' in res.causes and 'hysteresis' not in res.causes
    assert res.delay == pytest.approx(case.sensor['spec'].force_delay, abs=0.0002)
    unseen = case.unseen()
    assert est.score(_record(unseen.columns)) < 2.0 * cases.transfer_floor(case, unseen)


def _filtered_force_columns(f_ch):
    """Effect-free truth, ideal driver, the force through a causal Butterworth at ``f_ch``."""
    from scipy import signal
    case = cases.make_case(7, (), sensor_faults=(), duration=10.0, shape='bingham_tanh',
                           sensor_clean=True, measured_current=False, driver_tau=0.0)
    cols = dict(case.columns)
    b, a = signal.butter(2, f_ch, fs=1000.0)
    f = cols['force']
    cols['force'] = signal.lfilter(b, a, f - f[0]) + f[0]
    return cols


def test_anti_alias_filter_alone_is_a_sensor_finding_not_a_current_lag():
    """Effect-free damper, ideal driver; the force through a causal 150 Hz Butterworth.

    Before the full-rate filter stage the roll-off at every current edge was named
    ``current_lag`` (tau 1.6 ms) on top of a 1.4 ms ``channel_delay``.
    """
    cols = _filtered_force_columns(150.0)
    res = diagnose.run([_record(cols)])
    assert 'channel_filter' in res.causes and res.locations['channel_filter'] == 'sensor'
    assert res.channel_filter == pytest.approx(150.0, rel=0.15)
    assert res.physical_causes == ()
    rep, _ = report.build(res, [_record(cols)])
    assert rep['extended']['force_channel_cutoff_hz'] == pytest.approx(res.channel_filter)


def test_channel_delay_with_a_sample_of_dead_time_is_not_named_a_filter():
    """A 1.17 ms force-channel delay, command only (the truth's driver lag: a sample late).

    The filter stage ran before the current timing, and a 185 Hz low-pass plus 0.5 ms drew
    the delay and part of the dead time; named with the dead time, the filter must pay over
    its nested delay, and here it does not.
    """
    case = cases.make_case(100147, (), sensor_faults=None, duration=12.0,
                           measured_current=None)
    assert case.sensor['spec'].faults == ('clipping', 'channel_delay')
    res = diagnose.run([_record(case.columns)])
    assert 'channel_delay' in res.causes and 'channel_filter' not in res.causes
    assert res.final.eta['delay'] == pytest.approx(case.sensor['spec'].force_delay, abs=1e-4)


def test_filter_reduced_to_its_delay_keeps_one_delay():
    """A 3.9 ms channel delay on a Bouc-Wen damper with a current lag (truth integrator).

    Delay and filter were both kept until the current lag was named; the filter reduced to
    its nested delay must leave one ``channel_delay``, not two.
    """
    case = cases.make_case(236, ('current_lag',), sensor_faults=None, duration=12.0,
                           measured_current=None)
    assert case.sensor['spec'].faults == ('channel_delay',)
    res = diagnose.run([_record(case.columns)])
    assert len(set(res.causes)) == len(res.causes)
    assert 'channel_delay' in res.causes and 'channel_filter' not in res.causes
    assert 'current_lag' in res.physical_causes
    assert res.final.eta['delay'] == pytest.approx(case.sensor['spec'].force_delay, rel=0.2)


def test_a_filter_worse_than_none_at_every_cut_off_is_not_named():
    """A channel delay on a Bouc-Wen damper with a gas spring; no filter in the truth.

    Every cut-off was worse than no filter, so the filter's fit ended at f_ch = 0 (off), yet
    the refit of the other parameters gained 14 % (t 4.3) and a "filter" of 0 Hz was named.
    """
    case = cases.make_case(100070, ('gas_spring',), sensor_faults=None, duration=12.0,
                           measured_current=None)
    assert case.sensor['spec'].force_filter_hz == 0.0
    res = diagnose.run([_record(case.columns)])
    assert 'channel_filter' not in res.causes and 'channel_delay' in res.causes


def test_anti_alias_filter_with_a_dead_time_stays_a_filter():
    """150 Hz anti-alias filter and a one-sample dead time: the filter pays over a delay."""
    cols = _filtered_force_columns(150.0)
    # The command is logged one sample early: the force answers a sample after it.
    cmd = cols['current_command']
    cols['current_command'] = np.concatenate([cmd[1:], cmd[-1:]])
    res = diagnose.run([_record(cols)])
    assert set(res.causes) == {'channel_filter', 'current_delay'}
    assert res.channel_filter == pytest.approx(150.0, rel=0.15)
    check = [s for s in res.steps if 'nested delay' in s.get('stage', '')]
    assert len(check) == 1 and check[0]['candidates']['channel_filter']['accepted']


def test_anti_alias_filter_is_judged_against_the_current_lag_it_draws():
    """A 287 Hz anti-alias filter on a Bouc-Wen damper with a loop and a saturating current.

    No lagging delay is kept, so the filter was never judged, and the full-rate timing stage
    named its roll-off at the current edges ``current_lag``. Fitted on the same parent as the
    rival of that lag, the filter explains more: it is named and the lag is not.
    """
    case = cases.make_case(257, ('current_saturation', 'hysteresis'), sensor_faults=None,
                           duration=12.0, measured_current=None)
    spec = case.sensor['spec']
    assert 'anti_alias' in spec.faults and spec.force_delay == 0.0
    res = diagnose.run([_record(case.columns)])
    assert 'channel_filter' in res.causes and res.locations['channel_filter'] == 'sensor'
    assert res.channel_filter == pytest.approx(spec.force_filter_hz, rel=0.1)
    assert set(res.physical_causes) == {'hysteresis', 'current_saturation'}
    rival = [s for s in res.steps if 'rival' in s.get('stage', '')]
    assert len(rival) == 1 and rival[0]['added'] == 'channel_filter'


@pytest.mark.parametrize('seed', [3, 4])
def test_thermal_fade_in_a_12_s_record_is_testable_and_named(seed):
    """A strong thermal fade (truth integrator: heat from the dissipated power) in 12 s.

    Records under 15 s had thermal fade marked untestable; the benchmark's 12 s records hid
    fades of up to 15x the noise. The effect-free record of the same damper names no fade.
    """
    for effects, named in ((('thermal_fade',), True), ((), False)):
        case = cases.make_case(seed, effects, sensor_faults=(), duration=12.0,
                               shape='bingham_tanh', strength=0.9, sensor_clean=True,
                               measured_current=False, driver_tau=0.0)
        res = diagnose.run([_record(case.columns)])
        assert 'thermal_fade' not in res.untestable
        assert ('thermal_fade' in res.physical_causes) is named
        assert res.physical_causes[:1] == (('thermal_fade',) if named else ())


def test_driver_dead_time_is_a_named_driver_cause():
    """Measured coil current 9 ms behind the command (nominal Wonder Box: 3 ms)."""
    cols, _ = _sine_record(5.0, seed=9)
    dt = 1e-3
    cmd = cols['current_command']
    # Independent driver: exact first-order lag (7 ms) by the analytic step response, 9 ms delay.
    a = np.exp(-dt / 0.007)
    lag = np.empty_like(cmd)
    y = cmd[0]
    for k, u in enumerate(cmd):
        y = u + (y - u) * a
        lag[k] = y
    coil = np.concatenate([np.full(9, lag[0]), lag[:-9]])
    cols['current'] = coil + 0.002 * np.random.default_rng(1).standard_normal(coil.size)
    rec = _record(cols)
    res = diagnose.Diagnosis(nominal_driver=load_driver('wonder_box')).fit([rec])
    assert 'driver_delay' in res.causes and res.locations['driver_delay'] == 'driver'
    assert abs(res.driver['dead_time'] - 0.009) <= dt + 1e-9
    assert res.driver['tau_rise'] == pytest.approx(0.007, rel=0.1)
    rep, model = report.build(res, [rec])
    assert model['driver']['dead_time'] == pytest.approx(res.driver['dead_time'])
    assert 'Driver (command -> measured coil current)' in report.markdown(rep, [])


def test_estimator_predicts_and_scores_an_unseen_record():
    """Truth with series stiffness (Bouc-Wen-free algebraic shape): fit one, score another."""
    case = cases.make_case(11, ('series_stiffness',), sensor_faults=(), duration=10.0,
                           shape='algebraic', strength=0.8, measured_current=False)
    est = diagnose.Diagnosis()
    res = est.fit([_record(case.columns)])
    assert 'series_stiffness' in res.physical_causes
    other = case.unseen()
    rec = _record(other.columns, 'unseen')
    f = est.predict(rec)
    assert f.shape == rec.force.shape and np.all(np.isfinite(f))
    assert est.score(rec) < 0.5 * est.score(rec, model='baseline')
    # Driven twice as fast, the same damper leaves the fitted range: predict says so.
    from dataclasses import replace
    fast = replace(rec, velocity=2.0 * rec.velocity, displacement=2.0 * rec.displacement)
    with pytest.warns(UserWarning, match='outside the range the model was fitted on'):
        est.predict(fast)
    with pytest.raises(RuntimeError):
        diagnose.Diagnosis().predict(rec)


@pytest.mark.parametrize('dead_samples', [1, 2])
def test_dead_time_below_the_search_step_is_found_at_the_full_rate(dead_samples):
    """A dead time of one or two samples (a quarter or half of a 250 Hz search step)."""
    cols, clean = _sine_record(3.0, seed=13)
    rng = np.random.default_rng(13)
    t, v = cols['time'], cols['velocity']
    # Random current levels held 20-80 ms: many edges, each off by the dead time.
    cmd = np.empty(t.size)
    k = 0
    while k < t.size:
        n = int(rng.integers(20, 81))
        cmd[k:k + n] = rng.uniform(0.0, 1.0)
        k += n
    cols['current_command'] = cmd
    i = np.concatenate([np.full(dead_samples, cmd[0]), cmd[:-dead_samples]])
    f = (800 + 1500 * i) * v + (60 + 700 * i) * np.tanh(v / 0.012)
    cols['force'] = f + 3.0 * rng.standard_normal(t.size)
    res = diagnose.run([_record(cols)])
    assert res.physical_causes == ('current_delay',)
    dyn = res.final.dynamics()
    assert dyn['dead_time'] == pytest.approx(dead_samples * 1e-3, abs=1e-9)
    assert any(s.get('stage') == 'fine timing (full rate)' for s in res.steps)
    assert res.heldout['extended_nrmse'] < 1.15 * 3.0 / np.std(cols['force'])


def test_current_changes_at_moderate_speed_make_current_dynamics_testable():
    """Current steps while the stroke rate is 5-20 % of its peak still test a lag.

    Written here: fast strokes at one current, current steps only during slow motion; the
    force is a hand-written Bingham law driven by a first-order lagged current (25 ms).
    """
    rng = np.random.default_rng(3)
    rate = 1000.0
    t = np.arange(int(12 * rate)) / rate
    slow = (t % 3.0) < 1.5
    # Slow phases: 0.04 m/s peak; fast phases: 0.4 m/s peak (the 99th percentile).
    x = np.where(slow, 0.005 * np.sin(2 * np.pi * 4 / 3 * t), 0.016 * np.sin(2 * np.pi * 4 * t))
    v = np.gradient(x, 1.0 / rate)
    ph = t % 0.25
    cmd = np.where(slow & (ph >= 0.0625) & (ph < 0.1875), 0.9, 0.1)
    i_f = np.empty_like(cmd)
    a = 1.0 - np.exp(-1.0 / (rate * 0.025))
    y = cmd[0]
    for k, u in enumerate(cmd):
        y += a * (u - y)
        i_f[k] = y
    f = (500 + 900 * i_f) * v + (50 + 800 * i_f) * np.tanh(v / 0.01)
    f = f + rng.normal(0.0, 2.0, t.size)
    rec = _record({'time': t, 'displacement': x, 'velocity': v, 'force': f,
                   'current_command': cmd})
    untestable, notes = diagnose.testability([rec])
    assert 'current_lag' not in untestable, notes
    assert notes['current_edges']['rise_full_scale_equivalents'] >= 2.0
    # Under the old 20 % bar these steps would not count.
    moving = np.abs(v) > 0.2 * np.percentile(np.abs(v), 99)
    assert np.sum(np.abs(np.diff(cmd))[moving[1:]]) < 0.8


def test_soft_series_spring_is_named_with_its_stiffness_not_a_delay():
    """A soft series compliance (truth integrator, k1 = 2.3e5 N/m, baseline NRMSE 0.6).

    A force lagging the motion looks like a channel delay to the baseline, and a pre-yield
    loop can mimic part of it; the delay must not be kept when the spring explains it, and
    the spring's own search must reach the truth's basin (the separable iteration alone
    found k1 17x too stiff, plus a 13 ms delay and a loop).
    """
    case = cases.make_case(2, ('series_stiffness',), sensor_faults=(), duration=12.0,
                           shape='bingham_tanh', strength=0.8, measured_current=False)
    est = diagnose.Diagnosis()
    res = est.fit([_record(case.columns)])
    assert res.physical_causes == ('series_stiffness',)
    assert 'channel_delay' not in res.causes
    assert res.final.eta['k_series'] == pytest.approx(case.truth.k_series, rel=0.1)
    unseen = case.unseen()
    assert est.score(_record(unseen.columns)) < 1.5 * unseen.floor_nrmse


@pytest.mark.parametrize('strength', [0.8, 0.95])
def test_loop_share_of_the_yield_force_is_recovered_once_the_loop_is_named(strength):
    """Truth: a Bouc-Wen loop carrying a share w of the yield force beside a static yield.

    The truth's loop (its own integrator, ``z / z_max`` with beta, gamma) is not the fit's
    normalised loop. On this mixed programme the share is testable: the selection's loop
    candidates carry it, and the nested refit once the loop is named polishes it (where the
    share is not testable that refit is the only place it is freed). A share of 0.64
    (strength 0.8) recovered within 10 %, a share of 1 (strength 0.95) left above 0.9.
    """
    case = cases.make_case(2, ('hysteresis',), sensor_faults=(), duration=10.0,
                           shape='bingham_tanh', strength=strength, measured_current=False)
    est = diagnose.Diagnosis()
    res = est.fit([_record(case.columns)])
    assert res.physical_causes == ('hysteresis',)
    step = [s for s in res.steps if s.get('stage', '').startswith('hysteresis share')]
    assert len(step) == 1 and 'hysteresis_share' in step[0]['candidates']
    w = res.final.eta['hyst_weight']
    if case.truth.hyst_weight < 0.9:
        assert w == pytest.approx(case.truth.hyst_weight, rel=0.1)
    else:
        assert w > 0.9
    unseen = case.unseen()
    assert est.score(_record(unseen.columns)) < 1.5 * unseen.floor_nrmse


def test_static_yield_shape_is_judged_beside_a_freed_loop_share():
    """Truth: a partial loop (share 0.51) beside an algebraic static yield ``w / sqrt(1 + w^2)``.

    While the loop carries the whole yield force the static shape draws nothing, so the
    selection keeps ``yield_shape`` and ``hysteresis`` apart. With a share below 1 the
    static part is drawn again; its shape is judged on top (the algebraic exponent is 2).
    Since the loop candidates carry their share (stop 26) the shape's gain on top is 0.8 %
    at fold t 1.8 here, below the bar: it must be judged and found, not necessarily named.
    """
    case = cases.make_case(3, ('hysteresis',), sensor_faults=(), duration=12.0,
                           shape='algebraic', strength=0.8, measured_current=False)
    est = diagnose.Diagnosis()
    res = est.fit([_record(case.columns)])
    assert res.physical_causes[0] == 'hysteresis'
    step = [s for s in res.steps if s.get('stage', '').startswith('hysteresis share')]
    cand = step[0]['candidates']
    assert 1.5 < cand['yield_shape']['yield_n'] < 2.5
    if 'yield_shape' in res.physical_causes:
        assert 1.5 < res.final.eta['yield_n'] < 2.5
    assert res.final.eta['hyst_weight'] == pytest.approx(case.truth.hyst_weight, abs=0.1)
    unseen = case.unseen()
    assert est.score(_record(unseen.columns)) < 1.25 * unseen.floor_nrmse


@pytest.mark.parametrize('seed, shape, strength', [(4, 'algebraic', 0.55),
                                                   (7, 'bingham_tanh', 0.5)])
def test_new_partial_loop_finds_its_share_and_length(seed, shape, strength):
    """Truth: a Bouc-Wen loop carrying a quarter of the yield force beside the static curve.

    With the share at 1 the best loop is a tiny one that redraws the static curve, and the
    share's steps from there found nothing (w = 1); a new loop whose share is searched
    (``extra``) starts from a joint length x share grid.
    """
    case = cases.make_case(seed, ('hysteresis',), sensor_faults=(), duration=10.0,
                           shape=shape, strength=strength, measured_current=False)
    assert 0.2 < case.truth.hyst_weight < 0.3
    ds = engine.Dataset([dataio.decimate(_record(case.columns), 4)], n_folds=5)
    fit = engine.fit(ds, ('hysteresis',), new=('hysteresis',), extra=(engine.SHARE,))
    assert fit.eta['hyst_weight'] == pytest.approx(case.truth.hyst_weight, abs=0.05)
    assert fit.eta['x_h'] == pytest.approx(case.truth.x_h, rel=0.25)
    assert diagnose.partial_loop(['yield_shape', 'gas_spring'], 'hysteresis')
    assert not diagnose.partial_loop(['gas_spring'], 'hysteresis')
    assert not diagnose.partial_loop(['yield_shape'], 'series_stiffness')


@pytest.mark.parametrize('seed, shape, strength', [(4, 'algebraic', 0.55),
                                                   (7, 'bingham_tanh', 0.5)])
def test_partial_loop_is_not_read_as_a_force_channel_delay(seed, shape, strength):
    """Truth: a Bouc-Wen loop carrying a quarter of the yield force, no sensor fault.

    Near every reversal such a loop lags the force like a sub-millisecond channel delay, and
    no loop with the whole yield force in it draws it: the previous code named a sensor
    ``channel_delay`` with a gas spring or a thermal fade (unseen / floor 7.5 and 9.6). On a
    mixed programme the share is testable, and the delay must pay on top of a partial loop.
    """
    case = cases.make_case(seed, ('hysteresis',), sensor_faults=(), duration=10.0,
                           shape=shape, strength=strength, measured_current=False)
    assert 0.2 < case.truth.hyst_weight < 0.3
    est = diagnose.Diagnosis()
    res = est.fit([_record(case.columns)])
    assert 'hysteresis_share' not in res.notes
    assert 'channel_delay' not in res.causes
    assert res.physical_causes[0] == 'hysteresis'
    assert res.final.eta['hyst_weight'] == pytest.approx(case.truth.hyst_weight, abs=0.05)
    assert res.final.eta['x_h'] == pytest.approx(case.truth.x_h, rel=0.25)
    unseen = case.unseen()
    assert est.score(_record(unseen.columns)) < 1.6 * unseen.floor_nrmse


def test_periodicity_tells_repeated_cycles_from_mixed_motion():
    """Repeated sine cycles score near 1, band-limited noise and the truth's mixed programme low.

    Signals written here (numpy, scipy's Butterworth) and the independent truth's programme.
    """
    from scipy import signal

    class Motion:
        def __init__(self, x):
            self.displacement = np.asarray(x, dtype=float)

    t = np.arange(12000) / 1000.0
    sine = 0.01 * np.sin(2 * np.pi * 1.3 * t)
    b, a = signal.butter(4, [1.5, 8.0], fs=1000.0, btype='band')
    noise_motion = 0.01 * signal.filtfilt(b, a, np.random.default_rng(0).standard_normal(t.size))
    mixed = cases.make_case(3, (), sensor_faults=(), duration=12.0).columns['displacement']
    assert diagnose.periodicity(Motion(sine)) > 0.98
    assert diagnose.periodicity(Motion(noise_motion)) < 0.5
    assert diagnose.periodicity(Motion(mixed)) < 0.6
    holed = sine.copy()
    holed[500:520] = np.nan  # dropouts do not break it
    assert diagnose.periodicity(Motion(holed)) > 0.95
    for still in (np.zeros(100), np.full(100, np.nan), np.zeros(3)):
        assert diagnose.periodicity(Motion(still)) == 1.0  # no motion: nothing to test
    assert not diagnose.share_testable([Motion(sine)])
    assert diagnose.share_testable([Motion(sine), Motion(noise_motion)])


def test_loop_share_is_untestable_on_repeated_cycles():
    """Sine blocks (one frequency, three amplitudes): the share is untestable and said so."""
    cols, _ = _sine_record(5.0)
    res = diagnose.run([_record(cols)])
    assert 'hysteresis_share' in res.notes
    assert res.final.eta['hyst_weight'] == 1.0


def test_compatible_counts_only_the_pairs_the_new_effect_makes():
    """A nested pair already in a model (loop with its static shape) does not block others."""
    assert not diagnose.compatible(['hysteresis'], 'yield_shape')
    assert not diagnose.compatible(['yield_shape', 'gas_spring'], 'hysteresis')
    assert not diagnose.compatible(['current_lag'], 'current_lag_asymmetric')
    assert diagnose.compatible(['hysteresis', 'yield_shape'], 'current_lag')


def test_direction_asymmetry_on_a_bouc_wen_damper_is_recovered():
    """Spencer Bouc-Wen truth whose rebound/compression scale follows the loop's force.

    A scale that followed the rate instead stepped the loop's force at every reversal: rho came
    out 30 % low (0.17 for 0.247) and the unseen record at 2.1x the floor.
    """
    case = cases.make_case(2, ('direction_asymmetry',), sensor_faults=(), duration=10.0,
                           shape='bouc_wen', strength=0.7, measured_current=False)
    est = diagnose.Diagnosis()
    res = est.fit([_record(case.columns)])
    # A Bouc-Wen baseline really has a pre-yield loop: naming it is right.
    assert set(res.physical_causes) == {'direction_asymmetry', 'hysteresis'}
    assert res.final.eta['rho'] == pytest.approx(case.truth.rho, rel=0.1)
    unseen = case.unseen()
    assert est.score(_record(unseen.columns)) < 1.5 * unseen.floor_nrmse


def test_noise_floor_is_bounded_by_a_models_heldout_error():
    """A repeated-input figure above a model's held-out error is memory, not noise."""
    f = noise.NoiseFloor(rms=30.0, nrmse=0.3, pairs=500, max_distance=0.01)
    low = noise.bounded(f, 3.0)
    assert low.bounded and low.rms == 3.0 and low.repeats_rms == 30.0
    assert low.nrmse == pytest.approx(0.03) and 'bounds any noise floor' in low.method
    assert noise.bounded(f, 40.0) is f and not f.bounded
    assert noise.bounded(None, 3.0) is None


def _arctan_dataset(seed):
    case = cases.make_case(seed, (), sensor_faults=(), duration=10.0, shape='arctan',
                           measured_current=False)
    return engine.Dataset([dataio.decimate(_record(case.columns), 4)], n_folds=5)


def test_element_runs_are_memoised_exactly(monkeypatch):
    """A design that moves only the force channel re-uses the element run; results are equal.

    ``engine.element_run`` keys the run on the parameter array, the current dynamics and the
    record: the regressors of a memoised design equal those of a fresh dataset, a delay or
    low-pass change does not simulate again, nor does another theta without a series spring
    or a thermal fade (the element's trajectories do not depend on it then); with one, it
    does. The memo stays within its byte budget (oldest out first).
    """
    ds = _arctan_dataset(3)
    effects = ('channel_delay', 'hysteresis')
    eta = {**engine.neutral_eta(), 'v_y': 0.01, 'x_h': 2e-3}
    theta = np.array([0.0, 500.0, 1000.0, 50.0, 300.0])
    calls = []
    real = engine.simulate_extended

    def counted(*a):
        calls.append(1)
        return real(*a)

    monkeypatch.setattr(engine, 'simulate_extended', counted)
    x0 = engine.design(ds, effects, eta, theta)
    x1 = engine.design(ds, effects, {**eta, 'delay': 2e-3}, theta)
    x2 = engine.design(ds, effects, eta, theta)
    assert len(calls) == 1
    assert np.array_equal(x0, x2) and not np.array_equal(x0, x1)
    fresh = engine.Dataset(ds.records, n_folds=5)
    assert np.array_equal(engine.design(fresh, effects, {**eta, 'delay': 2e-3}, theta), x1)
    assert len(calls) == 2  # the fresh dataset's own run
    x3 = engine.design(ds, effects, eta, 1.5 * theta)
    assert len(calls) == 2
    assert np.array_equal(engine.design(fresh, effects, eta, 1.5 * theta), x3)
    spring, e_spring = effects + ('series_stiffness',), {**eta, 'k_series': 3e5}
    x4 = engine.design(ds, spring, e_spring, theta)
    x5 = engine.design(ds, spring, e_spring, 1.5 * theta)
    assert len(calls) == 4 and not np.array_equal(x4, x5)
    engine.design(ds, ('channel_delay', 'hysteresis', 'current_delay'),
                  {**eta, 'dead_time': 0.01}, theta)
    assert len(calls) == 5
    run = engine.element_run(ds, 0, engine.damper_params(effects, eta, theta).to_array(),
                             engine.current_dynamics(effects, eta))
    assert not any(a.flags.writeable for a in run)
    monkeypatch.setattr(engine, 'RUN_CACHE_BYTES', 2.5 * 5 * run[0].nbytes)
    for k in range(4):
        engine.design(ds, effects, {**eta, 'x_h': 1e-3 * (k + 1)}, theta)
    assert len(ds._runs) == 2 and ds._runs_bytes <= engine.RUN_CACHE_BYTES


def test_block_and_fold_sums_of_squares_equal_numpys():
    """``engine._grams``: per-range ``X^T X``, ``X^T y``, ``y^T y`` and their group sums."""
    rng = np.random.default_rng(5)
    x = rng.standard_normal((900, 5)) * [1.0, 1e3, 1e-2, 5.0, 1e4]
    y = rng.standard_normal(900) * 300.0
    order = rng.permutation(900)
    bounds = np.array([40, 100, 310, 311, 600, 880])
    group = np.array([2, 0, 2, 1, 0])
    g, h, e, gg, hg, eg = engine._grams(x, y, order, bounds, group, 4)
    for j in range(5):
        xs, ys = x[order[bounds[j]:bounds[j + 1]]], y[order[bounds[j]:bounds[j + 1]]]
        np.testing.assert_allclose(g[j], xs.T @ xs, rtol=1e-12, atol=1e-9 * abs(g[j]).max())
        np.testing.assert_allclose(h[j], xs.T @ ys, rtol=1e-12, atol=1e-9 * abs(h[j]).max())
        assert e[j] == pytest.approx(ys @ ys, rel=1e-12)
    for f in range(4):
        np.testing.assert_allclose(gg[f], g[group == f].sum(0), rtol=1e-12, atol=1e-6)
        np.testing.assert_allclose(hg[f], h[group == f].sum(0), rtol=1e-12, atol=1e-6)
        assert eg[f] == pytest.approx(e[group == f].sum(), rel=1e-12)
    assert not gg[3].any() and eg[3] == 0.0  # a group without ranges


@pytest.mark.parametrize('gas', [False, True])
def test_regressor_columns_equal_numpys_to_the_bit(gas):
    """``engine._regressors``: the force law's columns, the same products as numpy's."""
    rng = np.random.default_rng(11)
    u, m, y, g, x = (rng.standard_normal(700) * s for s in (0.3, 1.0, 0.9, 2.0, 0.01))
    cols = [np.ones(700), m * u, m * u * g, y, y * g] + ([x, x ** 2, x ** 2 * x] if gas else [])
    assert np.array_equal(engine._regressors(u, m, y, g, x, gas), np.column_stack(cols))


def test_repeat_scan_equals_the_cumulative_sums_of_numpy():
    """``noise._best_repeats``: best earlier match per sample, as numpy's cumsum finds it."""
    rng = np.random.default_rng(12)
    t = np.arange(1500) / 125.0
    x = np.sin(2.0 * t) + 1e-3 * rng.standard_normal(t.size)
    v = 2.0 * np.cos(2.0 * t) + 1e-2 * rng.standard_normal(t.size)
    i = (np.sin(0.5 * t) > 0) + 1e-3 * rng.standard_normal(t.size)
    sc = [np.std(a) for a in (x, v, i)]
    w, best, lag = 25, np.full(t.size, np.inf), np.zeros(t.size, dtype=int)
    for L in range(7, t.size - w):
        e = sum(((a[L:] - a[:-L]) / s) ** 2 for a, s in zip((x, v, i), sc))
        c = np.concatenate([[0.0], np.cumsum(e)])
        d = (c[w:] - c[:-w]) / w
        k = np.arange(L + w - 1, t.size)
        better = d < best[k]
        best[k[better]], lag[k[better]] = d[better], L
    got_lag, got_best = noise._best_repeats(x, v, i, 125.0, 0.05, 100.0, 0.2)
    assert np.array_equal(got_lag, lag) and np.array_equal(got_best, best)
    assert np.isfinite(best).sum() > 1000  # the comparison covers most samples


def test_yield_exponent_is_searched_with_its_smoothing_velocity():
    """Truth: an arctan yield ``(2/pi) atan(w)`` (truth integrator), no other effect.

    The algebraic sigmoid's exponent and v_y trade along a narrow valley (the error doubles
    within a factor 1.5 in v_y): searched one after the other from the tanh's v_y every
    exponent looked worse than tanh and the shape was not found (SSE ratio 1.0). The fit
    must reach the best point of a dense (n, v_y) grid.
    """
    ds = _arctan_dataset(15)
    base = engine.fit(ds, ())
    fit = engine.fit(ds, ('yield_shape',), start_eta=base.eta, start_theta=base.theta,
                     new=('yield_shape',))
    assert fit.sse < 0.95 * base.sse
    best = np.inf
    for n in np.linspace(0.7, 3.0, 12):
        for vy in base.eta['v_y'] * np.geomspace(0.4, 2.5, 21):
            eta = {**base.eta, 'yield_n': float(n), 'v_y': float(vy)}
            x = engine.design(ds, ('yield_shape',), eta, base.theta)
            best = min(best, engine.CVResult(ds, x, eta).sse)
    assert fit.sse < 1.005 * best


@pytest.mark.parametrize('active', [True, False])
def test_physics_screened_again_on_a_full_rate_timing(monkeypatch, active):
    """The same damper diagnosed whole: its dead time is a third of a decimated sample.

    At 250 Hz every candidate was fitted on top of the timing error (``yield_shape`` gain
    0.29, t 1.9); the full-rate stage named ``current_delay`` (loss 0.52) and nothing was
    screened again: the model stayed at 2.2 floors on its own record, 5.1 on an unseen one.
    With the active-block rule the shape is named at 250 Hz, the dead time comes out as a
    2.5 ms lag beside two causes and is swapped back at the full rate (the model has no room
    for a fine timing cause); without it, the full-rate screen names the shape.
    """
    if not active:
        monkeypatch.setattr(diagnose, 'N_ACTIVE', 10 ** 6)
    case = cases.make_case(281, ('current_delay', 'direction_asymmetry'), sensor_faults=None,
                           duration=12.0, measured_current=None)
    est = diagnose.Diagnosis()
    res = est.fit([_record(case.columns)])
    assert {'current_delay', 'direction_asymmetry', 'yield_shape'} == set(res.causes)
    again = [s for s in res.steps if s.get('stage') == 'physics again on the full-rate timing']
    if not active:
        assert again and again[0]['candidates']['yield_shape']['accepted']
    unseen = case.unseen()
    assert est.score(_record(unseen.columns)) < 2.0 * cases.transfer_floor(case, unseen)


def test_yield_shape_is_polished_from_its_best_grid_point():
    """Truth: an algebraic yield (truth integrator) behind a 1.3 ms dead time, clean load cell.

    Benchmark seed 0 case 281 at the full rate. The valley of (n, v_y) is narrower than the
    joint grid's steps (the error grows by half within 10 % in v_y): every grid point lost
    to the unshaped parent, which stayed the fit (gain 0), while the valley holds 18 % less
    error. The child must reach the best point of a dense scan about the valley.
    """
    case = cases.make_case(281, ('current_delay', 'direction_asymmetry'), sensor_faults=None,
                           duration=12.0, measured_current=None)
    assert case.truth.shape == 'algebraic'
    ds = engine.Dataset([_record(case.columns)], n_folds=5, outer=True)  # as diagnose's
    parent = engine.fit(ds, ('direction_asymmetry', 'current_delay'))
    held = ('rho', 'dead_time')
    child = engine.fit(ds, parent.effects + ('yield_shape',), start_eta=parent.eta,
                       start_theta=parent.theta, new=('yield_shape',), sweeps=1, fixed=held)
    eff = child.effects
    best = min(engine.CVResult(ds, engine.design(ds, eff, e, parent.theta), e).sse
               for e in ({**parent.eta, 'yield_n': float(n), 'v_y': parent.eta['v_y'] * f}
                         for n in np.arange(1.5, 2.55, 0.1)
                         for f in np.geomspace(0.9, 1.3, 13)))
    assert best < 0.9 * parent.sse
    assert child.sse < 1.01 * best


@pytest.mark.parametrize('factor', [0.3, 3.0])
def test_tanh_refit_from_an_algebraic_fit_searches_v_y_afresh(factor):
    """A model without ``yield_shape`` started from one with it (a backward drop) needs tanh's v_y.

    The algebraic sigmoid's v_y is up to 3x off tanh's; the local grid of a refit did not
    get back (SSE 1.1-2.0x the baseline's) and the dropped shape left a worse baseline
    (an arctan damper's unseen / floor 1.08 -> 1.36).
    """
    ds = _arctan_dataset(15)
    base = engine.fit(ds, ())
    start = {**base.eta, 'yield_n': 1.5, 'v_y': base.eta['v_y'] * factor}
    back = engine.fit(ds, (), start_eta=start, start_theta=base.theta, new=(), sweeps=1,
                      local=(0.5, 1.0, 2.0))
    assert back.sse < 1.01 * base.sse


@pytest.mark.parametrize('k, effects', [(40, ('current_lag', 'hysteresis')),
                                        (142, ('current_delay', 'series_stiffness'))])
def test_channel_delay_must_pay_on_top_of_a_loop_and_a_second_lag(k, effects):
    """Two lags at once: a loop with a current lag; a Bouc-Wen damper behind a soft spring.

    Benchmark cases (``bench_diagnose`` seed 1, cases 40 and 142; truth integrator and
    sensors). The force lags in two ways, and a channel delay paid on top of either alone
    (3.7 ms and 16 ms kept; unseen / floor 16 and 40). On a mixed programme the delay must
    also pay on top of the partial loop and the best other single together.
    """
    case = cases.make_case(100003 + k, effects, sensor_faults=None, duration=12.0,
                           measured_current=None)
    assert 'channel_delay' not in case.sensor['spec'].faults
    est = diagnose.Diagnosis()
    res = est.fit([_record(case.columns)])
    assert 'channel_delay' not in res.causes
    loop = {'hysteresis'} if case.truth.shape == 'bouc_wen' else set()
    truth = set(effects) - {'current_delay'} | loop
    assert truth <= set(res.physical_causes)
    unseen = case.unseen()
    assert est.score(_record(unseen.columns)) < 2.5 * cases.transfer_floor(case, unseen)


def test_hidden_partial_loop_is_a_loop_not_a_series_spring():
    """Truth: a Bouc-Wen loop carrying a quarter of the yield force beside an algebraic yield.

    Benchmark case (``bench_diagnose`` seed 1, case 98; truth integrator and sensors), no
    channel delay kept. A loop with the whole yield force cannot draw it (gain -4 %), so a
    stiff series spring and a gas spring were named (unseen / floor 3.95). Where the share is
    testable the selection's loop candidates carry their share.
    """
    case = cases.make_case(100003 + 98, ('hysteresis',), sensor_faults=None, duration=12.0,
                           measured_current=None)
    assert 0.2 < case.truth.hyst_weight < 0.3
    est = diagnose.Diagnosis()
    res = est.fit([_record(case.columns)])
    assert res.physical_causes[0] == 'hysteresis'
    assert 'series_stiffness' not in res.causes
    assert res.final.eta['hyst_weight'] == pytest.approx(case.truth.hyst_weight, abs=0.05)
    unseen = case.unseen()
    assert est.score(_record(unseen.columns)) < 1.5 * cases.transfer_floor(case, unseen)


@pytest.mark.parametrize('k', [43, 277])
def test_loop_share_must_pay_before_a_loop_candidate_carries_it(k):
    """Truth: a Bouc-Wen damper (its loop carries the whole yield force) with a saturating field.

    Benchmark cases (``bench_diagnose`` seed 0, cases 43 and 277; truth integrator and
    sensors). A loop candidate that took its share unjudged absorbed part of the saturation,
    which was then not named (unseen / floor 1.28 and 2.02). The share is kept only where it
    pays against ``w_h = 1`` by the selection's rule.
    """
    case = cases.make_case(k, ('current_saturation',), sensor_faults=None, duration=12.0,
                           measured_current=None)
    assert case.truth.shape == 'bouc_wen'
    est = diagnose.Diagnosis()
    res = est.fit([_record(case.columns)])
    assert {'hysteresis', 'current_saturation'} <= set(res.physical_causes)
    unseen = case.unseen()
    assert est.score(_record(unseen.columns)) < 1.6 * cases.transfer_floor(case, unseen)


def test_delivered_model_takes_the_outer_blocks_after_the_scoring():
    """Scored on the outer blocks, the delivered model solves its linear part on every block.

    The held-out figures stay those of the model fitted on the inner folds; the model that
    ``predict`` and model.json carry has the least-squares linear parameters of all blocks
    (same effects and nonlinear parameters).
    """
    case = cases.make_case(12, ('current_lag',), sensor_faults=(), duration=10.0,
                           measured_current=False)
    res = diagnose.Diagnosis().fit([_record(case.columns)])
    ds, fin = res.dataset, res.final
    assert 'current_lag' in res.causes and ds.outer.any()
    x = engine.design(ds, fin.effects, fin.eta, fin.theta)
    inner = copy.copy(fin)
    inner.theta = engine.CVResult(ds, x, fin.eta).theta  # inner blocks only
    assert not np.allclose(inner.theta, fin.theta)
    # The held-out figure is the inner model's, on the outer blocks.
    scored = diagnose.outer_mse(ds, inner)
    assert res.heldout['extended_mse'] == pytest.approx(scored, rel=1e-6)
    assert diagnose.outer_mse(ds, fin) < diagnose.outer_mse(ds, inner)
    # The delivered one solves all blocks (no block left out): no other theta does better.
    ds_all = engine.Dataset(ds.records, n_folds=ds.n_folds, outer=False)
    x_all = engine.design(ds_all, fin.effects, fin.eta, fin.theta)
    m = ds_all.fold >= 0

    def sse(th):
        return float(np.sum((ds_all.force[m] - x_all[m] @ th) ** 2))
    assert sse(fin.theta) < sse(inner.theta)
    assert sse(fin.theta) < sse(fin.theta * 1.001) and sse(fin.theta) < sse(fin.theta * 0.999)


def test_block_errors_add_up_to_the_fold_errors():
    """Every inner block's held-out SSE is kept; a fold's is the sum of its blocks'."""
    case = cases.make_case(12, ('current_lag',), sensor_faults=(), duration=6.0,
                           measured_current=False)
    recs = [_record(case.columns, 'a'), _record(case.unseen().columns, 'b')]
    ds = engine.Dataset(recs, n_folds=5, outer=True)
    assert ds.block_fold.size == 2 * 5 * 4  # 4 blocks per fold in each record
    assert np.all(ds.block_id[ds.fold < 0] == -1)
    assert np.array_equal(np.unique(ds.fold[ds.block_id >= 0]), np.arange(5))
    fit = engine.fit(ds, ('current_lag',))
    assert fit.test_b.shape == ds.block_fold.shape and np.all(fit.test_b > 0)
    sums = np.bincount(ds.block_fold, weights=fit.test_b, minlength=5)
    assert np.allclose(sums, fit.test, rtol=1e-9)


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_spring_and_loop_restarts_leave_a_wrong_k1_valley(seed, monkeypatch):
    """Bouc-Wen damper (truth integrator) behind a series spring of 5-9e5 N/m.

    Started in the valley of a 4x stiffer spring with the loop's shape at its bound, the
    coordinate search stays there (training SSE 4-150x that of a start at the truth); the
    restarts over k1, each with the loop searched anew, reach the truth's k1 (4-12 %). The
    loop's shape may end in a neighbouring valley: seed 1 at 1.25x the SSE of the start at
    the truth (a valley at 0.35x, unloading shape r_h = -0.98, lies outside the r_h grid).
    """
    case = cases.make_case(seed, ('series_stiffness',), sensor_faults=(), duration=12.0,
                           shape='bouc_wen', strength=0.65, measured_current=False)
    t = case.truth
    ds = engine.Dataset([dataio.decimate(_record(case.columns), 4)], outer=True)
    effects = ('hysteresis', 'series_stiffness')
    x_y = 1.0 / t.bw_a  # the normalised Bouc-Wen loop's length
    at_truth = engine.fit(ds, effects, new=(), sweeps=1, start_eta={
        'k_series': t.k_series, 'x_h': x_y, 'hyst_n': t.bw_n,
        'hyst_r': t.bw_gamma / (t.bw_beta + t.bw_gamma)})
    wrong = engine.fit(ds, effects, new=(), sweeps=1, start_eta={
        'k_series': 4 * t.k_series, 'x_h': 1.2 * x_y, 'hyst_n': 1.5, 'hyst_r': 0.5})
    assert wrong.sse > 3 * at_truth.sse  # the single start really is stuck
    best = engine.loop_restarts(ds, wrong, engine.K1_STARTS)
    assert best.sse < 1.3 * at_truth.sse
    assert best.eta['k_series'] == pytest.approx(t.k_series, rel=0.15)
    if seed == 1:  # the restarts on threads (as diagnose runs them) give the same fit
        monkeypatch.setattr(diagnose, 'JOBS', 2)
        threaded = engine.loop_restarts(ds, wrong, engine.K1_STARTS, mapper=diagnose._map)
        assert threaded.sse == best.sse and threaded.eta == best.eta


def test_loop_is_searched_again_at_the_full_rate():
    """Bouc-Wen damper (truth integrator), force channel 2.4 ms ahead, velocity noise 1.8 %.

    The lead is found at the full rate, after the loop's shape was chosen at 250 Hz on top
    of the uncorrected skew; refitted only locally, the loop kept an unloading shape of -0.72
    (truth -0.34) and the unseen record sat at 3.6 floors.
    """
    case = cases.make_case(30, (), sensor_faults=None, duration=12.0, measured_current=None)
    lead = case.sensor['spec'].force_delay
    assert lead == pytest.approx(-2.43e-3, abs=0.01e-3)
    t = case.truth
    est = diagnose.Diagnosis()
    res = est.fit([_record(case.columns)])
    # The loop keeps 95 % of the yield force; the static rest's shape (a sharp corner) may
    # join it at the full rate (``_shape_again``: unseen record 2.29 -> 2.22 floors).
    assert res.physical_causes[0] == 'hysteresis'
    assert set(res.physical_causes) <= {'hysteresis', 'yield_shape'}
    assert res.delay == pytest.approx(lead, abs=0.2e-3)
    r_h = t.bw_gamma / (t.bw_beta + t.bw_gamma)  # the normalised loop's unloading shape
    assert res.final.eta['hyst_r'] == pytest.approx(r_h, abs=0.15)
    assert res.final.eta['hyst_n'] == pytest.approx(t.bw_n, abs=0.15)
    assert any(s.get('stage') == 'loop searched anew (full rate)' for s in res.steps)
    unseen = case.unseen()
    assert est.score(_record(unseen.columns)) < 2.8 * cases.transfer_floor(case, unseen)


def test_anti_alias_filter_comes_before_the_spring_that_mimicked_it():
    """Algebraic-yield damper with a rebound/compression asymmetry, a 169 Hz anti-alias filter.

    Truth integrator; the load cell also clips at 86 % of its peak. The filter's roll-off
    had been taken by a 2.4e7 N/m series spring and a 1 ms dead time; on top of them the
    filter gained 0.16 at fold t 1.3 and was not named, and the unseen record sat at 2.6
    floors. Judged before the physics it hides, the filter stands and the spring and the
    dead time go.
    """
    case = cases.make_case(267, ('direction_asymmetry',), sensor_faults=None, duration=12.0,
                           measured_current=None)
    f_ch = case.sensor['spec'].force_filter_hz
    assert f_ch == pytest.approx(168.8, abs=0.1)
    est = diagnose.Diagnosis()
    res = est.fit([_record(case.columns)])
    assert res.locations.get('channel_filter') == 'sensor'
    assert res.channel_filter == pytest.approx(f_ch, rel=0.1)
    assert 'direction_asymmetry' in res.physical_causes
    assert not {'series_stiffness', 'current_delay'} & set(res.physical_causes)
    assert any(s.get('added') == 'channel_filter' and 'before the physics' in s.get('stage', '')
               for s in res.steps)
    unseen = case.unseen()
    assert est.score(_record(unseen.columns)) < 1.6 * cases.transfer_floor(case, unseen)


@pytest.mark.parametrize('shape', ['algebraic', 'bingham_tanh'])
def test_yield_shape_is_judged_again_at_the_full_rate(shape):
    """A steep yield (v_y 2.3 mm/s, truth integrator) measured without a velocity channel.

    A reversal crosses the yield's width in a few milliseconds: a sample or two at the
    search rate, so the selection keeps the tanh sigmoid on both dampers. At the full rate
    the algebraic sigmoid's shape (the fit's family at n = 2) is named, the tanh truth's is
    not: same programme, sensors and parameters, only the truth's sigmoid differs.
    """
    case = cases.make_case(4, (), shape=shape, sensor_faults=('no_velocity',), duration=12.0,
                           measured_current=True)
    assert case.truth.v_y == pytest.approx(2.3e-3, abs=0.1e-3)
    res = diagnose.Diagnosis().fit([_record(case.columns)])
    step = [s for s in res.steps if s.get('stage') == 'yield shape again (full rate)']
    assert len(step) == 1  # judged once, on top of the selected model
    if shape == 'bingham_tanh':
        assert 'yield_shape' not in res.causes
        return
    assert step[0].get('added') == 'yield_shape'
    assert 'yield_shape' in res.physical_causes
    assert res.final.eta['yield_n'] == pytest.approx(2.0, abs=0.5)


def test_a_driver_lag_that_gains_much_at_a_modest_fold_t_is_named():
    """An arctan damper with a direction asymmetry, its coil current not measured.

    The truth's driver lags the command by 0.38 ms (1.96x the noise in force). Its error
    sits in the blocks around the 27 command edges, so the full-rate timing gains 20-30 %
    of the held-out MSE at a fold t of only 1.9 and an active-block t of 2.4-2.8: below
    ``T_FINE``, but a gain of ``G_FINE`` or more needs only ``T_MIN``. Without the timing
    the unseen record of the same damper is predicted at 3.8 noise floors.
    """
    case = cases.make_case(100234, ('direction_asymmetry',), sensor_faults=None,
                           duration=12.0, measured_current=None)
    assert case.sensor['spec'].current == 'absent' and case.driver_contribution > 1.5
    est = diagnose.Diagnosis()
    res = est.fit([_record(case.columns)])
    step = [s for s in res.steps if s.get('stage') == 'fine timing (full rate)']
    assert len(step) == 1 and step[0].get('added') in diagnose.FINE
    stats = step[0]['candidates'][step[0]['added']]
    assert stats['gain_mse'] >= diagnose.G_FINE
    assert max(stats['t'], stats.get('t_active', 0.0)) < diagnose.T_FINE  # the old bar
    assert 'direction_asymmetry' in res.physical_causes
    unseen = case.unseen()
    assert est.score(_record(unseen.columns)) < 2.0 * cases.transfer_floor(case, unseen)


def test_a_spring_screened_on_top_of_a_named_loop_gets_the_restarts():
    """An algebraic damper behind a soft series spring (8.3e4 N/m), no velocity channel.

    Benchmark case (``bench_diagnose`` seed 1, case 297; truth integrator and sensors). A
    spring in front of the yield element draws a loop, and the loop is named first; the
    spring screened on top of it from one start gained 0.14 at fold t 1.5 and was refused
    (unseen / floor 9.2). Refitted with the restarts over k1 it gains 0.35 at t 10.
    """
    case = cases.make_case(100003 + 297, ('series_stiffness',), sensor_faults=None,
                           duration=12.0, measured_current=None)
    assert case.truth.k_series < 1e5 and 'velocity' not in case.columns
    res = diagnose.Diagnosis().fit([_record(case.columns)])
    assert 'series_stiffness' in res.physical_causes
    step = [s for s in res.steps if s.get('parent') == ['hysteresis']
            and 'series_stiffness' in s.get('candidates', {})]
    assert step and step[0]['candidates']['series_stiffness']['accepted']


def test_a_driver_dead_time_beyond_three_named_causes_is_named_last():
    """An algebraic damper with a partial loop and a direction asymmetry, current not measured.

    Benchmark case (``bench_diagnose`` seed 1, case 262; truth integrator and sensors). The
    selection names its three causes (loop, asymmetry, yield shape), which fills
    ``MAX_CAUSES``; the truth's driver then still delays the force of every command edge by
    a sample (1.7x the noise), and with no room left the full-rate timing was never judged:
    the unseen record of the same damper was predicted at 4.1 noise floors. The model stays
    above ``ROOM_FACTOR`` floors on its inner folds, so one more cause is looked for.
    """
    case = cases.make_case(100003 + 262, ('hysteresis', 'direction_asymmetry'),
                           sensor_faults=None, duration=12.0, measured_current=None)
    assert case.sensor['spec'].current == 'absent' and case.driver_contribution > 1.0
    est = diagnose.Diagnosis()
    res = est.fit([_record(case.columns)])
    step = [s for s in res.steps if s.get('stage', '').startswith('a cause beyond')]
    assert len(step) == 1 and step[0]['heldout_rms_over_floor'] > diagnose.ROOM_FACTOR
    assert step[0].get('added') == 'current_delay'
    phys = res.physical_causes
    assert len(phys) == diagnose.MAX_CAUSES + 1 and phys[-1] == 'current_delay'
    assert {'hysteresis', 'direction_asymmetry'} <= set(phys)
    assert res.final.eta['dead_time'] == pytest.approx(1e-3, abs=0.5e-3)
    unseen = case.unseen()
    assert est.score(_record(unseen.columns)) < 2.5 * cases.transfer_floor(case, unseen)


def test_an_arctan_shape_judged_with_the_saturation_it_trades_with():
    """An arctan-yield damper with a current saturation (and a thermal fade below the bar).

    Benchmark case (``bench_diagnose`` seed 0, case 173; truth integrator and sensors). The
    saturation shapes the same yield force as the sigmoid's tail. Stop 35: judged with the
    named causes' parameters held, the full-rate yield shape was refused and the tanh tail
    missed the unseen record (a faster programme) by 5.5 noise floors; judged with them
    refitted it was named there (3.07 floors). Stop 37: the saturated field drives the
    viscous term too and the curve's exponent is searched; the shape is then separable at
    the search rate already (named in the selection, gain 0.12 at t 2.7) and the unseen
    record comes to 2.66 floors.
    """
    case = cases.make_case(173, ('current_saturation', 'thermal_fade'), sensor_faults=None,
                           duration=12.0, measured_current=None)
    assert case.truth.shape == 'arctan'
    est = diagnose.Diagnosis()
    res = est.fit([_record(case.columns)])
    assert {'current_saturation', 'yield_shape'} <= set(res.physical_causes)
    assert res.final.params().yield_n > 0 and res.final.params().i_sat > 0
    unseen = case.unseen()
    assert est.score(_record(unseen.columns)) < 3.0 * cases.transfer_floor(case, unseen)


class _Final:
    def __init__(self, rms):
        self.heldout_mse = rms ** 2


def test_a_cause_beyond_the_limit_is_sought_only_where_the_model_stays_above_the_floor(
        monkeypatch):
    calls = []

    def stage(ds, final, chosen, cands, tick, label, t_min=diagnose.T_FINE, out=None):
        calls.append((tuple(chosen), tuple(cands), t_min))
        return final, chosen, {'stage': label, 'candidates': {}}

    monkeypatch.setattr(diagnose, '_fine_stage', stage)
    full = ['hysteresis', 'direction_asymmetry', 'yield_shape']
    physics = list(engine.EFFECTS)
    floor = noise.NoiseFloor(rms=10.0, nrmse=0.01, pairs=500, max_distance=0.02, method='test')
    for chosen, fl, rms in ((full[:2], floor, 40.0), (full, None, 40.0), (full, floor, 14.0)):
        out = diagnose._beyond_room(None, _Final(rms), chosen, physics, fl, lambda *a: None)
        assert out[2] is None and out[1] == chosen
    assert not calls
    final = _Final(16.0)
    out = diagnose._beyond_room(None, final, full + ['channel_delay'], physics, floor,
                                lambda *a: None)
    assert out[2]['heldout_rms_over_floor'] == pytest.approx(1.6)
    (chosen, cands, t_min), = calls
    assert t_min == diagnose.T_FINE and not set(cands) & set(chosen)
    assert 'current_delay' in cands and 'series_stiffness' in cands
    assert all(diagnose.compatible(list(chosen), e) for e in cands)


def _unseen_over_floor(case, fit):
    unseen = case.unseen()
    rec = _record(unseen.columns)
    m = np.asarray(rec.mask, dtype=bool)
    pred = engine.simulate(rec, fit.params(), fit.dynamics(), **fit.channel)
    rms = np.sqrt(np.mean((rec.force[m] - pred[m]) ** 2)) / np.std(rec.force[m])
    return rms / cases.transfer_floor(case, unseen)


def test_an_exponential_magnetisation_curve_is_fitted_by_the_curve_exponent():
    """The truth's field saturates as ``i_s (1 - exp(-i / i_s))`` (truth rig, clean sensors).

    Not the fit's tanh nor its algebraic family: the curve's exponent (``sat_n``) is searched
    jointly with ``i_s`` and brings the fitted curve nearer. Three strong saturations
    (``i_s`` = 0.25-0.34 A of 1 A): held-out MSE 4-12 % lower than the tanh curve's, and every
    unseen record better predicted (measured 1.44 -> 1.30, 3.01 -> 2.98, 1.97 -> 1.83 floors).
    """
    for seed in (11, 12, 13):
        case = cases.make_case(seed, ('current_saturation',), sensor_faults=(), duration=12.0,
                               shape='bingham_tanh', strength=1.0, measured_current=False)
        ds = engine.Dataset([_record(case.columns)])
        tanh = engine.fit(ds, ('current_saturation',), fixed=('sat_n',))
        curve = engine.fit(ds, ('current_saturation',))
        assert tanh.params().sat_n == 0.0 and curve.params().sat_n > 0.0, seed
        assert curve.heldout_mse < 0.97 * tanh.heldout_mse, seed
        assert _unseen_over_floor(case, curve) < _unseen_over_floor(case, tanh), seed


def test_a_force_channel_delay_beside_a_loop_is_judged_against_the_loop_without_it():
    """Two Bouc-Wen dampers (truth integrator), judged at the full rate on inner folds.

    Seed-1 case 37 of the benchmark (a 3.7 ms dead time, no channel delay): the selection
    had ended in a 2.3 ms force-channel delay beside a loop at share 0.65 with ``r_h`` at
    its bound (unseen 2.84 floors); the loop fitted anew without the delay is far better on
    the held-out folds, the delay is dropped and the unseen record comes to 1.27 floors.
    Seed-1 case 51 (a real 2.4 ms channel delay): the delay gains 97 % and stays.
    """
    case = cases.make_case(100040, ('current_delay',), sensor_faults=None, duration=12.0,
                           measured_current=None)
    assert 'channel_delay' not in case.sensor['spec'].faults
    ds = engine.Dataset([_record(case.columns)], outer=True)
    chosen = ['channel_delay', 'hysteresis', 'current_delay']
    trapped = engine.fit(ds, tuple(chosen), new=(), sweeps=1, start_eta={
        'delay': 2.3e-3, 'x_h': 8.3e-5, 'hyst_weight': 0.65, 'hyst_n': 2.3, 'hyst_r': 0.5,
        'dead_time': 2e-3, 'v_y': 0.0078})
    final, kept, step = diagnose._delay_or_loop(ds, trapped, chosen, lambda *a: None)
    assert kept == ['hysteresis', 'current_delay'] and step['dropped'] == ['channel_delay']
    assert final.heldout_mse < 0.5 * trapped.heldout_mse
    assert _unseen_over_floor(case, trapped) > 2.0
    assert _unseen_over_floor(case, final) < 1.5

    case = cases.make_case(100054, ('direction_asymmetry',), sensor_faults=None, duration=12.0,
                           measured_current=None)
    delay = case.sensor['spec'].force_delay
    assert delay > 2e-3
    t = case.truth
    ds = engine.Dataset([_record(case.columns)], outer=True)
    chosen = ['channel_delay', 'hysteresis', 'direction_asymmetry']
    with_delay = engine.fit(ds, tuple(chosen), new=(), start_eta={
        'delay': delay, 'x_h': 1.0 / t.bw_a, 'hyst_n': t.bw_n,
        'hyst_r': t.bw_gamma / (t.bw_beta + t.bw_gamma), 'rho': t.rho})
    final, kept, step = diagnose._delay_or_loop(ds, with_delay, chosen, lambda *a: None)
    assert kept == chosen and final is with_delay
    assert step['candidates']['channel_delay']['gain_mse'] > 0.5


@pytest.mark.parametrize('faults', [(), ('derived_velocity',)])
def test_the_prediction_velocity_is_nearer_the_truth_where_the_yield_turns(faults):
    """Truth records with a noisy measured velocity: ``for_prediction``'s velocity errs less.

    The truth's velocity is its own (the derivative of the spline through the programme); the
    records carry white velocity noise (0.5-2 % of its RMS) beside a noisy displacement, or
    a velocity the rig took as the derivative of that displacement (``derived_velocity``).
    Near the yield (|v| < 10 mm/s, usable samples) and over the record, against the fit's
    velocity (one low-pass at the motion band).
    """
    near, whole = [], []
    for seed in range(6):
        case = cases.make_case(seed, (), sensor_faults=faults, duration=12.0)
        rec = _record(case.columns)
        pred = dataio.for_prediction(rec)
        assert rec.velocity_pred is not None and pred.velocity is rec.velocity_pred
        v = case.clean['velocity'][case.sensor['info']['rows']]
        m = rec.mask & (np.abs(v) < 0.01)

        def rms(a, mm):
            return np.sqrt(np.mean((a - v)[mm] ** 2))
        near.append(rms(pred.velocity, m) / rms(rec.velocity, m))
        whole.append(rms(pred.velocity, rec.mask) / rms(rec.velocity, rec.mask))
    near, whole = np.array(near), np.array(whole)
    assert np.exp(np.mean(np.log(near))) < 0.97 and near.max() < 1.05
    assert np.exp(np.mean(np.log(whole))) < 0.95 and whole.max() < 1.0


def test_the_local_fits_bring_the_prediction_velocity_nearer_than_the_ladder_alone():
    """Truth records, a measured velocity with white noise: the local fits against the ladder.

    ``sensors.directional_velocity`` (the Butterworth ladder fused with past, centred and
    future local quadratic fits) against the ladder alone (``sensors.ici_lowpass``, the
    prediction velocity before stop 43) on the same fused rate. The truth's reversals turn
    against its yield force; measured at stop 43 on seeds 0-11: 0.54-0.88x near the yield,
    0.61-0.86x over the record.
    """
    near, whole = [], []
    for seed in range(6):
        case = cases.make_case(seed, (), sensor_faults=(), duration=12.0)
        rec = _record(case.columns)
        assert 'local quadratic fits' in rec.velocity_source
        x, dt = rec.displacement, rec.dt
        raw = np.asarray(case.columns['velocity'], dtype=float)
        fused, fc = sensors.fuse_velocity(x, raw, dt)
        noise = sensors.measured_velocity_noise(x, raw, dt, fc)
        ladder, _ = sensors.ici_lowpass(fused, dt, sensors.motion_band(fused, dt)[0], noise)
        v = case.clean['velocity'][case.sensor['info']['rows']]
        m = rec.mask & (np.abs(v) < 0.01)

        def rms(a, mm):
            return np.sqrt(np.mean((a - v)[mm] ** 2))
        near.append(rms(rec.velocity_pred, m) / rms(ladder, m))
        whole.append(rms(rec.velocity_pred, rec.mask) / rms(ladder, rec.mask))
    assert np.exp(np.mean(np.log(near))) < 0.8 and max(near) < 0.95
    assert np.exp(np.mean(np.log(whole))) < 0.85 and max(whole) < 0.95


def test_a_saved_model_predicts_with_the_prediction_velocity():
    """``model_io.predict`` takes the same velocity as ``Diagnosis.predict`` (not the fit's)."""
    from mr_suspension.core.extended import ExtendedDamperParams
    from mr_suspension.identification import model_io

    rec = _record(cases.make_case(0, (), sensor_faults=(), duration=12.0).columns)
    assert rec.velocity_pred is not None
    params = ExtendedDamperParams(c0=800.0, c1=900.0, fy0=50.0, fy1=600.0, v_y=0.01)
    dyn = {'dead_time': 0.0, 'tau_rise': 0.0, 'tau_fall': 0.0}
    model = model_io.model_dict(params, dyn, (), 'current')
    got = model_io.predict(model, rec)
    np.testing.assert_array_equal(got, engine.simulate(dataio.for_prediction(rec), params, dyn))
    assert not np.array_equal(got, engine.simulate(rec, params, dyn))


def test_a_yield_shape_that_ties_hedges_the_prediction_beyond_the_fitted_rates():
    """Benchmark seed 1 case 53: arctan damper, asymmetry, training rates to 3 v_y only.

    The held-out folds cannot tell the arctan tail from tanh plus a steeper viscous slope
    (shape not named), and an unseen record at 2.4x the rates was missed by 3.2 noise
    floors. The tied shape is kept as a hedge: predict returns the mean of both models.
    """
    case = cases.make_case(100003 + 53, ('current_lag_asymmetric', 'direction_asymmetry'),
                           sensor_faults=None, duration=12.0, measured_current=None)
    assert case.truth.shape == 'arctan'
    est = diagnose.Diagnosis()
    rec = _record(case.columns)
    res = est.fit([rec])
    assert 'yield_shape' not in res.causes and res.hedge is not None
    assert 'yield_shape' in res.hedge.effects and res.hedge.eta['yield_n'] > 0
    assert res.predictors == (res.final, res.hedge)
    unseen = case.unseen()
    ur = _record(unseen.columns, 'unseen')
    pr = diagnose.denoise_current(dataio.for_prediction(ur), res.driver)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')  # the unseen record leaves the fitted range
        f = est.predict(ur)
    alone = [engine.simulate(pr, m.params(), m.dynamics(), **m.channel) for m in res.predictors]
    np.testing.assert_allclose(f, 0.5 * (alone[0] + alone[1]), rtol=1e-12, atol=1e-9)
    m = ur.mask
    err = [np.sqrt(np.mean((ur.force[m] - g[m]) ** 2)) for g in (f, alone[0])]
    floor = cases.transfer_floor(case, unseen) * np.std(ur.force[m])
    assert err[0] < 0.85 * err[1] and err[0] < 3.0 * floor
    # On the fitted rates the two agree: the mean costs nothing held out.
    ho = res.heldout
    assert ho['hedged_nrmse'] < 1.02 * ho['extended_nrmse']
    rep, model = report.build(res, [rec])
    assert rep['extended']['hedge']['parameters']['yield_n'] == res.hedge.eta['yield_n']
    assert 'Prediction hedge' in report.markdown(rep, [])
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        np.testing.assert_allclose(model_io.predict(model, ur), f, rtol=1e-9, atol=1e-6)
