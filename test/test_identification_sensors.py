"""Sensor findings on hand-made rig records: stamps, dropouts, clipping, spikes, velocity."""

from pathlib import Path
import warnings

import numpy as np
import pytest
import truthcases

from mr_suspension.identification import data as dataio
from mr_suspension.identification import sensors

SHARED = Path(__file__).resolve().parents[1].parent / 'shared'
VRTHS = SHARED / 'data' / 'vrths'


def _motion(t):
    """Displacement [m] and its exact derivative: two sines (1.3 and 3.1 Hz)."""
    w1, w2 = 2 * np.pi * 1.3, 2 * np.pi * 3.1
    x = 0.008 * np.sin(w1 * t) + 0.002 * np.sin(w2 * t + 0.4)
    v = 0.008 * w1 * np.cos(w1 * t) + 0.002 * w2 * np.cos(w2 * t + 0.4)
    return x, v


def _cols(t, seed=0, noise=5.0):
    x, v = _motion(t)
    rng = np.random.default_rng(seed)
    f = 1500 * v + 400 * np.tanh(v / 0.02) + noise * rng.standard_normal(t.size)
    return {'time': t, 'displacement': x, 'velocity': v, 'force': f,
            'current_command': np.full(t.size, 0.5)}


def _build(cols, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        return dataio.build_record('hand', cols, dataio.LoadOptions(**kw))


def _names(rec):
    return [f['finding'] for f in rec.findings]


def _only_edges_masked(rec):
    """Every sample usable except the low-passed velocity's one-sided ends, all masked."""
    e = rec.velocity_edge
    inner = rec.mask[e:rec.n - e]
    return bool(inner.all() and not rec.mask[:e].any() and not rec.mask[rec.n - e:].any())


def test_clean_record_has_no_finding():
    rec = _build(_cols(np.arange(8000) * 1e-3))
    assert rec.findings == ()
    assert rec.mask.all() and rec.velocity_source == 'measured'
    np.testing.assert_array_equal(rec.stamps, rec.time)


def test_rounded_stamps_at_3khz_recover_the_rate_without_resampling():
    n = 60000
    t0 = 12.3456
    stamps = np.round(t0 + np.arange(n) / 3000.0, 4)      # 0.1 ms rounding at 3 kHz
    assert len(np.unique(np.round(np.diff(stamps), 9))) == 2
    base, fnd = sensors.uniform_time(stamps)
    assert fnd['finding'] == 'stamp_rounding' and fnd['action'] == 'corrected'
    assert fnd['quantum'] == pytest.approx(1e-4, rel=1e-6)
    assert not base.resampled and base.time.size == n
    assert abs(base.dt * 3000.0 - 1.0) < 1e-9
    cols = _cols(np.arange(n) / 3000.0)
    cols['time'] = stamps
    rec = _build(cols)
    assert rec.n == n and _names(rec) == ['stamp_rounding']
    assert abs(rec.dt * 3000.0 - 1.0) < 1e-9
    np.testing.assert_array_equal(rec.force, cols['force'])
    np.testing.assert_allclose(rec.stamps, stamps - stamps[0], atol=0)


def test_missing_rows_are_masked_on_the_uniform_grid():
    t = np.arange(6000) * 1e-3
    cols = _cols(t)
    gone = np.r_[1000:1005, 4200]
    keep = np.setdiff1d(np.arange(t.size), gone)
    rec = _build({k: v[keep] for k, v in cols.items()})
    assert rec.n == t.size and rec.dt == pytest.approx(1e-3, rel=1e-12)
    np.testing.assert_array_equal(np.flatnonzero(~rec.mask), gone)
    (fnd,) = rec.findings
    assert fnd['finding'] == 'dropout' and fnd['samples'] == 6 and fnd['runs'] == 2
    np.testing.assert_allclose(rec.force[keep], cols['force'][keep])
    np.testing.assert_allclose(rec.stamps, t[keep])
    stamps, f = dataio.at_stamps(rec, rec.force)
    np.testing.assert_array_equal(f, cols['force'][keep])


def test_clipped_load_cell_is_masked():
    cols = _cols(np.arange(8000) * 1e-3)
    rail = 0.7 * cols['force'].max()
    over = cols['force'] >= rail
    assert over.sum() > 300
    cols['force'] = np.minimum(cols['force'], rail)
    rec = _build(cols)
    (fnd,) = rec.findings
    assert fnd['finding'] == 'clipping' and fnd['channel'] == 'force'
    assert fnd['action'] == 'excluded' and fnd['rail_high'] == rail
    np.testing.assert_array_equal(~rec.mask, over)


def test_nan_and_frozen_runs_are_masked():
    cols = _cols(np.arange(8000) * 1e-3)
    f = cols['force'].copy()
    f[2000:2050] = np.nan
    f[6000:6200] = f[5999]                  # logger froze for 0.2 s while the damper moved
    cols['force'] = f
    rec = _build(cols)
    (fnd,) = rec.findings
    assert fnd['finding'] == 'dropout' and fnd['nan_samples'] == 50
    assert fnd['frozen_runs'] == 1
    bad = np.flatnonzero(~rec.mask)
    expect = np.r_[2000:2050, 6000:6200]
    assert set(expect) <= set(bad) and len(bad) - len(expect) <= 1    # 5999 holds the value
    assert np.all(np.isfinite(rec.force))


def test_a_hold_is_a_hold_under_round_off():
    """A frozen run scaled by 1 + 1e-9 u per sample (round-off of a unit conversion) is held.

    The finding, its mask and the velocity bridged over it are those of the exact hold; a
    24-bit converter's step (6e-8 of full scale) is never taken for a repeat.
    """
    cols = _cols(np.arange(8000) * 1e-3)
    f = cols['force'].copy()
    f[6000:6200] = f[5999]
    cols['force'] = f
    exact = _build(cols)
    rng = np.random.default_rng(5)
    blurred = {k: (v if k == 'time' else v * (1.0 + 1e-9 * rng.uniform(-1, 1, v.size)))
               for k, v in cols.items()}
    rec = _build(blurred)
    assert _names(rec) == _names(exact) == ['dropout']
    np.testing.assert_array_equal(rec.mask, exact.mask)
    span = 2.0 ** 24
    steps = (np.arange(1000) + 2.0 ** 23) / span   # consecutive codes near full scale
    assert not sensors.repeats(steps).any()
    assert sensors.repeats(np.array([1.0, 1.0, np.nan, np.nan, 0.0, 0.0])).tolist() == \
        [True, False, False, False, True]


def test_velocity_skewed_by_half_a_millisecond_is_replaced():
    t = np.arange(10000) * 1e-3
    cols = _cols(t)
    _, v_late = _motion(t - 0.5e-3)
    v, fnd = sensors.velocity_check(cols['displacement'], v_late, 1e-3)
    assert fnd['finding'] == 'velocity_inconsistent'
    assert fnd['shift_samples'] == pytest.approx(0.5, abs=0.05)
    assert fnd['gain'] == pytest.approx(1.0, abs=0.01)
    v0, none = sensors.velocity_check(cols['displacement'], cols['velocity'], 1e-3)
    assert none is None and v0 is cols['velocity']
    cols['velocity'] = v_late
    rec = _build(cols)
    assert _names(rec) == ['velocity_inconsistent']
    assert rec.velocity_source.startswith('derived') and _only_edges_masked(rec)
    cut = sensors.motion_cutoff(cols['displacement'], 1e-3)  # the motion band's (two sines)
    assert 3.1 * sensors.BAND_FACTOR <= cut < 100.0
    np.testing.assert_allclose(rec.velocity,
                               dataio.derive_velocity(cols['displacement'], 1e-3, cut, 4))


def test_velocity_derived_from_a_noisy_displacement_is_replaced():
    t = np.arange(10000) * 1e-3
    cols = _cols(t)
    rng = np.random.default_rng(3)
    x = cols['displacement'] + 2e-5 * rng.standard_normal(t.size)
    cols['displacement'] = x
    cols['velocity'] = np.gradient(x, 1e-3)        # the user's own raw derivative
    rec = _build(cols)
    (fnd,) = rec.findings
    assert fnd['finding'] == 'velocity_inconsistent' and fnd['noise_ratio'] > 0.05
    assert abs(fnd['shift_samples']) < 0.3
    assert rec.velocity_source.startswith('derived')
    _, v_true = _motion(t)
    inner = slice(300, -300)
    err_rec = np.std(rec.velocity[inner] - v_true[inner])
    assert err_rec < 0.3 * np.std(cols['velocity'][inner] - v_true[inner])


def test_velocity_in_wrong_units_or_sign_is_an_error():
    t = np.arange(5000) * 1e-3
    x, v = _motion(t)
    with pytest.raises(dataio.DataError, match='check --units'):
        sensors.velocity_check(x, 10.0 * v, 1e-3)
    with pytest.raises(dataio.DataError, match='opposite sign'):
        sensors.velocity_check(x, -v, 1e-3)


def test_velocity_gain_off_by_ten_percent_is_corrected():
    """Not a unit (10x, 1000x) or sign error: a miscalibrated channel, replaced."""
    t = np.arange(5000) * 1e-3
    x, v = _motion(t)
    used, fnd = sensors.velocity_check(x, 1.1 * v, 1e-3)
    assert fnd['finding'] == 'velocity_inconsistent' and fnd['action'] == 'corrected'
    assert fnd['gain'] == pytest.approx(1.1, abs=0.01)
    assert np.sqrt(np.mean(used ** 2)) == pytest.approx(np.sqrt(np.mean(v ** 2)), rel=0.03)


def test_spikes_are_excluded_if_few_and_an_error_if_many():
    cols = _cols(np.arange(8000) * 1e-3)
    cols['force'][5000] = cols['force'][5000] + 20 * np.ptp(cols['force'])
    cols['force'][3000] = 1e300
    rec = _build(cols)
    (fnd,) = rec.findings
    assert fnd['finding'] == 'spike' and fnd['nonphysical'] == 1 and fnd['outliers'] == 1
    np.testing.assert_array_equal(np.flatnonzero(~rec.mask), [3000, 5000])
    assert np.max(np.abs(rec.force)) < 2 * np.max(np.abs(np.delete(cols['force'], [3000, 5000])))
    cols['force'][::50] = 1e300
    with pytest.raises(dataio.DataError, match='non-physical'):
        _build(cols)


def test_jittery_and_irregular_stamps():
    rng = np.random.default_rng(1)
    t = np.arange(5000) * 1e-3
    _, fnd = sensors.uniform_time(t + 2e-5 * rng.standard_normal(t.size))
    assert fnd['finding'] == 'stamp_jitter'
    t_irr = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, 5000))
    base, fnd = sensors.uniform_time(t_irr)
    assert fnd['finding'] == 'irregular_sampling' and base.resampled
    rec = _build(_cols(t_irr))
    assert 'irregular_sampling' in _names(rec) and rec.stamps.size == 5000
    stamps, f = dataio.at_stamps(rec, rec.time)
    np.testing.assert_allclose(f, stamps, atol=1e-12)


