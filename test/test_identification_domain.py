"""The fitted domain and the stretches outside it, on hand-made rig records.

The records are built here with numpy (sines, band-limited random motion, a damper law
``F = c(i) v + f0(i) tanh(v / v0)`` plus noise); no fitting code of the package enters.
"""

import dataclasses
import json
import warnings

import numpy as np
import pytest
from scipy import signal

from mr_suspension.identification import domain as dm
from mr_suspension.identification.data import Record

RATE = 1000.0
GUARD = dm.GUARD


def _law(v, i):
    """Damper force [N]: viscous plus a smooth yield, both growing with the current."""
    return (800.0 + 1500.0 * i) * v + (100.0 + 600.0 * i) * np.tanh(v / 0.02)


def _record(x, v, i, seed=0, f=None, noise=5.0, dt=1.0 / RATE, name='hand', mask=None):
    i = np.broadcast_to(np.asarray(i, dtype=float), x.shape).copy()
    if f is None:
        f = _law(v, i) + noise * np.random.default_rng(seed).standard_normal(x.size)
    return Record(name=name, time=dt * np.arange(x.size), displacement=x, velocity=v,
                  force=f, i_in=i, input_kind='current', dt=dt, mask=mask)


def _sine(amp, freq, cur, dur=10.0, seed=0, dt=1.0 / RATE, **kw):
    t = dt * np.arange(int(round(dur / dt)))
    w = 2 * np.pi * freq
    return _record(amp * np.sin(w * t), amp * w * np.cos(w * t), cur, seed, dt=dt,
                   name=f'{1e3 * amp:g}mm{freq:g}Hz{cur:g}A', **kw)


def _random(seed, peak=0.007, dur=20.0, fc=3.0, cur=0.5):
    """Band-limited random motion (4th-order low-passed white noise), max |x| = ``peak``."""
    n = int(dur * RATE)
    sos = signal.butter(4, fc / (RATE / 2), output='sos')
    x = signal.sosfiltfilt(sos, np.random.default_rng(seed).standard_normal(n + 4000))
    x = x[2000:-2000]
    x = peak * (x - x.mean()) / np.max(np.abs(x - x.mean()))
    return _record(x, np.gradient(x, 1.0 / RATE), cur, seed + 1000, name=f'random{seed}')


@pytest.fixture(scope='module')
def training():
    recs = [_sine(0.008, 1.0, c, seed=k) for k, c in enumerate((0.0, 0.5, 1.0))]
    recs += [_sine(0.004, 3.0, c, seed=3 + k) for k, c in enumerate((0.0, 0.5, 1.0))]
    recs += [_random(s) for s in (1, 2)]
    return recs


@pytest.fixture(scope='module')
def domain(training):
    return dm.fit_domain(training)


def _kinds(chk):
    return [s.kind for s in chk.stretches]


def _hold_sine(amp, hold_at, t_hold, seg, cur=0.5, dur=11.0):
    """Return a 1 Hz sine of ``amp`` that leaves its crest at ``t_hold`` for ``seg`` s.

    It ramps to ``hold_at`` and back (cosine ramps of 0.5 s, zero velocity at the joints).
    """
    t = np.arange(int(round(dur * RATE))) / RATE
    w = 2 * np.pi
    tau = np.where(t < t_hold, t, np.where(t < t_hold + seg, t_hold, t - seg))
    x = amp * np.sin(w * tau)
    v = np.where((t >= t_hold) & (t < t_hold + seg), 0.0, amp * w * np.cos(w * tau))
    s = t - t_hold
    up = np.clip(s / 0.5, 0.0, 1.0)
    down = np.clip((s - (seg - 0.5)) / 0.5, 0.0, 1.0)
    shape = 0.5 * (1 - np.cos(np.pi * up)) - 0.5 * (1 - np.cos(np.pi * down))
    dshape = (np.where((s > 0) & (s < 0.5), 0.5 * np.pi / 0.5 * np.sin(np.pi * up), 0.0)
              - np.where((s > seg - 0.5) & (s < seg), 0.5 * np.pi / 0.5 * np.sin(np.pi * down),
                         0.0))
    x = x + (hold_at - amp) * shape
    v = v + (hold_at - amp) * dshape
    return t, x, v, np.full(t.size, cur)


