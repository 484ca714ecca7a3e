"""Closed-form checks of the quarter-car plant and its integrator."""

import math

import numpy as np
import pytest

from mr_suspension.core import road as rd
from mr_suspension.core.damper import BinghamParams, LinearDamperParams
from mr_suspension.core.metrics import sine_gain
from mr_suspension.core.quarter_car import QuarterCarParams
from mr_suspension.sim import config
from mr_suspension.sim.frequency import sine_dwell_gains
from mr_suspension.sim.simulator import CornerConfig, simulate

IDEAL = config.load_driver('ideal')


def test_natural_frequencies_closed_form():
    car = config.load_vehicle('seed001_military')
    ms, mu, ks, kt = car.m_s, car.m_u, car.k_s, car.k_t
    # det(K - w^2 M) = 0: ms mu w^4 - (ms (ks + kt) + mu ks) w^2 + ks kt = 0.
    a, b, c = ms * mu, -(ms * (ks + kt) + mu * ks), ks * kt
    roots = sorted([(-b - math.sqrt(b * b - 4 * a * c)) / (2 * a),
                    (-b + math.sqrt(b * b - 4 * a * c)) / (2 * a)])
    expected = [math.sqrt(r) / (2 * math.pi) for r in roots]
    assert np.allclose(car.natural_frequencies(), expected, rtol=1e-12)
    # Textbook approximations: body ~ sqrt(k_eq/m_s), wheel hop ~ sqrt((ks + kt)/mu).
    k_eq = ks * kt / (ks + kt)
    assert car.natural_frequencies()[0] == pytest.approx(
        math.sqrt(k_eq / ms) / (2 * math.pi), rel=0.02)
    assert car.natural_frequencies()[1] == pytest.approx(
        math.sqrt((ks + kt) / mu) / (2 * math.pi), rel=0.02)


@pytest.mark.parametrize('vehicle,c', [('seed001_military', 1500.0),
                                       ('seed003_passenger', 1000.0)])
def test_transmissibility_sine_dwell_within_1_percent(vehicle, c):
    car = config.load_vehicle(vehicle)
    cfg = CornerConfig(car=car, damper=LinearDamperParams(c=c), driver=IDEAL)
    freqs = np.array([0.5, 0.8, 1.2, 2.0, 3.0, 5.0, 8.0, 11.0, 14.0, 20.0])
    amp = 1e-3  # small: the tyre stays on the road and the stops are not reached
    analytic = np.abs(car.transfer(freqs, c)['acc'])
    for f, expected in zip(freqs, analytic):
        road = rd.harmonic(amp, f, duration=max(6.0, 12.0 / f), dt=cfg.dt)
        res = simulate(cfg, road)
        assert res.f_t.min() > 0.0
        measured = sine_gain(res.t, res.a_s, f, n_periods=max(2, int(2 * f))) / amp
        assert measured == pytest.approx(expected, rel=0.01), f'{vehicle} at {f} Hz'


def test_static_equilibrium_with_damper_preload():
    # Seed 003's Bingham law has F0 = -95 N (accumulator): the preload balances it at rest.
    cfg = CornerConfig(car=config.load_vehicle('seed003_passenger'),
                       damper=config.load_damper('seed003_bingham'), driver=IDEAL)
    road = rd.harmonic(1e-12, 1.0, duration=2.0)
    res = simulate(cfg, road)
    assert np.max(np.abs(res.z_s)) < 1e-9
    assert np.allclose(res.f_t, cfg.car.static_tyre_load, rtol=1e-9)


def test_tyre_cannot_pull_and_lifts_off_over_a_big_bump():
    cfg = CornerConfig(car=config.load_vehicle('city_car'),
                       damper=LinearDamperParams(c=3000.0), driver=IDEAL)
    res = simulate(cfg, rd.bump(height=0.12, length=0.6, speed=15.0, duration=3.0))
    assert res.f_t.min() == 0.0           # lift-off happened
    assert np.all(res.f_t >= 0.0)         # and the tyre never pulled
    assert np.all(np.isfinite(res.data))


def test_end_stops_limit_the_stroke():
    car = QuarterCarParams(m_s=300.0, m_u=40.0, k_s=8000.0, k_t=200000.0, c_t=0.0,
                           stroke_max=0.03, stroke_min=-0.03, k_stop=2e6)
    free = QuarterCarParams(**{**car.to_dict(), 'k_stop': 0.0})
    road = rd.step(height=0.08, duration=2.0)
    damper = LinearDamperParams(c=300.0)
    limited = simulate(CornerConfig(car=car, damper=damper, driver=IDEAL), road)
    unlimited = simulate(CornerConfig(car=free, damper=damper, driver=IDEAL), road)
    free_peak = np.max(np.abs(unlimited.stroke))
    assert free_peak > 0.1
    assert np.max(np.abs(limited.stroke)) < 0.4 * free_peak


def test_stiff_bingham_pre_yield_is_stable_at_1khz():
    # v_y = 1 mm/s makes the pre-yield tangent ~ 1e6 N s/m: the implicit step stays stable.
    damper = BinghamParams(f0=0.0, c0=1000.0, c1=0.0, fc0=800.0, fc1=0.0, v_y=0.001)
    cfg = CornerConfig(car=config.load_vehicle('seed001_military'), damper=damper,
                       driver=IDEAL)
    res = simulate(cfg, rd.iso8608('C', speed=20.0, duration=10.0, seed=3))
    assert np.all(np.isfinite(res.data))
    assert np.max(np.abs(res.a_s)) < 50.0
    # Dissipation: the damper absorbs energy, never supplies it.
    assert np.sum(res.f_d * res.stroke_rate) > 0.0


def test_bad_vehicle_parameters_raise():
    with pytest.raises(ValueError, match='m_s'):
        QuarterCarParams(m_s=-1.0)
    with pytest.raises(ValueError, match='stroke_min'):
        QuarterCarParams(stroke_min=0.05)
    with pytest.raises(ValueError, match='k_t'):
        QuarterCarParams(k_t=float('nan'))
    with pytest.raises(ValueError, match='unknown parameter'):
        QuarterCarParams.from_dict({'m_s': 200.0, 'mass': 3.0})


def test_sine_dwell_gains_match_the_linear_transfer_functions():
    # Seed 001 Figs 7-10 quantities: body acceleration, body amplitude, working space, NTF.
    car = config.load_vehicle('seed001_military')
    cfg = CornerConfig(car=car, damper=LinearDamperParams(c=2000.0), driver=IDEAL)
    freqs = np.array([0.7, 1.5, 4.0, 12.0])
    gains = sine_dwell_gains(cfg, freqs, amplitude=1e-3)
    analytic = car.transfer(freqs, 2000.0)
    for key in ('acc', 'z_s', 'stroke', 'ntf'):
        assert np.allclose(gains[key], np.abs(analytic[key]), rtol=0.01), key
    with pytest.raises(ValueError):
        sine_dwell_gains(cfg, [0.0, 1.0])