@pytest.mark.parametrize('name', ['10mm1Hz0x25A.txt', '25mm0x1Hz1A.txt', '2mm5Hz0A.txt',
                                  '5mm3Hz0x5A.txt'])
def test_vrths_sine_files_only_report_their_backward_difference_velocity(name):
    """The vrths velocity column is (x_k - x_{k-1}) / dt: half a sample late, nothing else."""
    path = VRTHS / 'preprocessed_sine' / name
    raw = np.loadtxt(path)
    dt = raw[1, 0] - raw[0, 0]
    backward = np.diff(raw[:, 1]) / dt
    assert np.max(np.abs(raw[1:, 2] - backward)) < 1e-3 * np.max(np.abs(raw[:, 2]))
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        (rec,) = dataio.load_records([path])
    assert _names(rec) == ['velocity_inconsistent'] and _only_edges_masked(rec)
    assert rec.findings[0]['shift_samples'] == pytest.approx(0.5, abs=0.05)


def test_vrths_earthquake_record_has_no_finding():
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        recs = dataio.load_records([VRTHS / 'validation' / 'validacion.mat'])
    assert all(r.findings == () and _only_edges_masked(r) for r in recs)


def test_package_generator_records_have_no_finding():
    """Fault-free records raise no data finding: the package's own generator and the truth rig.

    ``synthetic.make_record`` is kept here on purpose: the check is of its records, no fit.
    """
    from mr_suspension.identification import synthetic

    rec, _ = synthetic.make_record((), seed=4, duration=10.0)
    assert rec.findings == () and _only_edges_masked(rec)
    truth = truthcases.record(truthcases.case(29000, (), sensor_faults=(), duration=10.0).columns)
    assert truth.findings == () and _only_edges_masked(truth)