def test_fitted_domain_holds_the_training_ranges(domain, training):
    assert domain.displacement == pytest.approx((-0.008, 0.008), abs=1e-9)
    assert domain.i_in == (0.0, 1.0)
    assert 0.0754 * 0.99 < domain.velocity[1] <= dm.VEL_CAP * domain.abs_velocity_p999
    assert 3.0 < domain.band < 8.0             # 1 and 3 Hz sines, 3 Hz random motion
    assert domain.rest_noise is None           # no rest in the training
    assert domain.force_noise == pytest.approx(5.0, rel=0.1)
    assert len(domain.offsets) == len(training)
    assert max(abs(o) for _, o in domain.offsets) < 10.0
    assert domain.reversal is not None and domain.reversal < 20.0
    assert domain.records == len(training) and domain.samples == 100000


def test_records_inside_the_domain_are_not_flagged(domain, training):
    for rec in training:
        chk = dm.check(rec, domain)
        assert chk.stretches == (), (rec.name, chk.lines())
        assert chk.mask.all() and chk.excluded_share == 0.0
    inside = [_sine(0.006, 2.0, 0.25, seed=11), _sine(0.003, 4.0, 0.8, seed=12),
              _sine(0.007, 0.5, 0.6, dur=20.0, seed=13)]
    for rec in inside:
        assert dm.check(rec, domain).stretches == (), rec.name
    for s in range(20, 26):
        chk = dm.check(_random(s, peak=0.006), domain)
        assert chk.excluded_share < 0.005, chk.lines()


def test_longer_stroke_flags_exactly_that_stretch(domain):
    t, x, v, i = _hold_sine(0.008, 0.0109, 8.25, 1.5)
    rec = _record(x, v, i, seed=21)
    chk = dm.check(rec, domain)
    (st,) = chk.stretches
    assert st.kind == 'displacement' and '10.9 mm' in st.detail and '-8..8 mm' in st.detail
    beyond = t[x > 0.008 + dm.SLACK * 0.016]
    assert abs(st.t0 - (beyond[0] - GUARD)) <= 2 / RATE
    assert abs(st.t1 - (beyond[-1] + GUARD)) <= 2 / RATE
    assert st.value == pytest.approx(0.0109, abs=1e-6)
    inside = (t >= st.t0) & (t < st.t1)
    np.testing.assert_array_equal(chk.mask, ~inside)
    (line,) = chk.lines()
    assert line.startswith('displacement: 1 stretch, ') and '10.9 mm' in line
    # the same samples already masked by the record: nothing left to flag
    masked = dataclasses.replace(rec, mask=~inside)
    chk = dm.check(masked, domain)
    assert chk.stretches == () and chk.excluded_share == 0.0
    np.testing.assert_array_equal(chk.mask, ~inside)


def test_clipped_force_is_flagged(domain):
    rec = _sine(0.008, 1.0, 1.0, seed=31)
    rail = 0.8 * rec.force.max()
    held = rec.force >= rail
    rec = dataclasses.replace(rec, force=np.minimum(rec.force, rail))
    chk = dm.check(rec, domain)
    assert set(_kinds(chk)) == {'clipping'}
    crests = 11                                    # at 0, 1, ..., 10 s (halves at both ends)
    assert len(chk.stretches) == crests
    for k, st in enumerate(chk.stretches):
        assert st.t0 <= max(k - 0.15, 0.0) and st.t1 >= min(k + 0.15, rec.duration)
    assert not chk.mask[held].any()
    assert chk.excluded_share < held.mean() + crests * 2 * GUARD * RATE / rec.n
    assert f'{rail:.6g} N' in chk.stretches[0].detail


def test_force_swing_at_rest_is_flagged(domain):
    t, x, v, i = _hold_sine(0.006, 0.006, 5.25, 2.0, dur=10.0)
    f = _law(v, i) + 5.0 * np.random.default_rng(41).standard_normal(t.size)
    still = (t >= 5.75) & (t < 6.75)              # between the ramps: no motion at all
    f[still] += 2000.0 * np.sin(2 * np.pi * 5.0 * (t[still] - 5.75))
    chk = dm.check(_record(x, v, i, f=f), domain)
    assert set(_kinds(chk)) <= {'rest_noise', 'reversal'} and 'rest_noise' in _kinds(chk)
    assert not chk.mask[still].any()
    flagged = ~chk.mask
    assert not flagged[(t < 5.75 - GUARD - 0.01) | (t > 6.75 + GUARD + 0.01)].any()
    without = dm.check(_record(x, v, i, seed=41), domain)
    assert without.stretches == ()


def _dahl(rec, seed, x0=3e-4):
    """``rec`` with a hysteretic (Dahl) damper's force: the yield part turns over ``x0``."""
    z = np.empty(rec.n)
    acc = 0.0
    for k, vk in enumerate(rec.velocity):
        z[k] = acc
        acc += (vk - abs(vk) * acc) * rec.dt / x0
    i = rec.i_in
    f = (800.0 + 1500.0 * i) * rec.velocity + (100.0 + 600.0 * i) * z
    return dataclasses.replace(rec, force=f + 5.0 * np.random.default_rng(seed).standard_normal(
        rec.n))


