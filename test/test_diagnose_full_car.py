"""``diagnose-vehicle --car``: the four corners of a full car with the body's coupling.

Truth: ``truth/full_car.py`` (a body on four corners, own integrator and effect shapes).
"""

import json

import numpy as np
import pytest
from truthcases import write_full_car_bag

from mr_suspension.identification import full_car, vehicle, vehicle_data
from mr_suspension.identification.cli import main
from mr_suspension.identification.data import DataError
from mr_suspension.truth.full_car import make_full_car_case

NOMINAL = full_car.CarNominal.load()


def _records(case):
    return {c: [vehicle_data.build(c, cols)] for c, cols in case.columns.items()}


def test_coupling_matrix_is_the_rigid_body_closed_form():
    car = NOMINAL.car
    a = full_car.coupling_matrix(car)
    pos = car.positions()
    for i in range(4):
        for k in range(4):
            closed = (1.0 / car.m_b + pos[i, 0] * pos[k, 0] / car.i_yy
                      + pos[i, 1] * pos[k, 1] / car.i_xx)
            assert a[i, k] == pytest.approx(closed, rel=1e-12)
    # four body points of a rigid body: one force pattern moves none of them (rank 3)
    assert np.linalg.matrix_rank(a) == 3
    s = np.array([300.0, -120.0, 50.0, 80.0])
    heave = s.sum() / car.m_b
    pitch = -(pos[:, 0] @ s) / car.i_yy
    roll = (pos[:, 1] @ s) / car.i_xx
    np.testing.assert_allclose(a @ s, heave - pos[:, 0] * pitch + pos[:, 1] * roll, rtol=1e-12)


def test_anti_roll_bar_forces_cancel_in_heave_and_pitch():
    x = np.random.default_rng(3).normal(0.0, 0.01, (4, 50))
    f = full_car.arb_forces(NOMINAL.car, x)
    np.testing.assert_allclose(f.sum(axis=0), 0.0, atol=1e-12)
    np.testing.assert_allclose(f[0], -NOMINAL.car.k_arb_f * (x[0] - x[1]))


@pytest.mark.parametrize('effect,corner', [('spring_nonlinearity', 'rear_left'),
                                           ('current_lag', 'front_right')])
def test_hidden_effect_named_at_its_corner_only(effect, corner):
    case = make_full_car_case(71, effects=(effect,), corner=corner, duration=20.0,
                              strength=0.6)
    assert case.contributions[effect] > 3.0
    diag, _ = full_car.run(_records(case), NOMINAL)
    assert diag.corners[corner].causes[:1] == [effect], diag.passes
    assert {c for c, _ in diag.causes} == {corner}, diag.passes  # no other corner named
    assert diag.notes['converged']


def test_effect_free_car_names_nothing_and_fits_every_corner():
    case = make_full_car_case(72, duration=20.0)
    diag, _ = full_car.run(_records(case), NOMINAL)
    assert diag.causes == []
    for c, res in diag.corners.items():
        i = full_car.CORNERS.index(c)
        k_s = NOMINAL.car.corner(i).k_s
        assert res.corner['k_s'] == pytest.approx(k_s, rel=0.15), c
        assert res.corner['m_s'] == pytest.approx(
            NOMINAL.car.static_share('front' if i < 2 else 'rear'))


def test_without_the_coupling_a_quarter_car_fit_is_worse():
    """The same corner fitted as a quarter car of its static share predicts worse."""
    case = make_full_car_case(73, duration=20.0)
    recs = _records(case)
    diag, _ = full_car.run(recs, NOMINAL)
    for i, c in enumerate(full_car.CORNERS):
        alone, _, _ = vehicle.run(recs[c], vehicle.Nominal(NOMINAL.car.corner(i),
                                                           NOMINAL.damper, NOMINAL.driver),
                                  effects=())
        assert diag.corners[c].heldout['baseline_nrmse'] < \
            0.7 * alone.heldout['baseline_nrmse'], c


def test_records_on_other_clocks_or_a_missing_corner_are_refused():
    case = make_full_car_case(74, duration=8.0)
    recs = _records(case)
    with pytest.raises(DataError, match='rear_right'):
        full_car.run({c: r for c, r in recs.items() if c != 'rear_right'}, NOMINAL)
    cols = dict(case.columns['front_right'])
    cols['time'] = cols['time'] + 0.37
    recs['front_right'] = [vehicle_data.build('shifted', cols)]
    with pytest.raises(DataError, match='one clock'):
        full_car.run(recs, NOMINAL)


def test_cli_on_a_full_car_bag(tmp_path, capsys):
    case = make_full_car_case(75, effects=('direction_asymmetry',), corner='front_left',
                              duration=12.0, strength=0.8)
    bag = tmp_path / 'car'
    write_full_car_bag(case, bag)
    assert main(['diagnose-vehicle', str(bag), '--out', str(tmp_path / 'x'), '--quiet']) != 0
    assert '--car' in capsys.readouterr().err
    assert main(['diagnose-vehicle', str(bag), '--car', 'lisa_full_car', '--namespace',
                 'front_left', '--out', str(tmp_path / 'y'), '--quiet']) != 0
    out = tmp_path / 'diag'
    assert main(['diagnose-vehicle', str(bag), '--car', 'lisa_full_car', '--out', str(out),
                 '--no-plots']) == 0
    text = capsys.readouterr().out
    assert 'front_left' in text and 'rear_right' in text
    rep = json.loads((out / 'report.json').read_text())
    assert set(rep['corners']) == set(full_car.CORNERS)
    assert rep['causes'] == [{'corner': 'front_left', 'effect': 'direction_asymmetry'}]
    for c in full_car.CORNERS:
        assert (out / c / 'report.md').exists() and (out / c / 'vehicle.yaml').exists()
    md = (out / 'report.md').read_text()
    assert 'direction_asymmetry' in md and 'Effective masses' in md
