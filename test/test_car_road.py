"""Four-wheel car roads: rear delay, ISO 8608 spectra, left/right coherence, bumps, inputs."""

import math

import numpy as np
import pytest
from scipy import integrate, signal, special

from mr_suspension.core import car_road as cr, road as rd

FL, FR, RL, RR = range(4)


def _ramp(s):
    return np.clip(s, 0.0, 1.0), np.where((s >= 0.0) & (s < 1.0), 1.0, 0.0)


def _harmonic_sum(u, dt, s):
    """Evaluate the trigonometric polynomial through samples ``u`` (odd size) at times ``s``."""
    n = u.size
    assert n % 2 == 1, 'odd record: no Nyquist bin'
    coeff = np.fft.rfft(u)
    freqs = np.fft.rfftfreq(n, dt)
    phase = np.exp(2j * np.pi * np.outer(s, freqs[1:]))
    value = (coeff[0].real + 2.0 * (phase @ coeff[1:]).real) / n
    rate = 2.0 * (phase @ (coeff[1:] * 2j * np.pi * freqs[1:])).real / n
    return value, rate


# --- rear wheels = front tracks delayed by tau ------------------------------------------------

@pytest.mark.parametrize('wheelbase, shift', [(2.3, 115), (2.5, 125)])
def test_iso_rear_is_front_delayed_by_whole_samples(wheelbase, shift):
    car = cr.iso8608_two_track(speed=20.0, duration=10.0, dt=1e-3, seed=3, wheelbase=wheelbase)
    assert car.tau / car.dt == pytest.approx(shift)
    for front, rear in ((FL, RL), (FR, RR)):
        for x in (car.z, car.zdot):
            assert np.max(np.abs(x[rear, shift:] - x[front, :-shift])) <= 1e-12
            assert np.all(x[rear, :shift] == 0.0)
        # The delay matters: an undelayed rear would differ by centimetres.
        assert np.max(np.abs(car.z[rear] - car.z[front])) > 1e-3


def test_iso_rear_fractional_delay_matches_direct_harmonic_sum():
    dt, speed, wheelbase = 1e-3, 20.0, 2.31  # tau = 115.5 samples
    car = cr.iso8608_two_track(speed=speed, duration=2.0, dt=dt, seed=5, wheelbase=wheelbase)
    tau = wheelbase / speed
    assert abs(tau / dt - round(tau / dt)) > 0.4
    t = car.t
    ramp, _ = _ramp(t)
    for front, rear in ((FL, RL), (FR, RR)):
        # Un-faded profile from the front samples: z = u r, and zdot(0) = u(0) r'(0) = u(0).
        u = np.empty_like(t)
        u[1:] = car.z[front, 1:] / ramp[1:]
        u[0] = car.zdot[front, 0]
        s = t - tau
        value, rate = _harmonic_sum(u, dt, s)
        r, slope = _ramp(s)
        assert np.max(np.abs(car.z[rear] - value * r)) <= 1e-12
        assert np.max(np.abs(car.zdot[rear] - (rate * r + value * slope))) <= 1e-10
        assert np.all(car.z[rear, t < tau] == 0.0)


def test_from_track_keeps_front_bit_for_bit_and_delays_rear_by_whole_samples():
    road = rd.bump(height=0.04, length=1.0, speed=10.0, t0=0.3, duration=3.0, dt=1e-3)
    car = cr.from_track(road, wheelbase=2.3, speed=10.0)
    for i in (FL, FR):
        corner = car.corner(i)
        assert isinstance(corner, rd.Road)
        assert corner.dt == road.dt
        assert np.array_equal(corner.z, road.z) and np.array_equal(corner.zdot, road.zdot)
        assert np.array_equal(corner.t, road.t)
    shift = 230  # tau = 0.23 s
    for i in (RL, RR):
        assert np.array_equal(car.z[i, shift:], road.z[:-shift])
        assert np.array_equal(car.zdot[i, shift:], road.zdot[:-shift])
        assert np.all(car.z[i, :shift] == road.z[0]) and np.all(car.zdot[i, :shift] == 0.0)
    # A road that does not start at height 0: the rear waits on its first height.
    raised = rd.Road('raised', road.dt, road.z + 0.03, road.zdot)
    car = cr.from_track(raised, wheelbase=2.3055, speed=10.0)  # fractional: 230.55 samples
    assert np.all(car.z[RL, :231] == 0.03) and np.all(car.zdot[RL, :231] == 0.0)
    assert np.all(car.z[RL, 231:] >= 0.03) and np.max(car.z[RL]) == pytest.approx(0.07, abs=1e-3)


