"""Offline simulator: determinism, batch kernels, roads, configs, CLI and bad input."""

import json

import numpy as np
import pytest

from mr_suspension import cli
from mr_suspension.control.laws import ControllerParams
from mr_suspension.core import road as rd
from mr_suspension.core.metrics import ride_metrics
from mr_suspension.sim import config
from mr_suspension.sim.simulator import CornerConfig, simulate, simulate_batch


def _corner(**kw):
    base = {'car': config.load_vehicle('city_car'),
            'damper': config.load_damper('rd1005_bingham'),
            'driver': config.load_driver('wonder_box')}
    base.update(kw)
    return CornerConfig(**base)


def test_deterministic_for_a_seed():
    cfg = _corner(controller=config.load_controller('skyhook_onoff'))
    a = simulate(cfg, rd.iso8608('C', speed=20.0, duration=5.0, seed=7))
    b = simulate(cfg, rd.iso8608('C', speed=20.0, duration=5.0, seed=7))
    c = simulate(cfg, rd.iso8608('C', speed=20.0, duration=5.0, seed=8))
    assert np.array_equal(a.data, b.data)
    assert not np.array_equal(a.data, c.data)


def test_batch_kernels_agree_with_single_runs():
    roads = [rd.iso8608('B', speed=15.0, duration=4.0, seed=s) for s in range(2)]
    cfgs = [_corner(controller=ControllerParams(current=i), control_delay=d)
            for i in (0.0, 0.4, 1.2) for d in (0.0, 0.005)]
    cfgs.append(_corner(damper=config.load_damper('seed002_tanh')))
    cfgs.append(_corner(damper=config.load_damper('passive_linear'),
                        driver=config.load_driver('ideal')))
    idx = np.arange(len(cfgs)) % 2
    fast = simulate_batch(cfgs, roads, idx)
    generic = simulate_batch(cfgs, roads, idx, fast=False)
    for c, cfg in enumerate(cfgs):
        single = ride_metrics(simulate(cfg, roads[idx[c]]))
        for key in ('body_acc_rms', 'body_acc_wk_rms', 'vdv', 'working_space_rms',
                    'working_space_peak', 'tyre_load_rms', 'body_acc_peak'):
            assert fast[key][c] == pytest.approx(generic[key][c], rel=1e-9)
            assert fast[key][c] == pytest.approx(single[key], rel=1e-6), key
        assert fast['damper_energy'][c] > 0.0


def test_batch_generic_path_for_stateful_laws_and_feedback():
    roads = [rd.bump(duration=3.0)]
    cfgs = [_corner(damper=config.load_damper('seed000_mechanical')),
            _corner(controller=config.load_controller('skyhook_onoff'))]
    out = simulate_batch(cfgs, roads)
    for c, cfg in enumerate(cfgs):
        single = ride_metrics(simulate(cfg, roads[0]))
        assert out['body_acc_rms'][c] == pytest.approx(single['body_acc_rms'], rel=1e-9)


def test_semi_active_current_changes_the_ride():
    road = rd.bump(height=0.05, duration=4.0)
    soft = ride_metrics(simulate(_corner(controller=ControllerParams(current=0.0)), road))
    hard = ride_metrics(simulate(_corner(controller=ControllerParams(current=1.5)), road))
    assert hard['working_space_peak'] < soft['working_space_peak']
    assert hard['body_acc_peak'] > soft['body_acc_peak']


def test_iso8608_road_has_the_class_psd():
    speed, dt = 20.0, 1e-3
    road = rd.iso8608('D', speed=speed, duration=200.0, dt=dt, seed=3)
    z = road.z[road.t > 1.0]
    n = z.size
    spec = np.abs(np.fft.rfft(z)) ** 2 * 2 * dt / n
    f = np.fft.rfftfreq(n, dt)
    band = (f > 0.5) & (f < 8.0)
    ratio = spec[band] / (rd.iso8608_psd(f[band] / speed, 'D') / speed)
    assert np.mean(ratio) == pytest.approx(1.0, rel=0.1)
    # The exact road rate matches the numerical derivative (which loses the highest bands).
    err = np.gradient(road.z, dt)[2000:-2] - road.zdot[2000:-2]
    assert np.sqrt(np.mean(err ** 2)) < 0.15 * np.sqrt(np.mean(road.zdot[2000:] ** 2))


