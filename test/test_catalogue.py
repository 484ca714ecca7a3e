"""The effect catalogue: consistent data the selection and the reports can rely on."""

from dataclasses import fields

import pytest

from mr_suspension.core.driver import DriverParams
from mr_suspension.core.extended import ExtendedDamperParams
from mr_suspension.core.quarter_car import QuarterCarParams
from mr_suspension.identification import catalogue as cat

CATALOGUES = {'rig': cat.RIG, 'car': cat.CAR}
# Where a located effect's parameters are written (the fitted model files).
HOLDERS = {'damper': ExtendedDamperParams, 'vehicle': QuarterCarParams}


@pytest.mark.parametrize('problem', sorted(CATALOGUES))
def test_every_parameter_has_a_unit_and_a_plausible_range(problem):
    for effect in CATALOGUES[problem]:
        for name, unit, lo, hi, meaning in cat.parameters(effect):
            assert lo < hi and isinstance(unit, str) and meaning, (effect.name, name)


@pytest.mark.parametrize('problem', sorted(CATALOGUES))
def test_parameters_live_where_the_effect_does(problem):
    for effect in CATALOGUES[problem]:
        holder = HOLDERS.get(effect.location)
        if holder is None:
            continue
        own = {f.name for f in fields(holder)}
        missing = [p for p in effect.params + effect.linear if p not in own]
        assert not missing, (effect.name, missing)


def test_the_car_writes_the_current_chain_to_the_driver():
    own = {f.name for f in fields(DriverParams)}
    for effect in cat.CAR:
        if effect.location == 'current':
            assert set(effect.params) <= own, effect.name


@pytest.mark.parametrize('problem', sorted(CATALOGUES))
def test_relations_name_effects_of_the_same_catalogue(problem):
    catalogue = CATALOGUES[problem]
    known = set(cat.by_name(catalogue))
    assert len(known) == len(catalogue), 'an effect is listed twice'
    for effect in catalogue:
        assert {effect.nests, *effect.excludes} - {None} <= known, effect.name
    # A nested pair is one explanation in two sizes: never named together.
    for simple, general in cat.nested(catalogue):
        assert any({simple, general} <= group for group in cat.exclusive(catalogue))


def test_the_car_says_how_to_make_each_effect_testable():
    assert all(e.how for e in cat.CAR)


def test_separating_experiments_name_catalogue_effects_or_baseline_terms():
    baseline = {'c0', 'fy0', 'k_s'}
    for catalogue, table in ((cat.RIG, cat.RIG_SEPARATING), (cat.CAR, cat.CAR_SEPARATING)):
        known = set(cat.by_name(catalogue)) | baseline
        for pair, text in table.items():
            assert len(pair) == 2 and pair <= known and text, sorted(pair)


def test_the_current_chain_is_located_by_the_input():
    lag = cat.by_name(cat.RIG)['current_lag']
    assert cat.where(lag, coil=True) == 'damper' and cat.where(lag, coil=False) == 'driver'
    assert cat.where(cat.by_name(cat.RIG)['hysteresis'], coil=False) == 'damper'
    assert cat.names(cat.CAR, stage='road') == ('sprung_mass',)


def test_an_unknown_location_is_refused():
    with pytest.raises(ValueError, match='location'):
        cat.Effect('wheel_wobble', 'chassis', (), 'x')