def test_motion_cutoff_keeps_the_motion_and_drops_white_noise():
    rate = 1000.0
    t = np.arange(int(20 * rate)) / rate
    x, v = _motion(t)
    rng = np.random.default_rng(4)
    noisy = v + 0.01 * np.std(v) * rng.standard_normal(t.size)
    cut = sensors.motion_cutoff(noisy, 1 / rate)
    assert cut is not None and 3.1 * sensors.BAND_FACTOR <= cut < 0.3 * rate
    smooth = sensors.smooth_velocity(noisy, 1 / rate, cut)
    inner = slice(1000, -1000)
    # Amplitude kept to 1 % at the motion's own frequencies, white noise cut > 3x.
    assert np.std((smooth - v)[inner]) < np.std((noisy - v)[inner]) / 3
    assert abs(np.dot(smooth[inner], v[inner]) / np.dot(v[inner], v[inner]) - 1) < 0.01
    # Broadband content up to the Nyquist rate or too few samples: no low-pass at all.
    assert sensors.motion_cutoff(rng.standard_normal(t.size), 1 / rate) is None
    assert sensors.motion_cutoff(noisy[:100], 1 / rate) is None


def test_measured_velocity_noise_above_the_motion_band_is_removed():
    rate = 1000.0
    t = np.arange(int(12 * rate)) / rate
    cols = _cols(t)
    _, v = _motion(t)
    rng = np.random.default_rng(5)
    cols['velocity'] = v + 0.015 * np.std(v) * rng.standard_normal(t.size)
    rec = _build(cols)
    assert 'velocity_inconsistent' not in _names(rec)  # 1.5 % noise: not a fault
    assert np.std(rec.velocity - v) < np.std(cols['velocity'] - v) / 3
    # The displacement is exact here: its derivative is the better rate at every frequency.
    assert rec.velocity_source.startswith('measured (fused with d(displacement)/dt')
    fixed = _build(cols, velocity_cutoff=400.0)  # the user's cut-off wins
    assert np.std(fixed.velocity - v) > 0.8 * np.std(cols['velocity'] - v)


