"""Independent rig truth: closed forms, convergence, dissipation, sensors, cases, isolation.

Every expected value here is a textbook closed form or computed in the test from the inputs;
nothing comes from the fitting code (identification) or the package's damper/driver laws.
"""

import ast
import os
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest
import truthcases

from mr_suspension.truth import cases, rig, sensors

TRUTH_DIR = Path(__file__).resolve().parents[1] / 'mr_suspension' / 'truth'
FORBIDDEN = ('mr_suspension.identification', 'mr_suspension.core.extended',
             'mr_suspension.core.driver', 'mr_suspension.core.damper')


def _harmonic_fit(t, y, w):
    a = np.column_stack([np.cos(w * t), np.sin(w * t), np.ones_like(t)])
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    return coef[0], coef[1]


def test_linear_viscous_damper_is_c_times_v():
    t, x = truthcases.sine(freq=3.0, amp=0.012)
    for shape in ('bingham_tanh', 'algebraic', 'arctan'):
        out = rig.simulate(truthcases.linear_truth(shape=shape), t, x, np.full(t.size, 0.7))
        v = 0.012 * 2 * np.pi * 3.0 * np.cos(2 * np.pi * 3.0 * t)
        inner = slice(5, -5)  # the not-a-knot spline ends are slightly less exact
        assert np.max(np.abs(out['force'][inner] - 1500.0 * v[inner])) < 1e-6 * 1500 * 0.23


def test_first_order_lag_step_response():
    rate, tau = 1000.0, 0.0173
    t = np.arange(400) / rate
    cmd = np.where(np.arange(400) >= 50, 1.0, 0.0)
    out = rig.simulate(rig.RigTruth(tau_rise=tau, tau_fall=tau), t, np.zeros(400), cmd)
    ts = t - 0.050
    expect = np.where(ts > 0, 1.0 - np.exp(-np.clip(ts, 0, None) / tau), 0.0)
    assert np.max(np.abs(out['field_current'] - expect)) < 1e-6
    # The coil (driver output) is ideal here: it is the held command.
    assert np.array_equal(out['coil_current'], cmd)


def test_dead_time_shifts_the_step_by_a_fractional_time():
    rate, tau, dead = 1000.0, 0.004, 0.0113  # 11.3 samples
    t = np.arange(300) / rate
    cmd = np.where(np.arange(300) >= 20, 0.8, 0.0)
    truth = rig.RigTruth(dead_time=dead, tau_rise=tau, tau_fall=tau)
    out = rig.simulate(truth, t, np.zeros(300), cmd)
    ts = t - 0.020 - dead
    expect = np.where(ts > 0, 0.8 * (1.0 - np.exp(-np.clip(ts, 0, None) / tau)), 0.0)
    assert np.max(np.abs(out['field_current'] - expect)) < 1e-6
    # A whole-sample dead time (11 or 12 samples) would miss by far more.
    for d in (0.011, 0.012):
        ts = t - 0.020 - d
        other = np.where(ts > 0, 0.8 * (1.0 - np.exp(-np.clip(ts, 0, None) / tau)), 0.0)
        assert np.max(np.abs(out['field_current'] - other)) > 0.01


def test_asymmetric_lag_rises_and_falls_with_its_own_constants():
    rate, tr, tf = 1000.0, 0.003, 0.040
    t = np.arange(600) / rate
    cmd = np.where((np.arange(600) >= 100) & (np.arange(600) < 300), 1.0, 0.0)
    out = rig.simulate(rig.RigTruth(tau_rise=tr, tau_fall=tf), t, np.zeros(600), cmd)
    k = np.arange(600)
    rise = 1.0 - np.exp(-(t - 0.1) / tr)
    fall = (1.0 - np.exp(-0.2 / tr)) * np.exp(-(t - 0.3) / tf)
    expect = np.where(k < 100, 0.0, np.where(k < 300, rise, fall))
    assert np.max(np.abs(out['field_current'] - expect)) < 1e-6


def test_driver_site_puts_the_current_dynamics_before_the_coil_measurement():
    t = np.arange(200) / 1000.0
    cmd = np.where(np.arange(200) >= 50, 1.0, 0.0)
    for site, coil_lags in (('field', False), ('driver', True)):
        truth = rig.RigTruth(tau_rise=0.01, tau_fall=0.01, current_site=site)
        out = rig.simulate(truth, t, np.zeros(200), cmd)
        assert np.array_equal(out['coil_current'], cmd) != coil_lags
        assert out['field_current'][60] == pytest.approx(1 - np.exp(-1.0), abs=1e-6)