def test_road_generators_and_bad_input():
    bump = rd.bump(height=0.04, length=2.0, speed=10.0, t0=0.5, duration=2.0)
    assert bump.z.max() == pytest.approx(0.04, rel=1e-3)
    assert bump.z[bump.t < 0.5].max() == 0.0
    step = rd.step(height=0.03, duration=2.0)
    assert step.z[-1] == pytest.approx(0.03)
    with pytest.raises(ValueError, match='class'):
        rd.iso8608('Z')
    with pytest.raises(ValueError, match='road type'):
        rd.from_spec({'type': 'cobbles'})
    with pytest.raises(ValueError):
        rd.harmonic(amplitude=-1.0)
    cfg = _corner()
    with pytest.raises(ValueError, match='dt'):
        simulate(cfg, rd.bump(duration=1.0, dt=2e-3))
    bad = rd.Road('bad', 1e-3, np.full(100, np.nan), np.zeros(100))
    with pytest.raises(ValueError, match='NaN'):
        simulate(cfg, bad)
    with pytest.raises(ValueError, match='control_delay'):
        CornerConfig(control_delay=1.0)
    with pytest.raises(ValueError):
        simulate_batch([], [bump])


def test_every_config_set_loads_and_runs():
    road = rd.bump(duration=1.0)
    for kind, loader in (('vehicles', config.load_vehicle), ('dampers', config.load_damper),
                         ('drivers', config.load_driver),
                         ('controllers', config.load_controller)):
        names = config.available(kind)
        assert names, kind
        for name in names:
            if kind == 'vehicles' and 'front' in config.load_yaml(kind, name):
                continue  # a full car: test_full_car runs every full-car file
            obj = loader(name)
            kw = {'vehicles': 'car', 'dampers': 'damper', 'drivers': 'driver',
                  'controllers': 'controller'}[kind]
            res = simulate(_corner(**{kw: obj}), road)
            assert np.all(np.isfinite(res.data)), (kind, name)


def test_config_errors_are_clear(tmp_path):
    with pytest.raises(FileNotFoundError, match='available'):
        config.load_vehicle('no_such_car')
    bad = tmp_path / 'bad.yaml'
    bad.write_text('m_s: 200\nwheels: 4\n')
    with pytest.raises(ValueError, match='unknown parameter'):
        config.load_vehicle(bad)
    bad.write_text('m_s: [1, 2\n')
    with pytest.raises(ValueError, match='YAML'):
        config.load_vehicle(bad)


def test_cli_simulate_writes_csv_plots_and_metrics(tmp_path, capsys):
    out = tmp_path / 'sim'
    rc = cli.main(['simulate', '--road', 'bump', '--duration', '2', '--out', str(out)])
    assert rc == 0
    assert (out / 'bump_skyhook_onoff.csv').is_file()
    assert (out / 'bump_passive_0A.csv').is_file()
    assert (out / 'bump_time.png').stat().st_size > 10000
    metrics = json.loads((out / 'metrics.json').read_text())
    assert set(metrics) == {'skyhook_onoff', 'passive_0A'}
    header = (out / 'bump_passive_0A.csv').read_text().splitlines()[0]
    assert header.startswith('time,z_s,z_u')
    assert 'body acc. RMS' in capsys.readouterr().out


def test_cli_reports_bad_input_without_traceback(tmp_path, capsys):
    rc = cli.main(['simulate', '--vehicle', 'nope', '--out', str(tmp_path)])
    assert rc == 2
    assert 'no vehicles parameter set' in capsys.readouterr().err