def test_noisy_velocity_is_fused_with_the_displacement_below_the_wiener_crossover():
    rate = 1000.0
    dt = 1 / rate
    t = np.arange(int(12 * rate)) / rate
    cols = _cols(t)
    x, v = _motion(t)
    rng = np.random.default_rng(6)
    sx, sv = 5e-6, 0.015 * np.std(v)
    cols['displacement'] = x + sx * rng.standard_normal(t.size)
    cols['velocity'] = v + sv * rng.standard_normal(t.size)
    # Both noises white: the crossover is sigma_v / (2 pi sigma_x), from the spectra alone.
    fused, fc = sensors.fuse_velocity(cols['displacement'], cols['velocity'], dt)
    assert fc == pytest.approx(sv / (2 * np.pi * sx), rel=0.1)
    inner = slice(200, -200)
    raw = np.std((cols['velocity'] - v)[inner])
    # Wiener combination: sum over the band of S_v S_d / (S_v + S_d), S_d = w^2 S_x.
    f = np.linspace(0, rate / 2, 20001)
    s_v, s_d = 2 * sv ** 2 * dt, (2 * np.pi * f) ** 2 * 2 * sx ** 2 * dt
    ideal = np.sqrt(np.trapezoid(s_v * s_d / (s_v + s_d), f))
    # (over the whole band the measured velocity's own noise dominates: ideal ~ raw)
    assert np.std((fused - v)[inner]) < 1.1 * ideal < 1.1 * raw
    # The ends hold (the difference is padded by its mirror image, not its odd extension).
    ends = np.r_[(fused - v)[:200], (fused - v)[-200:]]
    assert np.sqrt(np.mean(ends ** 2)) < 2 * np.std((fused - v)[inner])
    # Through the loader, after the motion-band low-pass: far below the low-pass alone.
    rec = _build(cols)
    assert 'velocity_inconsistent' not in _names(rec)
    assert 'fused with d(displacement)/dt' in rec.velocity_source
    cut = sensors.motion_cutoff(cols['velocity'], dt)
    alone = sensors.smooth_velocity(cols['velocity'], dt, cut)
    assert np.std((rec.velocity - v)[inner]) < 0.3 * np.std((alone - v)[inner])
    # A clean displacement: the derivative wins; a clean velocity is left alone.
    assert sensors.fuse_velocity(x, cols['velocity'], dt)[1] > 0.45 * rate
    assert sensors.fuse_velocity(cols['displacement'], v, dt)[1] is None