@pytest.mark.parametrize('k1', [8e4, 5e7])
def test_series_spring_with_linear_damper_phase_and_amplitude(k1):
    c, f, amp = 2000.0, 5.0, 0.004
    w = 2 * np.pi * f
    t, x = truthcases.sine(freq=f, amp=amp, duration=2.0)
    out = rig.simulate(truthcases.linear_truth(c0=c, k_series=k1), t, x, np.zeros(t.size))
    keep = t >= 1.0  # transients decay with c / k1 <= 25 ms
    a, b = _harmonic_fit(t[keep], out['force'][keep], w)
    r = c * w / k1
    # F = A cos(w t - phi) against v = amp w cos(w t).
    assert np.hypot(a, b) == pytest.approx(c * w * amp / np.sqrt(1 + r * r), rel=1e-5)
    assert np.arctan2(b, a) == pytest.approx(np.arctan(r), abs=1e-5)


def test_bouc_wen_state_is_bounded_by_its_closed_form():
    a, beta, gamma, n = 3000.0, 2000.0, -500.0, 1.5
    zmax = (a / (beta + gamma)) ** (1 / n)
    truth = rig.RigTruth(shape='bouc_wen', bw_a=a, bw_beta=beta, bw_gamma=gamma, bw_n=n)
    assert truth.z_max == pytest.approx(zmax)
    t, x = truthcases.sine(freq=1.5, amp=0.015, duration=2.0)
    z = rig.simulate(truth, t, x, np.full(t.size, 0.5))['bw_z']
    assert np.max(np.abs(z)) <= zmax * (1 + 1e-9)
    assert np.max(np.abs(z)) > 0.99 * zmax


def test_direction_asymmetry_ratio_at_high_speed():
    rho = 0.3
    t, x = truthcases.sine(freq=2.0, amp=0.02, duration=1.0)
    out = rig.simulate(truthcases.linear_truth(rho=rho, v_switch=0.005), t, x, np.zeros(t.size))
    v = out['velocity']
    fast = np.abs(v) > 0.2
    ratio = out['force'][fast] / (1500.0 * v[fast])
    expect = 1 + rho * np.tanh(v[fast] / 0.005)
    assert np.allclose(ratio, expect, rtol=1e-6)
    assert np.max(ratio[v[fast] > 0]) / np.min(ratio[v[fast] < 0]) == pytest.approx(1.3 / 0.7,
                                                                                    rel=1e-6)


def test_gas_spring_and_saturation_closed_forms():
    truth = rig.RigTruth(gas_p0=2e6, gas_area=2e-4, gas_volume=4e-5, gas_n=1.3, i_sat=0.4,
                         c1=0.0, fy0=0.0, fy1=100.0, c0=1.0, driver_tau=0.0)
    x = np.linspace(-0.02, 0.02, 9)
    expect = -2e6 * 2e-4 * ((4e-5 / (4e-5 + 2e-4 * x)) ** 1.3 - 1.0)
    assert np.allclose(rig.gas_force(truth, x), expect, rtol=1e-12)
    # Stiffness at 0 is p0 A^2 n / V0 and the force resists the stroke.
    k0 = (rig.gas_force(truth, 1e-7) - rig.gas_force(truth, -1e-7)) / 2e-7
    assert k0 == pytest.approx(2e6 * 4e-8 * 1.3 / 4e-5, rel=1e-5)
    t = np.arange(100) / 1000.0
    cmd = np.linspace(0.0, 2.0, 100)
    out = rig.simulate(truth, t, np.zeros(100), cmd)
    assert np.allclose(out['effective_current'], 0.4 * (1 - np.exp(-cmd / 0.4)), atol=1e-12)


def test_thermal_fade_heats_with_dissipated_power_and_fades_the_force():
    truth = truthcases.linear_truth(thermal_beta_c=0.02, heat_capacity=50.0,
                                    thermal_resistance=0.5)
    t, x = truthcases.sine(freq=3.0, amp=0.01, duration=4.0)
    out = rig.simulate(truth, t, x, np.zeros(t.size))
    temp = out['temperature']
    power = out['force'] * out['velocity']
    # Energy balance C dT/dt = P - T/R integrated along the record (trapezoid).
    lhs = 50.0 * temp[-1]
    rhs = np.trapezoid(power - temp / 0.5, t)
    assert lhs == pytest.approx(rhs, rel=2e-3)
    assert temp[-1] > 1.0
    ratio = out['force'][-300:] / (1500.0 * out['velocity'][-300:])
    fast = np.abs(out['velocity'][-300:]) > 0.05
    assert np.allclose(ratio[fast], np.exp(-0.02 * temp[-300:][fast]), rtol=1e-9)


