"""Learned reference (``identification.reference``): accuracy, threads, rates, bad input.

Truths come from ``mr_suspension.truth`` (``truthcases``: its own integrator and sensors), and
the noise floor from the truth's own noise, never from the reference.
"""

from dataclasses import replace
import time

import numpy as np
import pytest
from sklearn.ensemble import HistGradientBoostingRegressor
from threadpoolctl import threadpool_info, threadpool_limits
import truthcases

from mr_suspension.identification import data as dataio
from mr_suspension.identification import reference

TRAIN = 0.7  # the first 70 % trains, the last 30 % is held out


@pytest.fixture(scope='module')
def loop_case():
    """Return a Bouc-Wen damper's case and record (its pre-yield loop has a memory).

    One stroke repeated at cycled currents (``single``), so the last 30 % repeats inputs the
    first 70 % holds; motion and current measured without noise, an ideal driver, no sensor
    fault: the force noise is the floor a perfect model of the inputs reaches.
    """
    case = truthcases.case(36005, (), shape='bouc_wen', sensor_faults=(), kind='single',
                           duration=30.0, measured_current=False, driver_tau=0.0,
                           input_noise=False)
    return case, truthcases.record(case.columns)


def _split(rec):
    train = np.arange(rec.n) < int(TRAIN * rec.n)
    return train, ~train & rec.mask


def _rms(a):
    return float(np.sqrt(np.mean(np.square(a))))


def test_reference_reaches_the_noise_floor_on_repeated_inputs(loop_case):
    """Held out within 2x the truth's noise; without the history (1 ms lags) far worse."""
    case, rec = loop_case
    train, test = _split(rec)
    assert np.abs(rec.velocity[test]).max() <= 1.02 * np.abs(rec.velocity[train]).max()
    assert set(np.unique(rec.i_in[test])) <= set(np.unique(rec.i_in[train]))
    std = np.std(rec.force[test])
    floor = _rms((rec.force - case.sensor['info']['reference_force'])[test]) / std
    ref = reference.fit_reference([rec], [train])
    got = _rms((rec.force - ref.predict(rec))[test]) / std
    short = reference.fit_reference([rec], [train], lags=(1e-3,) * 3)
    got_short = _rms((rec.force - short.predict(rec))[test]) / std
    print(f'\nheld-out NRMSE {got:.4f}, 1 ms history only {got_short:.4f}, '
          f'noise floor {floor:.4f}')
    assert ref.n_train == np.count_nonzero(train & rec.mask)
    assert got < 2.0 * floor
    assert got_short > 2.0 * got


def test_predictions_do_not_depend_on_the_thread_count(loop_case):
    """Bit-identical under 1 and 2 threads: the reference, and the estimator left to them."""
    _, rec = loop_case
    train, _ = _split(rec)
    x = reference.features(rec)
    pred, raw = [], []
    for n in (1, 2):
        with threadpool_limits(n):
            if n == 2 and not any(d['user_api'] == 'openmp' and d['num_threads'] == 2
                                  for d in threadpool_info()):
                pytest.skip('no OpenMP runtime with 2 threads here')
            pred.append(reference.fit_reference([rec], [train]).predict(rec))
            # fit_reference runs one thread for speed; the estimator itself must not care.
            # 3 trees: on busy cores a threaded fit spins at every node (25 trees took 60 s)
            est = HistGradientBoostingRegressor(**{**reference.PARAMS, 'max_iter': 3})
            raw.append(est.fit(x[train], rec.force[train]).predict(x))
    assert np.array_equal(pred[0], pred[1])
    assert np.array_equal(raw[0], raw[1])


def test_rows_predicts_only_where_asked(loop_case):
    _, rec = loop_case
    train, test = _split(rec)
    ref = reference.fit_reference([rec], [train])
    full = ref.predict(rec)
    part = ref.predict(rec, test)
    assert np.array_equal(part[test], full[test]) and np.all(np.isnan(part[~test]))
    assert np.all(np.isnan(ref.predict(rec, np.zeros(rec.n, dtype=bool))))


def test_lags_are_physical_times(loop_case):
    """A 1 kHz reference predicts a 200 Hz copy (every 5th sample) about as well.

    Lags counted in samples would look 5x further back at 200 Hz (the control).
    """
    case, rec = loop_case
    q = 5
    low = dataio.decimate(rec, q)
    assert low.dt == pytest.approx(q * rec.dt)
    k_hi, k_lo = reference.lag_samples(rec.dt), reference.lag_samples(low.dt)
    assert k_hi == (1, 2, 5, 10, 23, 50) and k_lo[-1] == 10
    for t, k in zip(reference.lag_times(), k_lo):
        assert abs(k * low.dt - t) <= 0.5 * low.dt + 1e-12 or (k == 1 and t < 0.5 * low.dt)
    names = reference.feature_names()
    f_hi, f_lo = reference.features(rec), reference.features(low)
    assert f_hi.shape[1] == f_lo.shape[1] == len(names)
    for name in ('displacement@-50ms', 'velocity@-50ms', 'input@-50ms', 'input@-10.5ms'):
        j = names.index(name)  # 50 and 10 samples at 1 kHz, 10 and 2 at 200 Hz
        assert np.array_equal(f_lo[10:, j], f_hi[::q][10:, j])
    train, test = _split(rec)
    ref = reference.fit_reference([rec], [train])
    std = np.std(rec.force[test])
    err_hi = _rms((rec.force - ref.predict(rec))[test]) / std
    p_lo = ref.predict(low)
    t_lo = test[::q]
    err_lo = _rms((low.force - p_lo)[t_lo]) / std
    diff = _rms((p_lo - ref.predict(rec)[::q])[t_lo]) / std
    by_samples = replace(ref, lags=tuple(q * t for t in ref.lags))
    err_samples = _rms((low.force - by_samples.predict(low))[t_lo]) / std
    print(f'\nheld-out NRMSE 1 kHz {err_hi:.4f}, 200 Hz {err_lo:.4f} (difference {diff:.4f}), '
          f'lags in samples {err_samples:.4f}')
    assert err_lo < 1.5 * err_hi
    assert diff < err_hi
    assert err_samples > 3.0 * err_lo


