"""CLI: diagnose writes report/model/figures, predict reproduces the fit, doe, help, errors."""

import argparse
import dataclasses
import json

import numpy as np
import pytest
import truthcases

from mr_suspension import cli as main_cli
from mr_suspension.identification import cli, model_io
from mr_suspension.identification.data import load_records, LoadOptions, parse_mapping
from mr_suspension.nodes.common import corner_config
from mr_suspension.sim import config


def _write_csv(path, rec, mm_kn=False):
    x = rec.displacement * (1e3 if mm_kn else 1.0)
    f = rec.force * (1e-3 if mm_kn else 1.0)
    v = rec.velocity * (1e3 if mm_kn else 1.0)
    np.savetxt(path, np.column_stack([rec.time, x, v, f, rec.i_in]), delimiter=',',
               header='t,stroke,rate,load,current_command', comments='', fmt='%.10g')


def test_diagnose_predict_round_trip(tmp_path, capsys):
    """A truth-rig damper with a gas spring (13x the noise), written in mm, mm/s and kN.

    ``diagnose`` reads it through the column and unit options, names the gas spring with a
    positive stiffness, and ``predict`` reproduces the fitted model's force from the same
    file to within the noise; a record driven twice as far and fast is flagged.
    """
    case = truthcases.case(27002, ('gas_spring',), shape='bingham_tanh', strength=0.8,
                           sensor_faults=(), duration=12.0, measured_current=False,
                           driver_tau=0.0)
    assert case.contributions['gas_spring'] > 10.0
    rec = truthcases.record(case.columns)
    csv = tmp_path / 'rig.csv'
    _write_csv(csv, rec, mm_kn=True)
    out = tmp_path / 'out'
    fmt = ['--columns', 'time=t,displacement=stroke,velocity=rate,force=load', '--units',
           'displacement=mm,velocity=mm/s,force=kN']
    assert cli.main(['diagnose', str(csv), '--out', str(out), '--quiet'] + fmt) == 0
    rep = json.loads((out / 'report.json').read_text())
    for key in ('baseline', 'verdict', 'causes', 'ambiguous', 'untestable', 'extended', 'gain'):
        assert key in rep
    assert set(rep['baseline']) >= {'model', 'parameters', 'heldout_nrmse'}
    assert rep['verdict'] == 'named' and rep['causes'][0]['effect'] == 'gas_spring'
    assert set(rep['causes'][0]) >= {'effect', 'parameters', 'heldout_nrmse', 'gain', 'evidence'}
    assert rep['gain'] == pytest.approx(
        1 - rep['extended']['heldout_nrmse'] / rep['baseline']['heldout_nrmse'])
    for png in ('force_time.png', 'loops.png', 'residuals.png', 'current_edges.png'):
        assert (out / png).stat().st_size > 1000
    assert 'gas_spring' in (out / 'report.md').read_text()
    model = model_io.load_model(out / 'model.json')
    assert model['damper']['law'] == 'extended' and model['damper']['k_gas1'] > 0
    params, dyn = model_io.load_fitted_model(out / 'model.json')
    assert set(dyn) == {'dead_time', 'tau_rise', 'tau_fall'}
    pred = tmp_path / 'pred.csv'
    assert cli.main(['predict', '--model', str(out / 'model.json'), str(csv), '--out',
                     str(pred)] + fmt) == 0
    got = np.loadtxt(pred, delimiter=',', skiprows=1)
    opts = LoadOptions(columns=parse_mapping(fmt[1], 'c'), units=parse_mapping(fmt[3], 'u'))
    (loaded,) = load_records([csv], opts)
    np.testing.assert_allclose(got[:, 1], model_io.predict(model, loaded), rtol=1e-7,
                               atol=1e-6)
    resid = got[:, 1] - rec.force
    assert np.std(resid) < 1.2 * case.noise_rms
    # The model knows the range it was fitted on: the same record is inside it, the same
    # damper driven twice as far and fast is not, and predict says so.
    assert model['fitted_range']['abs_velocity_p999'] == pytest.approx(
        np.percentile(np.abs(rec.velocity), 99.9), rel=1e-3)
    assert 'outside the domain' not in capsys.readouterr().err
    fast = tmp_path / 'fast.csv'
    np.savetxt(fast, np.column_stack([rec.time, 2 * rec.displacement, 2 * rec.velocity,
                                      rec.i_in]), delimiter=',',
               header='time,displacement,velocity,current_command', comments='')
    assert cli.main(['predict', '--model', str(out / 'model.json'), str(fast), '--out',
                     str(tmp_path / 'fast_pred.csv')]) == 0
    err = capsys.readouterr().err
    assert 'outside the domain the model was fitted on' in err and 'stroke rate' in err
    assert 'displacement: ' in err and 'input: ' not in err
    # A record without a force column can still be predicted.
    nof = tmp_path / 'noforce.csv'
    np.savetxt(nof, np.column_stack([rec.time, rec.displacement, rec.i_in]), delimiter=',',
               header='time,displacement,current_command', comments='')
    assert cli.main(['predict', '--model', str(out / 'model.json'), str(nof), '--out',
                     str(tmp_path / 'p2.csv')]) == 0
    p2 = np.loadtxt(tmp_path / 'p2.csv', delimiter=',', skiprows=1)
    assert p2.shape == (rec.n, 2)