def _strong_truth(shape, seed=5, exclude=('current_lag', 'gas_spring')):
    effects = tuple(e for e in rig.EFFECTS if e not in exclude)
    return rig.draw_truth(np.random.default_rng(seed), effects, shape=shape, strength=0.8)


@pytest.mark.parametrize('shape', rig.SHAPES)
def test_halving_the_substep_changes_the_force_far_less_than_the_noise(shape):
    rng = np.random.default_rng(11)
    t, x, i = rig.programme(rng, 6.0, 1000.0, 'full')
    truth = _strong_truth(shape)
    f10 = rig.simulate(truth, t, x, i, substeps=10)['force']
    f20 = rig.simulate(truth, t, x, i, substeps=20)['force']
    # The quietest sensor drawn has about 0.5 % of std(F) of noise.
    noise = 0.005 * np.std(f20)
    assert np.sqrt(np.mean((f10 - f20) ** 2)) < 0.02 * noise


def _cycle_energy(truth, current, freq=2.0, amp=0.012):
    t, x = truthcases.sine(freq=freq, amp=amp, duration=2.0)
    out = rig.simulate(truth, t, x, np.full(t.size, current))
    last = t >= 1.5  # one whole cycle (steady state)
    return np.trapezoid(out['force'][last] * out['velocity'][last], t[last])


@pytest.mark.parametrize('shape', rig.SHAPES)
def test_every_shape_dissipates_and_dissipates_more_with_current(shape):
    for truth in (rig.draw_truth(np.random.default_rng(2), (), shape=shape),
                  _strong_truth(shape, seed=3)):
        energies = [_cycle_energy(truth, i) for i in (0.0, 0.5, 1.0)]
        assert energies[0] > 0
        assert energies[0] < energies[1] < energies[2]


def test_without_switches_one_effect_off_and_contributions_are_positive():
    truth = rig.draw_truth(np.random.default_rng(4), ('current_delay', 'hysteresis',
                                                      'gas_spring'), strength=0.7)
    assert truth.effects == ('current_delay', 'hysteresis', 'gas_spring')
    assert truth.without('hysteresis').effects == ('current_delay', 'gas_spring')
    t, x, i = rig.programme(np.random.default_rng(1), 4.0, 1000.0, 'full')
    contrib = rig.contributions(truth, t, x, i)
    assert set(contrib) == set(truth.effects)
    assert all(v > 0 for v in contrib.values())
    gas = rig.gas_force(truth, x)
    assert contrib['gas_spring'] == pytest.approx(np.sqrt(np.mean(gas ** 2)), rel=1e-9)


def test_strength_orders_the_drawn_parameters():
    weak = rig.draw_truth(np.random.default_rng(1), rig.EFFECTS[:1] + rig.EFFECTS[3:],
                          strength=0.0)
    strong = rig.draw_truth(np.random.default_rng(1), rig.EFFECTS[:1] + rig.EFFECTS[3:],
                            strength=1.0)
    assert strong.dead_time > 10 * weak.dead_time
    assert strong.i_sat < weak.i_sat / 5
    assert strong.k_series < weak.k_series / 50
    assert abs(strong.rho) > 5 * abs(weak.rho)
    assert strong.gas_volume / strong.gas_area < weak.gas_volume / weak.gas_area


@pytest.mark.parametrize('kind', ['full', 'harmonic', 'steps', 'random', 'continuous', 'sweep',
                                  'single', 'constant'])
def test_programmes_start_and_end_at_rest_within_limits(kind):
    t, x, i = rig.programme(np.random.default_rng(3), 12.0, 500.0, kind, stroke=0.02,
                            v_max=0.3, i_max=1.5)
    assert t.size == 6000 and np.allclose(np.diff(t), 1 / 500.0)
    assert abs(x[0]) < 1e-9 and abs(x[-1]) < 2e-4
    assert np.max(np.abs(x)) <= 0.03 + 1e-9
    assert np.max(np.abs(np.gradient(x, t))) < 0.35
    assert i.min() >= 0 and i.max() <= 1.5
    assert i.max() > 0
    if kind not in ('constant', 'sweep'):
        assert np.unique(np.round(i, 9)).size >= 3


