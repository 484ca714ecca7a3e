"""Full car: tuning against the passive damper, carpet plot and the single-side bump demo."""

import json
import math

import numpy as np
import pytest

from mr_suspension import cli
from mr_suspension.evaluation import full_car as fce

# One worker compiles the full-car kernels (about a minute from a cold cache), not two.
pytestmark = pytest.mark.xdist_group('full_car')


def short_plant(roads=('iso_C_15',)):
    return fce.FullCarPlant(roads=roads, duration=3.0)


def test_tuned_law_is_never_worse_than_its_defaults_and_meets_the_limit():
    plant = short_plant()
    res = fce.study(('modal_skyhook',), plant, ws_ratio=0.95, n_passive=5, maxiter=2)
    tuned = res.tuned[0]
    default = fce.evaluate([fce.law_config(plant, 'modal_skyhook')], plant)
    assert res.objective.penalised({k: np.asarray(v)[None, :] for k, v in
                                    tuned.figures.items()})[0] \
        <= res.objective.penalised(default)[0] + 1e-12
    assert tuned.violation <= 0.0
    lo, hi = zip(*fce.space('modal_skyhook', plant).bounds)
    for name, low, high in zip(fce.MODAL_GAINS, lo, hi):
        assert low <= tuned.gains[name] <= high


def test_modal_critical_damping_is_that_of_each_rigid_tyre_mode():
    car = short_plant().car
    crit = fce.modal_critical(car)
    f = car.natural_frequencies()
    # c_crit = 2 m w: with the real tyres the modes are a little softer than with rigid ones.
    for c, m, name in zip(crit, (car.m_b, car.i_yy, car.i_xx), ('heave', 'pitch', 'roll')):
        w_rigid = c / (2.0 * m)
        assert 2 * math.pi * f[name] < w_rigid < 1.15 * 2 * math.pi * f[name], name


def test_equal_space_picks_the_best_passive_current_within_the_space():
    passive = {'current': np.array([0.0, 0.5, 1.0]),
               'body_acc_wk_rms': np.array([[1.0], [1.5], [2.0]]),
               'tyre_load_rms': np.array([[100.0], [110.0], [150.0]]),
               'working_space_rms': np.array([[0.010], [0.008], [0.007]])}
    soft = {k: v[0] for k, v in passive.items() if k != 'current'}
    obj = fce.tune.Objective(soft, ws_ratio=1.0)
    point = {'body_acc_wk_rms': [1.2], 'tyre_load_rms': [100.0], 'working_space_rms': [0.0085]}
    eq = fce.equal_space(point, passive, obj)
    assert eq['current'] == 0.5  # 0.5 A and 1 A fit in 8.5 mm; 0.5 A is the more comfortable
    assert eq['comfort_change_pct'] == pytest.approx(100.0 * (1.2 / 1.5 - 1.0))
    point['working_space_rms'] = [0.006]
    assert fce.equal_space(point, passive, obj)['current'] is None


def test_cli_writes_report_carpet_and_bump(tmp_path):
    out = tmp_path / 'fc'
    rc = cli.main(['full-car', '--roads', 'iso_C_15', '--laws', 'modal_skyhook',
                   '--maxiter', '1', '--passive-points', '5', '--ws-ratio', '1.0',
                   '--out', str(out)])
    assert rc == 0
    report = json.loads((out / 'report.json').read_text())
    assert report['tuned'][0]['law'] == 'modal_skyhook'
    assert (out / 'carpet.png').stat().st_size > 10000
    text = (out / 'report.md').read_text()
    if report['tuned'][0]['equal_space'].get('current') is not None:
        assert (out / 'bump.png').is_file() and 'Single-side bump' in text


def test_bad_inputs_are_clear():
    plant = short_plant()
    with pytest.raises(ValueError, match='unknown scenario'):
        plant.road('cobbles')
    with pytest.raises(ValueError, match='unknown law'):
        fce.space('telepathy', plant)
    assert cli.main(['full-car', '--maxiter', '0']) != 0
    with pytest.raises(ValueError, match='not iso'):
        plant.road('iso_C')