def _slow_then_fast(rate, seconds=6.0):
    """Velocity [m/s] and displacement: a 1.5 Hz sine, then fast-reversing strokes.

    The strokes are ``0.1 tanh(8 sin(2 pi 2 t))`` (a smoothed square wave in velocity); the
    displacement is their integral on a 20x finer grid (trapezoid), sampled at ``rate``.
    """
    fine = 20
    tf = np.arange(int(2 * seconds * rate * fine)) / (rate * fine)
    slow = tf < seconds
    vf = np.where(slow, 0.1 * np.sin(2 * np.pi * 1.5 * tf),
                  0.1 * np.tanh(8 * np.sin(2 * np.pi * 2.0 * (tf - seconds))))
    xf = np.concatenate([[0.0], np.cumsum(0.5 * (vf[1:] + vf[:-1])) / (rate * fine)])
    return tf[::fine], vf[::fine], xf[::fine] - np.mean(xf)


def test_a_prediction_takes_a_quieter_velocity_than_the_fit():
    rate = 1000.0
    dt = 1 / rate
    t, v, x = _slow_then_fast(rate)
    rng = np.random.default_rng(8)
    cols = {'time': t, 'displacement': x + 3e-6 * rng.standard_normal(t.size),
            'velocity': v + 0.015 * np.std(v) * rng.standard_normal(t.size),
            'force': 1500 * v + 400 * np.tanh(v / 0.02) + 5 * rng.standard_normal(t.size),
            'current_command': np.full(t.size, 0.5)}
    rec = _build(cols)
    assert 'for predictions the ladder of zero-phase low-passes and local quadratic fits' in \
        rec.velocity_source
    # The fit's velocity: the fusion, then one cut-off for the whole record (the fast half's).
    fused, fc = sensors.fuse_velocity(cols['displacement'], cols['velocity'], dt)
    cut, _ = sensors.motion_band(fused, dt)
    whole = sensors.smooth_velocity(fused, dt, cut)
    np.testing.assert_allclose(rec.velocity, whole)
    pred = dataio.for_prediction(rec)
    assert pred.velocity_pred is None and pred.force is rec.force
    half = t.size // 2
    slow, fast = slice(300, half - 1000), slice(half + 1000, -300)
    err = pred.velocity - v
    ref = whole - v
    # The sine needs a few Hz: far less noise there; the strokes keep the record's band.
    assert np.std(err[slow]) < 0.6 * np.std(ref[slow])
    assert np.std(err[fast]) < 1.05 * np.std(ref[fast])
    # The Butterworth ladder in it is never wider than the record's band, which the ends
    # keep; windows and decimation carry
    # the prediction velocity along.
    noise = sensors.velocity_noise(cols['displacement'], cols['velocity'], dt, fc)
    _, cuts = sensors.ici_lowpass(fused, dt, cut, noise)
    assert cuts.max() == pytest.approx(cut) and np.median(cuts[slow]) < 0.5 * cut
    assert cuts[0] == cuts[-1] == pytest.approx(cut)
    piece = dataio.decimate(dataio.window(rec, 100, 5100), 2)
    np.testing.assert_array_equal(dataio.for_prediction(piece).velocity,
                                  rec.velocity_pred[100:5100:2])
    # A velocity the rig took as a central difference has no white noise: no second one.
    cols['velocity'] = np.gradient(cols['displacement'] + 2e-6 * rng.standard_normal(t.size),
                                   dt)
    assert not sensors.white_noise(cols['velocity'], dt)
    assert sensors.white_noise(fused - v, dt)
    # Its noise is the derivative of the displacement's when it differentiates the recorded
    # displacement (level within DERIV_TOL): a noise model, and a prediction velocity, still.
    cols['velocity'] = np.gradient(cols['displacement'], dt)
    e = sensors.measured_velocity_noise(cols['displacement'], cols['velocity'], dt)
    assert e is not None and e.size == t.size
    assert np.std(e) == pytest.approx(np.std(np.gradient(3e-6 * rng.standard_normal(t.size),
                                                         dt)), rel=0.15)
    assert 'for predictions the ladder of zero-phase low-passes and local quadratic fits' in \
        _build(cols).velocity_source
    # Coloured noise of another kind (a sensor's own 150 Hz low-pass) is not modelled.
    coloured = sensors.lowpass(0.05 * np.std(v) * rng.standard_normal(t.size), dt, 150.0)
    assert sensors.measured_velocity_noise(cols['displacement'], v + coloured, dt) is None