def test_bad_inputs_raise_clear_errors():
    t, x = truthcases.sine(duration=0.5)
    i = np.zeros(t.size)
    for bad in ({'shape': 'spencer'}, {'c0': 0.0}, {'tau_rise': 0.01}, {'rho': 0.6},
                {'bw_gamma': 1e5}, {'k_series': -1.0}, {'v_y': float('nan')}):
        with pytest.raises(ValueError):
            rig.RigTruth(**bad)
    with pytest.raises(ValueError, match='uniform'):
        rig.simulate(rig.RigTruth(), t ** 2, x, i)
    with pytest.raises(ValueError, match='samples'):
        rig.simulate(rig.RigTruth(), t, x[:-1], i)
    with pytest.raises(ValueError, match='unknown effect'):
        rig.draw_truth(np.random.default_rng(0), ('friction',))
    with pytest.raises(ValueError, match='exclude'):
        rig.draw_truth(np.random.default_rng(0), ('current_lag', 'current_lag_asymmetric'))
    with pytest.raises(ValueError, match='kind'):
        rig.programme(np.random.default_rng(0), 1.0, 100.0, 'chirp')
    with pytest.raises(ValueError, match='unknown fault'):
        sensors.draw_sensor(np.random.default_rng(0), faults=('gremlins',))
    with pytest.raises(ValueError, match='clean'):
        sensors.draw_sensor(np.random.default_rng(0), faults=('drift',), clean=True)


# -------------------------------------------------------------------------------- sensors

def _clean_record(duration=8.0, rate=1000.0, seed=0):
    rng = np.random.default_rng(seed)
    t, x, i = rig.programme(rng, duration, rate, 'random')
    return t, rig.simulate(rig.draw_truth(rng, (), shape='arctan'), t, x, i)


