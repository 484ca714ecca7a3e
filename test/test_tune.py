"""The one corner builder, metric names, ``evaluate``'s exit code, and ``tune``."""

import argparse

import numpy as np
import pytest

from mr_suspension import cli
from mr_suspension.control.laws import ControllerParams
from mr_suspension.core.metrics import ride_metrics
from mr_suspension.evaluation import runner, tune, tune_cli
from mr_suspension.sim import config as cfg, corner
from mr_suspension.sim.simulator import simulate

ROADS = ('bump',)  # one short road keeps the tuning tests fast


def _simulate_args(*extra):
    return cli.build_parser().parse_args(['simulate', *extra])


def test_simulate_builder_gives_the_controller_its_plant():
    """Defect: simulate gave PDD the city car's masses and a Bingham inverse."""
    args = _simulate_args('--vehicle', 'seed001_military', '--damper', 'seed002_tanh',
                          '--controller', 'pdd')
    conf = cli.corner_from_args(args)
    car = cfg.load_vehicle('seed001_military')
    ctrl = conf.controller
    assert (ctrl.m_s, ctrl.m_u, ctrl.k_s, ctrl.k_t) == (car.m_s, car.m_u, car.k_s, car.k_t)
    assert ctrl.damper_model['law'] == 'tanh'
    assert ctrl.i_max <= conf.driver.i_range
    # The reference run of simulate gets the same plant knowledge.
    ref = cli.corner_from_args(args, args.reference)
    assert ref.controller.m_s == car.m_s and ref.controller.damper_model['law'] == 'tanh'
    # One builder: the evaluation builds exactly the same corner.
    assert conf == runner.build_config('pdd', 'seed001_military', 'seed002_tanh', 'wonder_box')


def test_nodes_builder_equals_simulate_builder():
    common = pytest.importorskip('mr_suspension.nodes.common')
    args = _simulate_args('--vehicle', 'seed001_military', '--damper', 'seed002_tanh',
                          '--controller', 'pdd')
    nodes = common.corner_config('seed001_military', 'seed002_tanh', 'wonder_box', 'pdd')
    assert nodes == cli.corner_from_args(args)
    assert nodes.controller.m_s == cfg.load_vehicle('seed001_military').m_s


def test_builder_bad_input():
    with pytest.raises(ValueError, match='unknown controller'):
        corner.build_corner('teleport')
    with pytest.raises(ValueError):
        corner.build_corner('skyhook', driver=3.0)
    with pytest.raises(ValueError):
        corner.load_controller('skyhook', {'c_sky': -1.0})


def test_evaluate_exits_zero_after_success(tmp_path):
    """Defect: ``evaluate`` returned its rows, so ``sys.exit(rows)`` exited with 1."""
    code = cli.main(['evaluate', '--laws', 'passive_0A', '--scenarios', 'bump', '--study',
                     'none', '--no-plots', '--out', str(tmp_path / 'ev')])
    assert code == 0
    assert (tmp_path / 'ev' / 'report.md').is_file()


def test_ntf_min_means_the_normalised_tyre_force_everywhere():
    """Defect: ``ntf_min`` was a force [N] in the batch metrics, F_t / F_t0 in ride_metrics."""
    conf = corner.build_corner('skyhook_onoff', 'seed003_passenger')
    road = tune._road('bump', conf.dt)
    one = ride_metrics(simulate(conf, road))
    batch = corner.batch_metrics([conf], [road])
    assert 0.0 <= one['ntf_min'] <= 1.0
    assert batch['ntf_min'][0] == pytest.approx(one['ntf_min'], rel=1e-6)
    assert batch['tyre_force_min'][0] == pytest.approx(one['tyre_force_min'], rel=1e-6)
    assert one['tyre_force_min'] == pytest.approx(one['ntf_min'] * conf.car.static_tyre_load)
    via_runner = runner.batch_metrics([conf], road)['ntf_min'][0]
    assert via_runner == pytest.approx(one['ntf_min'], rel=1e-6)
    name, unit = cli.METRIC_LABELS['ntf_min']
    assert unit == '-' and 'F_t / F_t0' in name
    assert cli.METRIC_LABELS['tyre_force_min'][1] == 'N'


def test_passive_sweep_equals_constant_current_runs():
    plant = tune.Plant(roads=('bump', 'iso_C_20'))
    sweep = tune.passive_sweep(plant, n=11)
    assert sweep['current'][0] == 0.0 and sweep['current'][-1] == pytest.approx(
        cfg.load_driver('wonder_box').i_range)
    for k in (0, 6):
        conf = plant.corner(ControllerParams(law='constant', current=float(sweep['current'][k])))
        for r, name in enumerate(plant.roads):
            met = ride_metrics(simulate(conf, tune._road(name, plant.dt)))
            for key in ('body_acc_wk_rms', 'tyre_load_rms', 'working_space_rms'):
                assert sweep[key][k, r] == pytest.approx(met[key], rel=1e-6), (k, name, key)