def test_slow_turning_point_is_no_rest(domain):
    # at 0.2 Hz the stroke rate stays below the rest speed for 0.58 s around each turning
    # point, while the yield force turns over 0.5 mm of stroke: motion, not a force at rest
    rec = _dahl(_sine(0.008, 0.2, 1.0, seed=45), 45)
    assert dm.check(rec, domain).stretches == ()
    anywhere = dataclasses.replace(domain, rest_stroke=1.0)
    assert 'rest_noise' in _kinds(dm.check(rec, anywhere))


def test_end_of_record_at_the_stop_is_flagged(domain):
    # the case from the field: the actuator travels to 10.9 mm (training 8 mm), the load cell
    # clips, the force swings at zero velocity; everything before is a clean 1 Hz sine
    t, x, v, i = _hold_sine(0.008, 0.0109, 8.25, 2.75, dur=12.0, cur=1.0)
    f = _law(v, i) + 5.0 * np.random.default_rng(51).standard_normal(t.size)
    stop = (t >= 8.75) & (t < 10.5)
    f[stop] += 2500.0 * np.sin(2 * np.pi * 4.0 * (t[stop] - 8.75))
    f = np.minimum(f, 2200.0)
    chk = dm.check(_record(x, v, i, f=f), domain)
    assert {'displacement', 'clipping', 'rest_noise'} <= set(_kinds(chk))
    assert all(8.25 - GUARD <= s.t0 and s.t1 <= 11.0 + GUARD for s in chk.stretches)
    assert chk.mask[t < 8.2].all()
    assert len(chk.lines()) == len(set(_kinds(chk)))


def _lagged(rec, seed, lag=0.025):
    """``rec`` with the force of a damper that lags the motion by ``lag`` (a loop)."""
    k = int(round(lag * RATE))
    v = np.concatenate([np.full(k, rec.velocity[0]), rec.velocity[:-k]])
    f = _law(v, rec.i_in) + 5.0 * np.random.default_rng(seed).standard_normal(rec.n)
    return dataclasses.replace(rec, force=f)


def test_force_against_the_motion_beyond_the_loop_is_flagged():
    levels = ((1, 0.2), (2, 0.6), (3, 1.0))
    dom = dm.fit_domain([_lagged(_random(s, cur=c), s) for s, c in levels])
    assert 50.0 < dom.reversal < 200.0             # the lag drives the force against the motion
    for s, c in ((30, 0.3), (31, 0.9), (32, 0.5), (33, 0.7)):
        chk = dm.check(_lagged(_random(s, peak=0.006, cur=c), s), dom)
        assert chk.stretches == (), chk.lines()
    rec = _lagged(_random(32, peak=0.006, cur=0.5), 32)
    wrong = (rec.time >= 12.0) & (rec.time < 12.5)
    chk = dm.check(dataclasses.replace(rec, force=np.where(wrong, -rec.force, rec.force)), dom)
    assert set(_kinds(chk)) == {'reversal'}
    fast = wrong & (np.abs(rec.velocity) > 0.5 * np.abs(rec.velocity[wrong]).max())
    assert fast.any() and not chk.mask[fast].any()
    assert all(12.0 - GUARD <= s.t0 and s.t1 <= 12.5 + GUARD for s in chk.stretches)


def test_constant_offset_flags_the_whole_record_and_excludes_nothing(domain):
    rec = _sine(0.006, 2.0, 0.5, seed=61)
    chk = dm.check(dataclasses.replace(rec, force=rec.force + 300.0), domain)
    (st,) = chk.stretches
    assert st.kind == 'offset' and st.value == pytest.approx(300.0, abs=15.0)
    assert st.t0 == 0.0 and st.t1 == pytest.approx(rec.duration)
    assert chk.mask.all() and chk.excluded_share == 0.0
    assert dm.check(rec, domain).stretches == ()


def test_higher_frequency_excitation_is_flagged(domain):
    rec = _sine(0.0006, 12.0, 0.5, seed=71)        # 45 mm/s: inside the speed range
    chk = dm.check(rec, domain)
    assert set(_kinds(chk)) == {'frequency'}
    (st,) = chk.stretches
    assert st.value == pytest.approx(12.0, abs=0.5)
    assert chk.excluded_share > 0.95
    # a 12 Hz burst inside an in-domain record: only the burst (and the window) flagged
    t = rec.time
    base = _sine(0.006, 1.0, 0.5, seed=72)
    burst = (t >= 4.0) & (t < 6.0)
    x = base.displacement + np.where(burst, rec.displacement, 0.0)
    v = base.velocity + np.where(burst, rec.velocity, 0.0)
    chk = dm.check(_record(x, v, 0.5, seed=73), domain)
    assert set(_kinds(chk)) == {'frequency'}
    window = dm.FREQ_PERIODS / domain.band
    for s in chk.stretches:
        assert 4.0 - window - GUARD <= s.t0 and s.t1 <= 6.0 + window + GUARD
    assert not chk.mask[(t >= 4.5) & (t < 5.5)].any()