def test_from_track_fractional_delay_interpolates_within_the_linear_bound():
    amp, freq, dt = 0.01, 3.0, 1e-3
    left = rd.harmonic(amplitude=amp, freq=freq, duration=2.0, dt=dt)
    right = rd.harmonic(amplitude=amp, freq=2.0 * freq, duration=2.0, dt=dt)
    car = cr.from_track(left, wheelbase=2.3055, speed=10.0, right=right)  # 230.55 samples
    tau = car.tau
    assert np.array_equal(car.z[FR], right.z)
    t = car.t
    after = t >= tau
    for rear, f in ((RL, freq), (RR, 2.0 * freq)):
        w = 2.0 * np.pi * f
        bound = dt ** 2 / 8.0 * amp * w ** 2
        assert np.max(np.abs(car.z[rear, after] - amp * np.sin(w * (t[after] - tau)))) <= bound
        assert np.max(np.abs(car.zdot[rear, after]
                             - amp * w * np.cos(w * (t[after] - tau)))) <= bound * w
        # At rest before tau: the road's first height, rate 0.
        assert np.all(car.z[rear, ~after] == 0.0) and np.all(car.zdot[rear, ~after] == 0.0)
        # Linear interpolation is not the exact delay: the error is there, just bounded.
        assert np.max(np.abs(car.z[rear, after] - amp * np.sin(w * (t[after] - tau)))) > 0.0


def test_from_track_rejects_mismatched_tracks():
    left = rd.step(duration=2.0)
    with pytest.raises(ValueError, match='share dt and length'):
        cr.from_track(left, 2.3, 10.0, right=rd.step(duration=3.0))
    with pytest.raises(ValueError, match='road.Road'):
        cr.from_track(np.zeros(10), 2.3, 10.0)


# --- ISO 8608 two-track spectra ---------------------------------------------------------------

def test_front_left_track_is_the_single_track_iso8608_road():
    car = cr.iso8608_two_track('D', speed=15.0, duration=5.0, seed=7)
    road = rd.iso8608('D', speed=15.0, duration=5.0, seed=7)
    assert np.array_equal(car.z[FL], road.z) and np.array_equal(car.zdot[FL], road.zdot)


def test_reproducible_from_seed():
    a = cr.iso8608_two_track(duration=3.0, seed=11)
    b = cr.iso8608_two_track(duration=3.0, seed=11)
    c = cr.iso8608_two_track(duration=3.0, seed=12)
    assert np.array_equal(a.z, b.z) and np.array_equal(a.zdot, b.zdot)
    assert not np.allclose(a.z, c.z)


SPEED, DT, TRACK, SEEDS, NPERSEG = 20.0, 5e-3, 1.4, range(4), 2048