@pytest.fixture(scope='module')
def skyhook_study():
    return tune.study(['skyhook'], tune.Plant(roads=ROADS), comfort_weight=1.0, ws_ratio=0.9,
                      n_passive=11, maxiter=3, seed=1)


def test_tuned_law_no_worse_than_default_and_within_limit(skyhook_study):
    res = skyhook_study['tuned'][0]
    obj = skyhook_study['objective_obj']
    pen = {k: res[k]['J'] + tune.RHO * max(res[k]['g'], 0.0) for k in ('default', 'tuned')}
    assert pen['tuned'] <= pen['default']
    assert res['tuned']['g'] <= 1e-9
    ws = np.asarray(res['tuned']['metrics']['working_space_rms'])
    assert np.all(ws <= obj.limit * (1.0 + 1e-9))
    for (lo, hi), g in zip([(g['lo'], g['hi']) for g in res['gains']], res['gains']):
        assert lo <= res['tuned']['gains'][g['name']] <= hi
    eq = res['equal_space']
    assert eq['current'] is not None and np.isfinite(eq['wk_change_pct'])
    passive_ws = np.asarray(eq['passive']['metrics']['working_space_rms'])
    assert np.all(passive_ws <= ws * (1.0 + 1e-9))  # the passive uses no more working space


def test_tuned_yaml_round_trips(skyhook_study, tmp_path):
    tune_cli.write_outputs(skyhook_study, tmp_path, plots=False)
    res = skyhook_study['tuned'][0]
    path = tmp_path / 'controllers' / 'skyhook.yaml'
    loaded = cfg.load_controller(str(path))
    assert loaded == res['controller']
    plant = skyhook_study['plant_obj']
    met = tune.evaluate([plant.corner(str(path))], plant.roads, plant.dt)
    assert met['body_acc_wk_rms'][0] == pytest.approx(res['tuned']['metrics']['body_acc_wk_rms'])
    report = (tmp_path / 'report.md').read_text()
    assert 'equal working space' in report and (tmp_path / 'report.json').is_file()


def test_bad_input():
    plant = tune.Plant(roads=ROADS)
    with pytest.raises(ValueError, match='unknown law'):
        tune.study(['astrology'], plant, maxiter=1)
    with pytest.raises(ValueError, match='empty'):
        tune.study(['skyhook'], tune.Plant(roads=()), maxiter=1)
    with pytest.raises(ValueError, match='unknown scenario'):
        tune.study(['skyhook'], tune.Plant(roads=('mars',)), maxiter=1)
    with pytest.raises(tune.InfeasibleError, match='infeasible'):
        tune.study(['skyhook'], plant, ws_limit=1e-5, n_passive=11, maxiter=1)
    with pytest.raises(ValueError, match='at least 11'):
        tune.study(['skyhook'], plant, n_passive=5, maxiter=1)
    with pytest.raises(ValueError, match='comfort weight'):
        tune.study(['skyhook'], plant, comfort_weight=2.0, n_passive=11, maxiter=1)


def test_cli_bad_input_exits_2(tmp_path, capsys):
    for extra in (['--law', 'astrology'], ['--roads', ','], ['--ws-limit', '1e-5']):
        code = cli.main(['tune', '--roads', 'bump', '--maxiter', '1', '--passive-points',
                         '11', '--no-plots', '--out', str(tmp_path / 't'), *extra])
        assert code == 2, extra
        assert 'error:' in capsys.readouterr().err


def test_workers_equal_serial():
    kwargs = {'comfort_weight': 0.5, 'ws_ratio': 0.95, 'n_passive': 11, 'maxiter': 1}
    plant = tune.Plant(roads=ROADS)
    serial = tune.study(['skyhook_onoff'], plant, workers=0, **kwargs)
    par = tune.study(['skyhook_onoff'], plant, workers=2, **kwargs)
    a, b = serial['tuned'][0], par['tuned'][0]
    assert a['tuned']['gains'] == b['tuned']['gains']
    assert a['history'] == b['history']
    # The constant-current sweep runs on the vectorised affine kernel (sim.batch.run), whose
    # last bits differ between processes (about 1e-15 relative); the feedback laws are exact.
    for key in tune.KEYS:
        np.testing.assert_allclose(serial['passive'][key], par['passive'][key], rtol=1e-12)


def test_cli_tune_parser():
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers(dest='command')
    tune_cli.register(sub)
    args = parser.parse_args(['tune', '--law', 'all', '--workers', '2'])
    assert tune_cli._laws(args.law) == list(tune.LAWS) and args.workers == 2
