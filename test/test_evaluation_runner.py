"""Evaluation runner, scenarios, tables and the ``evaluate`` command."""

import argparse
import json
import math

import numpy as np
import pytest

from mr_suspension.core.quarter_car import QuarterCarParams
from mr_suspension.evaluation import cli, runner, scenarios as scn, tables
from mr_suspension.sim import config as cfg


def test_scenario_groups_and_names():
    assert scn.expand('quick') == ['step', 'bump', 'iso_C_20']
    assert len(scn.expand('iso')) == 12
    assert scn.expand(['step,bump', 'step']) == ['step', 'bump']
    assert scn.make('iso_B_30').road.duration == pytest.approx(scn.ISO_DURATION)
    assert scn.make('harmonic_2.5').kind == 'harmonic'
    for bad in ('iso_Z_20', 'iso_C_fast', 'teleport'):
        with pytest.raises(ValueError):
            scn.make(bad)
    with pytest.raises(ValueError):
        scn.expand(' , ')


def test_linear_passive_run_matches_closed_form_response():
    # A linear damper at 1 Hz: the simulated stroke amplitude equals |H(j w)| of the
    # closed-form quarter car (seed 001 eqs. 2-3 with tyre damping).
    from mr_suspension.core.damper import LinearDamperParams
    from mr_suspension.core.metrics import sine_gain
    from mr_suspension.sim.simulator import simulate
    car = cfg.load_vehicle('seed003_passenger')
    conf = runner.build_config('passive_0A', car, LinearDamperParams(c=1500.0), 'ideal')
    res = simulate(conf, scn.make('harmonic_1.5').road)
    expected = abs(QuarterCarParams.transfer(car, 1.5, 1500.0)['stroke']) * 0.01
    assert sine_gain(res.t, res.stroke, 1.5, 4) == pytest.approx(expected, rel=2e-3)


def _table_cells(text):
    """Cells of each line of a Markdown table (outer pipes dropped, blanks stripped)."""
    return [[c.strip() for c in line.strip().strip('|').split('|')]
            for line in text.splitlines()]


def test_run_rows_and_relative_table():
    rows = runner.run(['passive_0A', 'skyhook'], ['bump'], driver='ideal')
    assert [r['law'] for r in rows] == ['passive_0A', 'skyhook']
    for r in rows:
        for key in runner.METRICS:
            assert math.isfinite(r[key]) and r[key] >= 0.0
    rel = tables.relative(rows, 'passive_0A')
    assert all(v == 0.0 for k, v in rel[0].items() if k not in ('law', 'scenario'))
    # The tables hold the metrics they render: each cell read back is the row's value in the
    # unit its header names (3 significant digits), or its change against passive_0A in %.
    keys = [key for key, _, _ in tables.COLUMNS]
    head, sep, *body = _table_cells(tables.markdown(rows))
    assert head == ['law', 'scenario'] + [name for _, name, _ in tables.COLUMNS]
    assert len(body) == len(rows) and set(''.join(sep)) == {'-'}
    for cells, row in zip(body, rows):
        assert cells[:2] == [row['law'], 'bump']
        for cell, (key, name, _) in zip(cells[2:], tables.COLUMNS):
            unit = 1e3 if name.endswith('[mm]') else 1.0  # metrics are SI: m -> mm
            assert float(cell) == pytest.approx(row[key] * unit, rel=5.1e-3, abs=1e-12), key
    _, _, *body = _table_cells(tables.markdown(rel, percent=True))
    passive, sky = rows
    assert body[0][2:] == ['+0.0'] * len(keys)
    assert body[1][:2] == ['skyhook', 'bump']
    for cell, key in zip(body[1][2:], keys):
        want = 100.0 * (sky[key] / passive[key] - 1.0)
        assert float(cell) == pytest.approx(want, abs=0.051), key
        assert cell[0] == ('+' if want >= 0.0 else '-')
    mean = tables.summary_by_law(rows)
    assert {m['law'] for m in mean} == {'passive_0A', 'skyhook'}


def test_overrides_and_actuator_scale():
    conf = runner.build_config('skyhook', overrides={'skyhook': {'c_sky': 1234.0},
                                                     '*': {'estimation': 'ideal'}},
                               actuator_scale=2.0)
    assert conf.controller.c_sky == 1234.0 and conf.controller.estimation == 'ideal'
    wb = cfg.load_driver('wonder_box')
    assert conf.driver.fluid_tau_fall == pytest.approx(2.0 * wb.fluid_tau_fall)
    assert runner.scaled_driver(wb, 0.0).dead_time == 0.0
    with pytest.raises(ValueError):
        runner.scaled_driver(wb, -1.0)
    with pytest.raises(ValueError):
        runner.build_config('nonexistent_law')
    with pytest.raises(ValueError):
        runner.build_config('skyhook', overrides={'skyhook': {'c_sky': -5.0}})