@pytest.fixture(scope='module')
def spectra():
    """Welch auto- and cross-spectra of the four corners pooled over seeds (fade-in cut)."""
    pxx = np.zeros((4, NPERSEG // 2 + 1))
    pxy = np.zeros((2, NPERSEG // 2 + 1), dtype=complex)
    for seed in SEEDS:
        car = cr.iso8608_two_track('C', speed=SPEED, duration=60.0, dt=DT, seed=seed,
                                   track=TRACK)
        z = car.z[:, car.t >= 1.0 + car.tau]
        f, p = signal.welch(z, fs=1.0 / DT, nperseg=NPERSEG)
        pxx += p / len(SEEDS)
        for k, (a, b) in enumerate(((FL, FR), (RL, RR))):
            pxy[k] += signal.csd(z[a], z[b], fs=1.0 / DT, nperseg=NPERSEG)[1] / len(SEEDS)
    return f, pxx, pxy


@pytest.mark.parametrize('band', [(0.5, 2.0), (2.0, 8.0), (8.0, 30.0), (30.0, 80.0)])
def test_each_track_has_the_iso8608_psd(spectra, band):
    f, pxx, _ = spectra
    sel = (f >= band[0]) & (f <= band[1])
    theory = rd.iso8608_psd(f[sel] / SPEED, 'C') / SPEED
    for i in range(4):
        ratio = np.mean(pxx[i, sel] / theory)
        assert ratio == pytest.approx(1.0, abs=0.2), (cr.CORNERS[i], band, ratio)


def test_left_right_coherence_follows_the_isotropic_model(spectra):
    f, pxx, pxy = spectra
    model = cr.isotropic_coherence(f / SPEED, TRACK, 2.0) ** 2
    for k, (a, b) in enumerate(((FL, FR), (RL, RR))):
        msc = np.abs(pxy[k]) ** 2 / (pxx[a] * pxx[b])
        sel = (f >= 0.4) & (f <= 20.0)
        assert np.mean(np.abs(msc[sel] - model[sel])) < 0.05
        # Octave bands over the fall of the model (0.87 .. 0.08): a track width off by
        # 30 % moves some band by > 0.1.
        for lo in (0.4, 0.8, 1.6, 3.2):
            octave = (f >= lo) & (f <= 2.0 * lo)
            assert np.mean(msc[octave]) == pytest.approx(np.mean(model[octave]), abs=0.06)
        # High at long wavelengths (> 25 m), low at short ones (< 2 m).
        assert np.mean(msc[(f >= 0.4) & (f <= 0.8)]) > 0.75
        assert np.mean(msc[(f >= 10.0) & (f <= 40.0)]) < 0.05
        # Isotropy: real, positive cross-spectrum (no phase) where the tracks are coherent.
        lo = (f >= 0.4) & (f <= 2.0)
        assert np.mean(np.abs(np.angle(pxy[k][lo]))) < 0.15


def test_isotropic_coherence_matches_the_isotropy_integral():
    # Isotropic surface: S(n, m) ~ (n^2 + m^2)^(-(w + 1)/2) gives the profile PSD ~ n^-w and
    # the cross-spectrum of tracks B apart, integral of S cos(2 pi m B) dm.
    for w in (2.0, 3.0):
        for n in (0.02, 0.1, 0.3):
            def density(m, n=n, w=w):
                return (n * n + m * m) ** (-(w + 1.0) / 2.0)
            cross = integrate.quad(density, 0.0, np.inf, weight='cos', wvar=2 * np.pi * TRACK)
            auto = integrate.quad(density, 0.0, np.inf)
            expected = cross[0] / auto[0]
            assert cr.isotropic_coherence(n, TRACK, w) == pytest.approx(expected, rel=1e-6)
    n = np.array([0.0, 0.01, 0.1, 1.0, 10.0])
    u = 2.0 * np.pi * n[1:] * TRACK
    gamma = cr.isotropic_coherence(n, TRACK, 2.0)
    assert gamma[0] == 1.0
    assert np.allclose(gamma[1:], u * special.k1(u), rtol=1e-12, atol=1e-300)
    assert np.all(np.diff(gamma) < 0.0)


def test_coherence_none_gives_identical_left_and_right_tracks():
    same = cr.iso8608_two_track(duration=5.0, seed=2, coherence=None)
    for a, b in ((FL, FR), (RL, RR)):
        assert np.array_equal(same.z[a], same.z[b])
        assert np.array_equal(same.zdot[a], same.zdot[b])
    iso = cr.iso8608_two_track(duration=5.0, seed=2)
    assert not np.allclose(iso.z[FL], iso.z[FR])


# --- exact rates -------------------------------------------------------------------------------

def test_zdot_matches_central_difference_full_band():
    dt = 2e-4
    car = cr.iso8608_two_track(speed=20.0, duration=3.0, dt=dt, seed=4)
    for i in range(4):
        grad = np.gradient(car.z[i], dt)
        err = np.linalg.norm(grad[1:-1] - car.zdot[i, 1:-1]) / np.linalg.norm(car.zdot[i])
        assert err < 0.02, (cr.CORNERS[i], err)


def test_zdot_matches_central_difference_with_the_fade_in_term():
    dt = 1e-3
    car = cr.iso8608_two_track(speed=20.0, duration=4.0, dt=dt, seed=6, n_max=0.5)
    t = car.t
    kinks = (0.0, 1.0, car.tau, 1.0 + car.tau)
    keep = np.ones(t.size, dtype=bool)
    keep[[0, -1]] = False
    for k in kinks:
        keep &= np.abs(t - k) > 1.5 * dt
    for i in range(4):
        grad = np.gradient(car.z[i], dt)
        scale = np.max(np.abs(car.zdot[i]))
        assert np.max(np.abs(grad - car.zdot[i])[keep]) < 0.01 * scale, cr.CORNERS[i]
    # The fade-in term u r' is larger than that tolerance: leaving it out would fail.
    front = t < 1.0
    assert np.max(np.abs(car.z[FL, front] / np.maximum(t[front], dt))) > 0.01 * np.max(
        np.abs(car.zdot[FL]))


def test_bump_zdot_matches_central_difference():
    dt = 1e-4
    car = cr.bump(height=0.05, length=2.0, speed=10.0, duration=1.5, dt=dt)
    for i in range(4):
        grad = np.gradient(car.z[i], dt)
        assert np.max(np.abs(grad - car.zdot[i])) < 1e-3 * np.max(np.abs(car.zdot[i]))


# --- bumps -------------------------------------------------------------------------------------

@pytest.mark.parametrize('side, hit', [('left', (FL, RL)), ('right', (FR, RR)),
                                       ('both', (FL, FR, RL, RR))])
def test_bump_side_and_rear_timing(side, hit):
    height, length, speed, t0, wheelbase = 0.05, 2.0, 10.0, 0.5, 2.3
    car = cr.bump(height, length, speed, t0, side=side, duration=2.0, dt=1e-3,
                  wheelbase=wheelbase)
    for i in range(4):
        if i in hit:
            assert np.max(car.z[i]) == pytest.approx(height)
        else:
            assert np.all(car.z[i] == 0.0) and np.all(car.zdot[i] == 0.0)
    t = car.t
    for front, rear in ((FL, RL), (FR, RR)):
        if front not in hit:
            continue
        start_front = t[np.argmax(car.z[front] > 0.0)]
        start_rear = t[np.argmax(car.z[rear] > 0.0)]
        assert t0 < start_front <= t0 + 1.001e-3
        assert t0 + wheelbase / speed < start_rear <= t0 + wheelbase / speed + 1.001e-3
        assert np.all(car.z[rear, t <= t0 + wheelbase / speed] == 0.0)
        # Analytic: the rear bump is the front one 230 samples later.
        assert np.allclose(car.z[rear, 230:], car.z[front, :-230], atol=1e-12)


# --- container and spec ------------------------------------------------------------------------

def test_car_road_properties_and_corner_lookup():
    car = cr.bump(duration=2.0, dt=1e-3, speed=10.0, wheelbase=2.3)
    assert car.n_steps == 2000 and car.duration == pytest.approx(2.0)
    assert car.t.shape == (2001,) and car.tau == pytest.approx(0.23)
    assert cr.CORNERS == ('front_left', 'front_right', 'rear_left', 'rear_right')
    assert np.array_equal(car.corner('rear_right').z, car.z[RR])
    with pytest.raises(ValueError, match='corner'):
        car.corner(4)
    with pytest.raises(ValueError, match='corner'):
        car.corner('middle')


def test_from_spec_types():
    iso = cr.from_spec({'type': 'iso8608', 'road_class': 'B', 'speed': 15.0, 'seed': 1},
                       duration=3.0, dt=2e-3, wheelbase=2.5, track=1.6)
    ref = cr.iso8608_two_track('B', speed=15.0, duration=3.0, dt=2e-3, seed=1, track=1.6,
                               wheelbase=2.5)
    assert np.array_equal(iso.z, ref.z) and iso.wheelbase == 2.5
    bump = cr.from_spec({'type': 'bump', 'side': 'right'}, duration=2.0)
    assert np.all(bump.z[FL] == 0.0) and np.max(bump.z[FR]) > 0.0
    step = cr.from_spec({'type': 'step', 't0': 0.5}, duration=2.0, wheelbase=2.3)
    assert step.speed == cr.RIG_SPEED == 10.0
    assert np.array_equal(step.z[FL], rd.step(t0=0.5, duration=2.0).z)
    assert np.array_equal(step.z[RL, 230:], step.z[FL, :-230])
    harm = cr.from_spec({'type': 'harmonic', 'freq': 2.0, 'speed': 20.0}, duration=1.0)
    assert harm.speed == 20.0 and harm.n_steps == 1000
    assert cr.from_spec({'type': 'sweep'}, duration=2.0).z.shape == (4, 2001)


def test_from_spec_rejects_bad_specs():
    with pytest.raises(ValueError, match=r"\['bump', 'harmonic', 'iso8608', 'step', 'sweep'\]"):
        cr.from_spec({'type': 'pothole'})
    with pytest.raises(ValueError, match='mapping'):
        cr.from_spec('bump')
    with pytest.raises(ValueError, match='track'):
        cr.from_spec({'type': 'bump', 'track': 1.5})
    with pytest.raises(ValueError, match='bump'):
        cr.from_spec({'type': 'bump', 'colour': 'red'})


# --- validation --------------------------------------------------------------------------------

def test_bad_inputs_raise_clear_errors():
    road = rd.step(duration=1.0)
    with pytest.raises(ValueError, match='speed = -5'):
        cr.iso8608_two_track(speed=-5.0)
    with pytest.raises(ValueError, match='speed = -5'):
        cr.from_track(road, 2.3, -5.0)
    with pytest.raises(ValueError, match='speed = -5'):
        cr.bump(speed=-5.0)
    with pytest.raises(ValueError, match="side must be one of.*'middle'"):
        cr.bump(side='middle')
    with pytest.raises(ValueError, match='track = 0.1 m'):
        cr.iso8608_two_track(track=0.1)
    with pytest.raises(ValueError, match='wheelbase = 20 m'):
        cr.bump(wheelbase=20.0)
    with pytest.raises(ValueError, match='coherence'):
        cr.iso8608_two_track(coherence='exponential')
    with pytest.raises(ValueError, match='seed'):
        cr.iso8608_two_track(seed=-1)
    with pytest.raises(ValueError, match='road class'):
        cr.iso8608_two_track(road_class='Z')
    with pytest.raises(ValueError, match='speed must be a finite'):
        cr.from_track(road, 2.3, math.nan)


def test_car_road_checks_shapes_and_finiteness():
    z = np.zeros((4, 11))
    cr.CarRoad('ok', 1e-3, z, z, 10.0, 2.3)
    with pytest.raises(ValueError, match=r'shape \(4, n \+ 1\).*\(3, 11\)'):
        cr.CarRoad('bad', 1e-3, np.zeros((3, 11)), np.zeros((3, 11)), 10.0, 2.3)
    with pytest.raises(ValueError, match='zdot shape'):
        cr.CarRoad('bad', 1e-3, z, np.zeros((4, 10)), 10.0, 2.3)
    nan = z.copy()
    nan[2, 5] = np.nan
    with pytest.raises(ValueError, match='z must be finite'):
        cr.CarRoad('bad', 1e-3, nan, z, 10.0, 2.3)
    with pytest.raises(ValueError, match='wheelbase'):
        cr.CarRoad('bad', 1e-3, z, z, 10.0, 0.0)
    with pytest.raises(ValueError, match='dt'):
        cr.CarRoad('bad', math.nan, z, z, 10.0, 2.3)