@pytest.mark.parametrize('faults, seed', [(('dropout_hold',), 0), (('dropout_hold',), 3),
                                          (('dropout_hold', 'no_velocity'), 0),
                                          (('dropout_hold', 'no_velocity'), 3),
                                          (('dropout_missing',), 2), (('dropout_missing',), 3)])
def test_motion_is_bridged_smoothly_over_gaps_and_frozen_frames(faults, seed):
    """Rig truth with frozen frames or missing rows (0.4-0.6 % of the samples).

    Bridged by straight lines (or left frozen), the velocity erred 4.2-24x more within 15
    samples of the gaps than elsewhere, and those few samples carried most of its error; a
    local cubic through the usable samples on both sides keeps the motion's slope.
    """
    from scipy import ndimage

    from mr_suspension.truth import cases

    case = cases.make_case(seed, (), sensor_faults=faults, duration=12.0)
    rec = _build(case.columns)
    truth = np.interp(rec.time, case.clean['time'] - case.clean['time'][0],
                      case.clean['velocity'])
    near = ndimage.binary_dilation(~rec.mask, iterations=15) & rec.mask
    far = rec.mask & ~near
    for m in (near, far):
        m[:300] = m[-300:] = False
    assert near.sum() > 100
    err = rec.velocity - truth
    assert np.sqrt(np.mean(err[near] ** 2)) < 3.3 * np.sqrt(np.mean(err[far] ** 2))