def test_passive_sweep_and_tune():
    met = runner.passive_sweep([0.0, 1.0], 'bump')
    # Harder damping: less working space (seed 001 Fig. 9 direction).
    assert met['working_space_rms'][1] < met['working_space_rms'][0]
    best, values, obj, _ = runner.tune('skyhook_onoff', 'i_max', [0.1, 0.5], 'bump')
    assert best in values and obj.shape == (2,)
    with pytest.raises(ValueError):
        runner.tune('skyhook', 'c_sky', [], 'bump')
    with pytest.raises(ValueError):
        runner.passive_sweep([1.0], 'bump', kind='magic')


def test_cli_help_and_run(tmp_path, capsys):
    parser = argparse.ArgumentParser(prog='mr-suspension')
    sub = parser.add_subparsers(dest='command')
    cli.register(sub)
    with pytest.raises(SystemExit):
        parser.parse_args(['evaluate', '--help'])
    assert 'scenarios' in capsys.readouterr().out
    out = tmp_path / 'ev'
    assert cli.main(['--laws', 'passive_0A,pdd', '--scenarios', 'bump', '--study',
                     'tradeoff', '--set', 'pdd.i_max=1.5', '--out', str(out)]) == 0
    rows = json.loads((out / 'metrics.json').read_text())
    assert {r['law'] for r in rows} == {'passive_0A', 'pdd'}
    assert (out / 'report.md').is_file() and (out / 'time_bump.png').is_file()
    assert (out / 'metrics.csv').read_text().startswith('law,scenario')
    for bad in (['--set', 'nodot=1'], ['--study', 'astrology'], ['--scenarios', 'mars']):
        with pytest.raises(SystemExit):
            cli.main(['--laws', 'passive_0A', '--scenarios', 'bump', '--no-plots', '--out',
                      str(out)] + bad)


def test_tables_reject_empty(tmp_path):
    with pytest.raises(ValueError):
        tables.write_csv([], tmp_path / 'x.csv')
    assert np.isnan(tables.relative([{'law': 'a', 'scenario': 's', 'vdv': 1.0}], 'b')[0]['vdv'])


def test_cli_tune(tmp_path, capsys):
    out = tmp_path / 'tune'
    assert cli.main(['--laws', 'skyhook_onoff', '--scenarios', 'bump', '--study', 'none',
                     '--no-plots', '--tune', 'skyhook_onoff.i_max=0.1,0.4', '--objective',
                     'working_space_rms', '--out', str(out)]) == 0
    text = capsys.readouterr().out
    # More on-state current, less working space: the grid search must pick 0.4 A.
    assert 'best 0.4' in text
    assert 'Tuning skyhook_onoff.i_max' in (out / 'report.md').read_text()
    with pytest.raises(SystemExit):
        cli.main(['--laws', 'skyhook', '--scenarios', 'bump', '--no-plots', '--study', 'none',
                  '--tune', 'skyhook.c_sky=', '--out', str(out)])


def test_cli_all_studies_light(tmp_path):
    """Every study of the command runs end to end (light settings) and lands in the report."""
    out = tmp_path / 'all'
    assert cli.main(['--laws', 'passive_0A,add', '--scenarios', 'bump', '--study', 'all',
                     '--light', '--out', str(out)]) == 0
    report = (out / 'report.md').read_text()
    for heading in ('## Seed 001', '## Seed 003', '## Best passive settings',
                    'offline semi-active reference', '## Degradation with actuator speed',
                    '## Degradation with sensor', '## Estimator delays', '## Sensor noise',
                    'Comfort at equal working space'):
        assert heading in report, heading
    for name in ('control_seed001_linear', 'control_seed003_step', 'frequency_response',
                 'degradation_actuator', 'tradeoff_bump', 'tradeoff_families_bump'):
        assert (out / f'{name}.png').stat().st_size > 10000, name


def test_fitted_model_json_as_damper(tmp_path):
    """A damper fitted by diagnose (extended law) drives the plant and the inverse model."""
    from mr_suspension.core.extended import ExtendedDamperParams
    from mr_suspension.identification.model_io import model_dict, save_model
    from mr_suspension.sim.simulator import simulate
    fitted = ExtendedDamperParams(c0=400.0, c1=900.0, fy0=30.0, fy1=450.0, i_sat=0.8,
                                  k_series=5e5)
    path = tmp_path / 'model.json'
    save_model(path, model_dict(fitted, {'dead_time': 0.003, 'tau_rise': 0.007,
                                         'tau_fall': 0.004}, ['saturation'], 'current'))
    conf = runner.build_config('skyhook', damper=str(path), driver='ideal')
    assert conf.damper == fitted
    assert conf.controller.damper_model['law'] == 'extended'
    res = simulate(conf, scn.make('bump').road)
    assert np.all(np.isfinite(res.f_d)) and np.ptp(res.i_cmd) > 0.05
    with pytest.raises(ValueError):
        runner.load_damper(str(tmp_path / 'missing.json'))
    other = tmp_path / 'other.json'
    other.write_text('{"c0": 400.0}')
    with pytest.raises(ValueError, match='not a fitted model'):
        runner.load_damper(str(other))