def test_short_flags_merge_within_the_guard(domain):
    rec = _sine(0.006, 2.0, 0.5, seed=81)
    i = rec.i_in.copy()
    i[[3000, 3025]] = 1.5                          # two glitches 25 ms apart
    chk = dm.check(dataclasses.replace(rec, i_in=i), domain)
    (st,) = chk.stretches
    assert st.kind == 'input' and '1.5 A' in st.detail
    assert st.t0 == pytest.approx(3.0 - GUARD) and st.t1 == pytest.approx(3.025 + GUARD + 1e-3)


def test_constant_training_input_has_a_floor():
    dom = dm.fit_domain([_random(s) for s in (1, 2)])    # all at 0.5 A
    assert dom.i_in == (0.5, 0.5)
    rec = _random(40, peak=0.006)
    noisy = 0.5 + 0.003 * np.random.default_rng(40).standard_normal(rec.n)
    assert dm.check(dataclasses.replace(rec, i_in=noisy), dom).stretches == ()
    (st,) = dm.check(dataclasses.replace(rec, i_in=np.full(rec.n, 0.55)), dom).stretches
    assert st.kind == 'input' and st.duration == pytest.approx(rec.duration)


def test_domain_round_trips_through_a_dict(domain):
    d = json.loads(json.dumps(domain.to_dict()))
    back = dm.Domain.from_dict(d)
    assert back == domain
    rec = _sine(0.0006, 12.0, 0.5, seed=91)
    assert dm.check(rec, d).stretches == dm.check(rec, domain).stretches
    for bad in ({k: v for k, v in d.items() if k != 'band'}, dict(d, velocity=[1.0, -1.0]),
                dict(d, rest_velocity=float('nan')), [1, 2]):
        with pytest.raises(ValueError):
            dm.Domain.from_dict(bad)


def test_bad_inputs_never_crash(domain):
    n = 3000
    flat = _record(np.zeros(n), np.zeros(n), 0.0, f=np.full(n, 12.0))
    chk = dm.check(flat, domain)                   # constant channels
    assert chk.mask.shape == (n,)
    none = dataclasses.replace(_sine(0.006, 2.0, 0.5), mask=np.zeros(10000, dtype=bool))
    chk = dm.check(none, domain)
    assert chk.stretches == () and not chk.mask.any() and chk.excluded_share == 0.0
    assert chk.lines() == []
    rec = _sine(0.006, 2.0, 0.5, seed=101)
    gaps = np.ones(rec.n, dtype=bool)
    gaps[2000:2300] = False
    f, x = rec.force.copy(), rec.displacement.copy()
    f[2000:2300] = np.nan
    x[2100] = np.inf
    chk = dm.check(dataclasses.replace(rec, force=f, displacement=x, mask=gaps), domain)
    assert chk.stretches == () and not chk.mask[2000:2300].any() and chk.mask[gaps].all()
    nan_unmasked = dataclasses.replace(rec, force=f)   # NaN the record's mask missed
    chk = dm.check(nan_unmasked, domain)
    assert chk.stretches == () and not chk.mask[2000:2300].any()
    slow_rate = _sine(0.006, 2.0, 0.5, seed=102, dt=0.005)
    assert dm.check(slow_rate, domain).stretches == ()
    assert dm.check(dataclasses.replace(rec, dt=float('nan')), domain).stretches == ()
    tiny = _record(np.zeros(4), np.zeros(4), 0.5, f=np.zeros(4))
    dm.check(tiny, domain)
    with warnings.catch_warnings():
        warnings.simplefilter('error')             # no numpy warning either
        dom = dm.fit_domain([flat])                # constant training: no motion, no band
        assert dom.band is None and dom.reversal is None and dom.offsets == ()
        chk = dm.check(rec, dom)
        assert {'displacement', 'velocity', 'input'} <= set(_kinds(chk))
        dm.check(flat, dom)
        dm.fit_domain([flat, none, slow_rate])
    with pytest.raises(ValueError, match='no usable samples'):
        dm.fit_domain([none])
    with pytest.raises(ValueError, match='no usable samples'):
        dm.fit_domain([])