def test_motion_fill_keeps_a_cubic_and_leaves_usable_samples_alone():
    y = 1e-3 * np.arange(200.0) ** 3 / 200.0 ** 2
    mask = np.ones(200, dtype=bool)
    mask[50:60] = False
    mask[195:] = False  # at the end: one side only, a straight line's hold
    got = sensors.fill_motion(np.where(mask, y, 7.0), mask)
    np.testing.assert_allclose(got[:195], y[:195], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(got[195:], y[194])
    # Only the record's own unusable motion is bridged: a clipped load cell leaves it as read.
    t = np.arange(6000) / 1000.0
    cols = _cols(t)
    cols['force'] = np.clip(cols['force'], -0.8 * np.max(cols['force']), None)
    rec = _build(cols)
    assert not rec.mask.all()
    np.testing.assert_array_equal(rec.displacement, cols['displacement'])


def test_a_frozen_frame_is_found_however_short_its_runs():
    """All channels repeating their previous value at once, in runs of 1-4 samples."""
    t = np.arange(12000) * 1e-3
    cols = _cols(t)
    rng = np.random.default_rng(9)
    starts = rng.choice(np.arange(10, t.size - 10, 40), size=30, replace=False)
    held = np.zeros(t.size, dtype=bool)
    for s, ln in zip(starts, rng.integers(1, 5, size=starts.size)):
        held[s + 1:s + 1 + ln] = True
    idx = np.maximum.accumulate(np.where(held, 0, np.arange(t.size)))
    frozen = {k: (v[idx] if k != 'current_command' and k != 'time' else v)
              for k, v in cols.items()}
    # Each channel alone: runs shorter than MIN_RUN are never a single-channel fault.
    assert held.sum() > 30 and sensors.MIN_RUN > 4
    rec = _build(frozen)
    f = [f for f in rec.findings if f['channel'] == 'force, displacement, velocity']
    assert len(f) == 1 and f[0]['finding'] == 'dropout' and f[0]['samples'] == held.sum()
    np.testing.assert_array_equal(rec.mask, ~held)
    # Channels that repeat often on their own (coarse quantisation at slow motion) coincide
    # by chance: no finding.

    def repeating(p):
        rep = rng.uniform(size=t.size) < p
        rep[0] = False
        return rng.normal(size=t.size)[np.maximum.accumulate(np.where(rep, 0, np.arange(t.size)))]

    often = {'force': repeating(0.3), 'displacement': repeating(0.3)}
    assert sensors.frame_holds(often) == (None, None)
    assert sensors.frame_holds({'force': cols['force']}) == (None, None)


def test_heavy_clipping_at_both_rails_is_found():
    """15 % of the samples at the rails: their own runs must not set the chance level."""
    from mr_suspension.truth import cases

    case = cases.make_case(7, (), sensor_faults=('clipping',), duration=12.0,
                           measured_current=False, shape='bingham_tanh')
    force = case.columns['force']
    assert case.sensor['info']['clipped'] > 0.1 * force.size
    rec = _build(case.columns)
    (f,) = [f for f in rec.findings if f['finding'] == 'clipping']
    assert f['rail_high'] == force.max() and f['rail_low'] == force.min()
    e = rec.velocity_edge
    valid = np.array(case.sensor['info']['valid'], dtype=bool)
    valid[:e] = valid[valid.size - e:] = False
    np.testing.assert_array_equal(rec.mask, valid)


def test_a_derived_velocity_masks_its_one_sided_ends():
    t = np.arange(8000) * 1e-3
    x, v = _motion(t)
    cols = _cols(t)
    del cols['velocity']
    cols['displacement'] = x + 5e-6 * np.random.default_rng(3).standard_normal(t.size)
    rec = _build(cols)
    cut = sensors.motion_cutoff(cols['displacement'], 1e-3)
    assert rec.velocity_edge == int(np.ceil(0.5 / (cut * 1e-3))) > 0
    assert _only_edges_masked(rec) and 'one-sided' in rec.velocity_source
    assert dataio.velocity_edge(None, 1e-3, 8000) == 0
    assert dataio.velocity_edge(20.0, 1e-3, 500) == 0  # too short to spare them


def test_the_masked_velocity_ends_are_where_a_derived_velocity_errs():
    """Independent truth records without a velocity channel (truth integrator and sensors).

    The zero-phase derivative's first and last samples see one side only: pooled over six
    records their error is several times that of the rest (0.9-17 mm/s at the end samples
    against 0.2-0.6 mm/s RMS inside), and those are the samples the mask drops.
    """
    from mr_suspension.truth import cases

    edge, inner = [], []
    for seed in range(6):
        case = cases.make_case(seed, (), sensor_faults=('no_velocity',), duration=12.0,
                               measured_current=False)
        rec = _build(case.columns)
        rows = case.sensor['info'].get('rows')
        truth = case.clean['velocity'] if rows is None else case.clean['velocity'][rows]
        e = rec.velocity - truth
        k = rec.velocity_edge
        assert k > 0 and _only_edges_masked(rec)
        edge.append(np.r_[e[:k], e[rec.n - k:]])
        inner.append(e[k:rec.n - k])
    rms_edge = np.sqrt(np.mean(np.concatenate(edge) ** 2))
    rms_inner = np.sqrt(np.mean(np.concatenate(inner) ** 2))
    assert rms_edge > 3.0 * rms_inner


def _kinked_strokes(rate, seconds=8.0, seed=0):
    """Velocity [m/s] that turns with a kink: a reversal against a yield force.

    Strokes of random length at 1-4 Hz whose acceleration jumps where the velocity crosses
    zero (slope 1.6x steeper after the crossing than before): ``v = a sin(phi)`` scaled by
    ``1.3`` on one sign and ``0.7`` on the other, written sample by sample (no filter).
    """
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * rate)) / rate
    f = np.repeat(rng.uniform(1.0, 4.0, size=int(seconds * 4) + 1), int(rate / 4))[:t.size]
    phi = 2 * np.pi * np.cumsum(f) / rate
    s = np.sin(phi)
    return t, 0.08 * s * np.where(s > 0, 1.3, 0.7)