def test_bad_input_raises_with_a_message(loop_case):
    _, rec = loop_case
    few = np.zeros(rec.n, dtype=bool)
    few[100:500] = True
    with pytest.raises(ValueError, match=r'400 usable training samples.*need at least 500'):
        reference.fit_reference([rec], [few])
    dark = replace(rec, mask=np.zeros(rec.n, dtype=bool))
    with pytest.raises(ValueError, match='0 usable training samples'):
        reference.fit_reference([dark], [np.ones(rec.n, dtype=bool)])
    with pytest.raises(ValueError, match='one train mask per record'):
        reference.fit_reference([rec, rec], [np.ones(rec.n, dtype=bool)])
    with pytest.raises(ValueError, match='mask has shape'):
        reference.fit_reference([rec], [np.ones(rec.n - 1, dtype=bool)])
    with pytest.raises(ValueError, match='at least 3 lags'):
        reference.fit_reference([rec], [np.ones(rec.n, dtype=bool)], lags=(0.01, 0.02))
    # NaN at every 4th sample: every row reads one at some lag (lags 1, 2, 5, 10, 23, 50)
    v = rec.velocity.copy()
    v[::4] = np.nan
    mask = rec.mask.copy()
    mask[::4] = False
    holes = replace(rec, velocity=v, mask=mask)
    with pytest.raises(ValueError, match='non-finite'):
        reference.fit_reference([holes], [np.ones(rec.n, dtype=bool)])


def test_nan_in_masked_samples_is_left_out(loop_case):
    """Masked NaN samples: the rows reading them are not trained on; predictions finite."""
    _, rec = loop_case
    train, _ = _split(rec)
    k_x, k_f = 5000, 9000
    x, f, mask = rec.displacement.copy(), rec.force.copy(), rec.mask.copy()
    x[k_x] = np.nan
    f[k_f] = np.nan
    mask[[k_x, k_f]] = False
    bad = replace(rec, displacement=x, force=f, mask=mask)
    ref = reference.fit_reference([bad], [train])
    reads = k_x + np.array((0,) + reference.lag_samples(rec.dt))
    use = train & mask
    use[reads] = False
    assert reads.size == 7 and k_f not in reads
    assert ref.n_train == np.count_nonzero(use) == np.count_nonzero(train & rec.mask) - 8
    pred = ref.predict(bad)
    assert np.all(np.isfinite(pred))
    assert np.isnan(reference.features(bad)[reads]).any(axis=1).all()


def test_score_blocks_per_block_mse(loop_case):
    _, rec = loop_case
    train, test = _split(rec)
    idx = np.flatnonzero(test)
    offset = np.zeros(rec.n)
    for b, part in enumerate(np.array_split(idx, 4)):
        offset[part] = b + 1.0
    got = reference.score_blocks([rec.force - offset], [rec], [test], 4)
    assert got.shape == (1, 4)
    np.testing.assert_allclose(got[0], [1.0, 4.0, 9.0, 16.0])
    ref = reference.fit_reference([rec], [train])
    np.testing.assert_array_equal(reference.score_blocks(ref, [rec], [test], 3),
                                  reference.score_blocks([ref.predict(rec)], [rec], [test], 3))
    empty = reference.score_blocks([rec.force], [rec], [np.zeros(rec.n, dtype=bool)], 2)
    assert np.all(np.isnan(empty))


def test_sixty_seconds_at_one_kilohertz():
    """Fit and predict 60 s at 1 kHz (the time is printed, not asserted: machines differ)."""
    case = truthcases.case(36100, ('current_lag', 'hysteresis'), sensor_faults=(),
                           duration=60.0)
    rec = truthcases.record(case.columns)
    assert rec.n == 60_000 and rec.dt == pytest.approx(1e-3)
    train, test = _split(rec)
    t0 = time.perf_counter()
    ref = reference.fit_reference([rec], [train])
    t1 = time.perf_counter()
    pred = ref.predict(rec)
    t2 = time.perf_counter()
    nrmse = _rms((rec.force - pred)[test]) / np.std(rec.force[test])
    print(f'\n60 s at 1 kHz: fit {t1 - t0:.2f} s ({ref.n_train} rows), predict {t2 - t1:.2f} s '
          f'({rec.n} rows), total {t2 - t0:.2f} s; held-out NRMSE {nrmse:.4f} '
          f'(noise floor {case.floor_nrmse:.4f})')
    assert ref.n_train == np.count_nonzero(train & rec.mask)
    assert pred.shape == (rec.n,) and np.all(np.isfinite(pred))