def test_doe_help_and_errors(tmp_path, capsys):
    prog = tmp_path / 'prog.csv'
    assert cli.main(['doe', '--out', str(prog), '--duration', '30']) == 0
    arr = np.loadtxt(prog, delimiter=',', skiprows=1)
    assert arr.shape == (30000, 4)
    assert np.ptp(arr[:, 3]) > 0.9 and np.max(np.abs(arr[:, 1])) < 0.05
    ap = argparse.ArgumentParser(prog='mr-suspension')
    cli.register(ap.add_subparsers(dest='command'))
    for sub in ('diagnose', 'predict', 'doe'):
        with pytest.raises(SystemExit) as exc:
            ap.parse_args([sub, '--help'])
        assert exc.value.code == 0
    assert 'held-out' in capsys.readouterr().out
    bad = tmp_path / 'bad.csv'
    bad.write_text('time,displacement,force\n0,0,1\n')
    assert cli.main(['diagnose', str(bad), '--out', str(tmp_path / 'o')]) == 2
    assert 'current_command' in capsys.readouterr().err
    assert cli.main(['predict', '--model', str(bad), str(bad), '--out', 'x.csv']) == 2


def test_force_in_kn_read_as_n_is_flagged(tmp_path, capsys):
    """An effect-free truth-rig damper whose force is written in kN: flagged, no cause."""
    rec = truthcases.record(truthcases.case(27010, (), shape='bingham_tanh', sensor_faults=(),
                                            duration=6.0, measured_current=False,
                                            driver_tau=0.0).columns)
    csv = tmp_path / 'kn.csv'
    np.savetxt(csv, np.column_stack([rec.time, rec.displacement, rec.velocity,
                                     rec.force * 1e-3, rec.i_in]), delimiter=',',
               header='time,displacement,velocity,force,current_command', comments='')
    out = tmp_path / 'o'
    assert cli.main(['diagnose', str(csv), '--out', str(out), '--no-plots']) == 0
    assert 'kN' in capsys.readouterr().err
    rep = json.loads((out / 'report.json').read_text())
    assert any('kN' in w for w in rep['input_warnings'])
    assert rep['verdict'] == 'none'