def test_directional_velocity_keeps_the_kink_of_a_reversal():
    """One-sided windows keep a kinked reversal that every symmetric low-pass blurs.

    Truth: ``_kinked_strokes`` with white noise of 2 mm/s. Near the reversals (|v| < 10
    mm/s) the fused estimate (``directional_velocity``) errs less than the Butterworth
    ladder alone (``ici_lowpass``), and over the whole record no more; the local fits alone
    (``lpa_ici``) are better than the ladder near the reversals too.
    """
    rate, dt = 1000.0, 1e-3
    t, v = _kinked_strokes(rate)
    y = v + 0.002 * np.random.default_rng(4).standard_normal(t.size)
    model = 0.002 * np.random.default_rng(5).standard_normal(t.size)
    est, share = sensors.directional_velocity(y, dt, 60.0, model)
    local, sd = sensors.lpa_ici(y, dt, model)
    ladder, _ = sensors.ici_lowpass(y, dt, 60.0, model)
    near = (np.abs(v) < 0.01) & (t > 0.2) & (t < t[-1] - 0.2)
    inner = (t > 0.2) & (t < t[-1] - 0.2)

    def rms(e, w):
        return float(np.sqrt(np.mean(e[w] ** 2)))

    assert rms(est - v, near) < 0.8 * rms(ladder - v, near)
    assert rms(local - v, near) < 0.8 * rms(ladder - v, near)
    assert rms(est - v, inner) < rms(ladder - v, inner)
    assert np.all(np.isfinite(est)) and np.all((share >= 0) & (share <= 1))
    assert np.all(np.isfinite(local)) and np.all(sd > 0)


def test_lpa_ici_windows_skip_masked_samples_and_stay_inside_the_record():
    rate, dt = 1000.0, 1e-3
    t, v = _kinked_strokes(rate, seconds=3.0, seed=2)
    model = 0.002 * np.random.default_rng(5).standard_normal(t.size)
    y = v + 0.002 * np.random.default_rng(6).standard_normal(t.size)
    clean, _ = sensors.lpa_ici(y, dt, model)
    mask = np.ones(t.size, dtype=bool)
    mask[1000:1010] = False
    bad = y.copy()
    bad[1000:1010] = 5.0  # a held or filled run far off the motion
    est, sd = sensors.lpa_ici(bad, dt, model, mask)
    # no window reaches into the run: every usable sample is as far from it as without it
    assert np.max(np.abs(est[mask] - v[mask])) < 0.02
    assert np.max(np.abs(est[mask] - clean[mask])) < np.max(np.abs(clean[mask] - v[mask])) + 0.01
    # samples whose every window holds the run have no estimate; the ends use one side only
    assert np.all(np.isnan(est[1002:1008])) and np.all(np.isinf(sd[1002:1008]))
    assert abs(est[0] - v[0]) < 0.01 and abs(est[-1] - v[-1]) < 0.01
    # fused with the ladder, those samples take the ladder
    fused, share = sensors.directional_velocity(bad, dt, 60.0, model, mask)
    assert np.all(np.isfinite(fused)) and np.all(share[1002:1008] == 0)


def test_directional_velocity_without_noise_or_samples_is_the_ladder():
    dt = 1e-3
    t, v = _kinked_strokes(1000.0, seconds=2.0)
    est, share = sensors.directional_velocity(v, dt, 60.0, np.zeros(t.size))
    np.testing.assert_array_equal(est, sensors.ici_lowpass(v, dt, 60.0, np.zeros(t.size))[0])
    assert not share.any()
    # a record shorter than the shortest local window: the ladder, finite
    short = v[:4] + 1e-3
    est, share = sensors.directional_velocity(short, dt, 60.0, np.full(4, 1e-3))
    assert np.all(np.isfinite(est)) and not share.any()


def test_a_rail_is_found_alike_under_round_off():
    """Samples at a rail that differ by round-off (1e-9 relative) are still at the rail."""
    from mr_suspension.identification.vehicle_data import rail_pileup
    rng = np.random.default_rng(4)
    t = np.arange(20000) * 1e-3
    x = 18.0 * np.sin(2 * np.pi * 1.3 * t) + rng.normal(0.0, 0.05, t.size)
    x = np.clip(x, -15.0, 15.0)
    wobble = x * (1.0 + 1e-9 * rng.uniform(-1.0, 1.0, x.size))
    for check in (lambda y: sensors.clipping('a', y), lambda y: rail_pileup('a', y)):
        m0, f0 = check(x)
        m1, f1 = check(wobble)
        assert f0 is not None and f1 is not None
        np.testing.assert_array_equal(m0, m1)
        assert (~m0).sum() == np.sum(np.abs(x) == 15.0)