def _upsampled_xcorr_delay(ref, meas, up=64):
    """Lag (samples) maximising the circular cross-correlation, FFT-upsampled ``up`` times."""
    n = ref.size
    a = np.fft.rfft(ref - ref.mean())
    b = np.fft.rfft(meas - meas.mean())
    spec = np.conj(a) * b
    full = np.zeros(n * up // 2 + 1, dtype=complex)
    full[:spec.size] = spec
    cc = np.fft.irfft(full, n * up)
    k = int(np.argmax(cc))
    lag = k if k < n * up // 2 else k - n * up
    return lag / up


@pytest.mark.parametrize('delay_samples', [2.37, -0.6])
def test_force_delay_is_recovered_by_cross_correlation(delay_samples):
    t, clean = _clean_record()
    spec = sensors.SensorSpec(force_white=0.0, force_ar=0.0, force_delay=delay_samples / 1000)
    cols, info = sensors.apply(np.random.default_rng(1), t, clean, spec)
    cut = slice(100, -100)
    est = _upsampled_xcorr_delay(clean['force'][cut], cols['force'][cut])
    assert est == pytest.approx(delay_samples, abs=0.1)


def test_anti_alias_filter_is_causal_and_lags():
    t, clean = _clean_record()
    spec = sensors.SensorSpec(force_white=0.0, force_ar=0.0, force_filter_hz=100.0)
    cols, _ = sensors.apply(np.random.default_rng(1), t, clean, spec)
    est = _upsampled_xcorr_delay(clean['force'][100:-100], cols['force'][100:-100])
    # Group delay of a 2nd-order Butterworth at low frequency: sqrt(2) / (2 pi fc) = 2.25 ms.
    assert est == pytest.approx(np.sqrt(2) / (2 * np.pi * 100.0) * 1000, abs=0.3)


def test_rounded_stamps_clipping_and_noise_floor():
    t, clean = _clean_record(rate=3000.0, duration=4.0)
    spec = sensors.SensorSpec(force_white=0.004, force_ar=0.012, force_ar_tau=0.008,
                              clip_fraction=0.8, time_quantum=1e-4)
    cols, info = sensors.apply(np.random.default_rng(2), t, clean, spec)
    q = cols['time'] / 1e-4
    assert np.max(np.abs(q - np.round(q))) < 1e-6
    assert np.all(np.diff(cols['time']) > 0)
    assert len(np.unique(np.round(np.diff(cols['time']), 9))) > 1  # irregular now
    rail = info['rail']
    f = cols['force']
    assert np.max(np.abs(f)) <= rail
    held = np.abs(f) == rail
    assert held.sum() == info['clipped'] > 0
    noise = (f - clean['force'])[~held]
    assert info['noise_rms'] == pytest.approx(np.std(noise), rel=1e-9)
    target = np.hypot(0.004, 0.012) * np.std(clean['force'])
    assert info['noise_rms'] == pytest.approx(target, rel=0.15)
    assert info['floor_nrmse'] == pytest.approx(np.std(noise) / np.std(f[~held]), rel=1e-9)


def test_velocity_current_and_dropout_variants():
    t, clean = _clean_record(duration=4.0)
    base = {'force_white': 0.005, 'force_ar': 0.0, 'displacement_noise': 5e-6}
    cols, _ = sensors.apply(np.random.default_rng(0), t, clean,
                            sensors.SensorSpec(velocity='derived', current='absent', **base))
    assert np.allclose(cols['velocity'], np.gradient(cols['displacement'], cols['time']))
    assert 'current' not in cols
    cols, _ = sensors.apply(np.random.default_rng(0), t, clean,
                            sensors.SensorSpec(velocity='absent', current_noise=0.01, **base))
    assert 'velocity' not in cols
    assert np.std(cols['current'] - clean['coil_current']) == pytest.approx(0.01, rel=0.1)
    spec = sensors.SensorSpec(dropout='nan', dropout_fraction=0.005, **base)
    cols, info = sensors.apply(np.random.default_rng(0), t, clean, spec)
    nan = np.isnan(cols['force'])
    assert nan.sum() == info['dropped'] >= 20
    assert np.array_equal(nan, np.isnan(cols['displacement']))
    assert not np.isnan(cols['current_command']).any()
    spec = sensors.SensorSpec(dropout='missing', dropout_fraction=0.005, **base)
    cols, info = sensors.apply(np.random.default_rng(0), t, clean, spec)
    assert cols['time'].size == t.size - info['dropped']
    assert np.array_equal(cols['time'], t[info['rows']])
    spec = sensors.SensorSpec(dropout='hold', dropout_fraction=0.005, **base)
    cols, info = sensors.apply(np.random.default_rng(0), t, clean, spec)
    assert np.sum(np.diff(cols['force']) == 0) >= info['dropped']


def test_draw_sensor_clean_and_faults():
    rng = np.random.default_rng(0)
    spec = sensors.draw_sensor(rng, faults=None, clean=True)
    assert spec.faults == () and spec.force_delay == 0 and spec.clip_fraction == 0
    assert spec.displacement_noise == 0 and spec.dropout == 'none'
    assert spec.force_white > 0 and spec.force_ar > 0
    spec = sensors.draw_sensor(rng, faults=('channel_delay', 'clipping', 'dropout_hold'),
                               rate=2000.0)
    assert 0.3e-3 <= abs(spec.force_delay) <= 5e-3
    assert 0.7 <= spec.clip_fraction <= 0.95 and spec.dropout == 'hold'
    for _ in range(20):
        spec = sensors.draw_sensor(rng, faults=None)
        assert len(spec.faults) <= 3


# ---------------------------------------------------------------------------------- cases

def test_make_case_columns_csv_and_unseen_record(tmp_path):
    case = cases.make_case(7, ('current_lag', 'series_stiffness'), ('channel_delay',),
                           duration=4.0, rate=500.0, measured_current=True, strength=0.6)
    cols = case.columns
    assert set(cols) == {'time', 'displacement', 'velocity', 'force', 'current_command',
                         'current'}
    assert all(v.size == 2000 for v in cols.values())
    assert case.effects == ('current_lag', 'series_stiffness')
    assert set(case.contributions) == set(case.effects)
    assert case.contributions['series_stiffness'] == pytest.approx(
        case.contributions_n['series_stiffness'] / case.noise_rms)
    assert 0 < case.floor_nrmse < 0.1
    path = case.write_csv(tmp_path / 'case.csv')
    table = np.genfromtxt(path, delimiter=',', names=True)
    for name in cols:
        assert np.allclose(table[name], cols[name], rtol=1e-9, atol=1e-12)
    other = case.unseen()
    assert other.record == 1 and other.truth == case.truth
    assert other.sensor['spec'] == case.sensor['spec']
    assert not np.allclose(other.columns['displacement'], cols['displacement'])
    again = cases.make_case(7, ('current_lag', 'series_stiffness'), ('channel_delay',),
                            duration=4.0, rate=500.0, measured_current=True, strength=0.6)
    assert np.array_equal(again.columns['force'], cols['force'])


def test_make_case_missing_rows_keep_clean_force_aligned():
    case = cases.make_case(3, (), ('dropout_missing',), duration=3.0, measured_current=False)
    n = case.columns['time'].size
    assert n < 3000 and 'current' not in case.columns
    assert case.clean_force.size == n
    resid = case.columns['force'] - case.clean_force
    assert np.std(resid) == pytest.approx(case.noise_rms, rel=1e-9)


# ------------------------------------------------------------------------------ isolation

def test_truth_modules_import_nothing_from_the_fitting_code():
    files = sorted(TRUTH_DIR.glob('*.py'))
    assert {f.name for f in files} >= {'__init__.py', 'rig.py', 'sensors.py', 'cases.py'}
    for path in files:
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                mod = node.module or ''
                names = [mod] + [f'{mod}.{a.name}' for a in node.names]
            for name in names:
                assert not name.startswith(FORBIDDEN), f'{path.name} imports {name}'
                if name.startswith('mr_suspension'):
                    # Road profiles are the experiment's input, not a model under judgement.
                    assert name.startswith(('mr_suspension.truth', 'mr_suspension.core.road',
                                            'mr_suspension.core.car_road')), \
                        f'{path.name}: {name}'
        assert 'importlib' not in path.read_text()


def test_transfer_floor_counts_a_drifting_channels_level_shift():
    """A fitted model carries the training record's mean noise; drift moves it per record."""
    drift = cases.make_case(3, (), sensor_faults=('drift',), duration=6.0,
                            measured_current=False)
    unseen = drift.unseen()
    info_t, info_u = drift.sensor['info'], unseen.sensor['info']
    e_t = (drift.columns['force'] - info_t['reference_force'])[info_t['valid']]
    e_u = (unseen.columns['force'] - info_u['reference_force'])[info_u['valid']]
    s_u = np.std(unseen.columns['force'][info_u['valid']])
    shift = (np.mean(e_u) - np.mean(e_t)) / s_u
    got = cases.transfer_floor(drift, unseen)
    # mean((e - m)^2) = var(e) + (mean(e) - m)^2: the own floor plus the level shift.
    assert got == pytest.approx(np.hypot(unseen.floor_nrmse, shift), rel=1e-9)
    assert abs(shift) > 0.2 * unseen.floor_nrmse  # the drift's shift is not negligible here
    # Without drift the two floors agree (the coloured noise's mean is small).
    still = cases.make_case(3, (), sensor_faults=(), duration=6.0, measured_current=False)
    assert cases.transfer_floor(still, still.unseen()) == pytest.approx(
        still.unseen().floor_nrmse, rel=0.05)


_DIGEST = """
import hashlib
import numpy as np
from mr_suspension.truth import cases
h = hashlib.sha1()
for shape in ('bingham_tanh', 'algebraic', 'arctan', 'bouc_wen'):
    case = cases.make_case(7, ('series_stiffness', 'thermal_fade', 'current_lag'), shape=shape,
                           sensor_faults=('derived_velocity',), duration=1.5)
    for name in sorted(case.columns):
        h.update(np.ascontiguousarray(case.columns[name]).tobytes())
print(h.hexdigest())
"""


def test_a_case_is_the_same_data_from_a_fresh_compile_and_from_numbas_cache(tmp_path):
    """A truth case's records must not depend on the compile state of the truth's kernels.

    A difference of one ulp in the force between a process that compiled the kernels and
    one that loaded them from numba's cache (as ``fastmath`` allows) is enough for a chaotic
    selection to name another cause set. Two processes, one cache folder: the first
    compiles and writes it, the second loads it; every column must be bit-identical.
    """
    env = {**os.environ, 'NUMBA_CACHE_DIR': str(tmp_path / 'numba')}
    out = [subprocess.run([sys.executable, '-c', _DIGEST], env=env, capture_output=True,
                          text=True, timeout=600, check=True).stdout.strip()
           for _ in range(2)]
    assert any((tmp_path / 'numba').rglob('*.nbi'))  # the second process had a cache
    assert len(out[0]) == 40 and out[0] == out[1]