def test_fitted_model_plugs_into_simulator_and_nodes(tmp_path):
    # A diagnose model.json is a damper and a driver parameter set for simulate and the nodes
    # (plumbing: a truth-rig record with a current lag, nothing judged on the fit).
    rec = truthcases.record(truthcases.case(27020, ('current_lag',), shape='bingham_tanh',
                                            sensor_faults=(), duration=12.0,
                                            measured_current=False).columns)
    csv = tmp_path / 'rig.csv'
    np.savetxt(csv, np.column_stack([rec.time, rec.displacement, rec.force, rec.i_in]),
               delimiter=',', header='time,displacement,force,current_command', comments='',
               fmt='%.10g')
    out = tmp_path / 'diag'
    assert cli.main(['diagnose', str(csv), '--out', str(out), '--quiet']) == 0
    model_path = out / 'model.json'
    params, dyn = model_io.load_fitted_model(model_path)
    damper = config.load_damper(model_path)
    assert damper == params
    driver = config.load_driver(model_path)
    assert driver == model_io.fitted_driver(model_path)
    assert driver.dead_time == pytest.approx(min(dyn['dead_time'], 0.25))
    corner = corner_config(damper=str(model_path), driver=str(model_path))
    assert corner.damper == params
    sim_out = tmp_path / 'sim'
    assert main_cli.main(['simulate', '--damper', str(model_path), '--driver', str(model_path),
                          '--duration', '2', '--out', str(sim_out)]) == 0
    metrics = json.loads((sim_out / 'metrics.json').read_text())
    assert metrics['skyhook_onoff']['body_acc_rms'] > 0.0


def test_fitted_range_flags_only_what_leaves_it():
    rec = truthcases.record(truthcases.case(27030, ('current_lag',), sensor_faults=(),
                                            duration=6.0, measured_current=False).columns)
    rng = model_io.fitted_range([rec])
    shares, msg = model_io.outside_range(rng, rec)
    assert msg is None and shares['velocity'] < 0.001 and shares['input'] == 0.0
    from dataclasses import replace
    hot = replace(rec, i_in=1.5 * rec.i_in)
    shares, msg = model_io.outside_range(rng, hot)
    assert shares['input'] > model_io.RANGE_SHARE and 'input above' in msg
    assert shares['velocity'] < 0.001 and 'faster' not in msg
    # The stroke counts only where it enters the force (a gas spring in the model).
    far = replace(rec, displacement=3.0 * rec.displacement)
    shares, msg = model_io.outside_range(rng, far)
    assert shares['displacement'] > model_io.RANGE_SHARE and 'stroke beyond' in msg
    assert model_io.outside_range(rng, far, stroke=False)[1] is None
    # A malformed block in model.json is refused with its key named.
    model = {'damper': {'law': 'extended'}, 'current_dynamics': {
        'dead_time': 0.0, 'tau_rise': 0.0, 'tau_fall': 0.0}}
    model['damper'].update(model_io.ExtendedDamperParams().to_dict())
    model['fitted_range'] = {**rng, 'abs_velocity_p999': float('nan')}
    with pytest.raises(ValueError, match='fitted_range'):
        model_io.check_model(model)
    model['fitted_range'] = rng
    assert model_io.check_model(model) is model


def test_a_hedge_in_model_json_is_averaged_into_predict_and_checked():
    rec = truthcases.record(truthcases.case(27040, ('current_lag',), sensor_faults=(),
                                            duration=3.0, measured_current=False).columns)
    dyn = {'dead_time': 0.0, 'tau_rise': 0.0, 'tau_fall': 0.0}
    tanh = model_io.ExtendedDamperParams(c0=900.0, c1=2000.0, fy0=80.0, fy1=600.0, v_y=0.02)
    shaped = dataclasses.replace(tanh, c0=500.0, yield_n=1.5, v_y=0.03)
    model = model_io.model_dict(tanh, dyn, ('current_lag',), 'current_command')
    alone = model_io.predict(model, rec)
    other = model_io.predict(model_io.model_dict(shaped, dyn, (), 'current_command'), rec)
    assert np.max(np.abs(alone - other)) > 1.0
    for w in (0.0, 0.5, 1.0):
        model['hedge'] = model_io.hedge_dict(shaped, dyn, ('yield_shape',), weight=w)
        np.testing.assert_allclose(model_io.predict(model, rec),
                                   (1 - w) * alone + w * other, rtol=1e-12, atol=1e-9)
    model['hedge']['weight'] = 1.5
    with pytest.raises(ValueError, match='hedge must be a model block with a weight'):
        model_io.check_model(model)
    model['hedge'] = {'weight': 0.5, 'damper': {'law': 'extended', 'v_y': -1.0}}
    with pytest.raises(ValueError, match='hedge'):
        model_io.check_model(model)
