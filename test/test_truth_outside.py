"""Effects of the independent truth that the diagnosis catalogue lacks (``rig.OUTSIDE``).

Fluid inertia ``m_f a`` and Stribeck seal friction ``(F_c + (F_s - F_c) exp(-(v/v_s)^2))
sign(v)``: closed forms on a sine, their drawn strength against the noise, their absence from
the benchmark's ``EFFECTS`` and from the catalogue, and deterministic cases per seed (seeds
``truthcases.BASE + n``, never the benchmark's).
"""

import numpy as np
import pytest
import truthcases

from mr_suspension.identification import engine
from mr_suspension.truth import cases, rig

DURATION = 4.0


def test_outside_effects_are_neither_drawn_by_the_benchmark_nor_in_the_catalogue():
    assert rig.OUTSIDE == ('fluid_inertia', 'seal_friction')
    for e in rig.OUTSIDE:
        assert e not in rig.EFFECTS
        assert e not in engine.ALL_EFFECTS
    # A truth drawn from the catalogue's effects has them off.
    truth = rig.draw_truth(np.random.default_rng(11), rig.EFFECTS[-3:], strength=0.9)
    assert truth.fluid_mass == 0 and truth.seal_fs == 0 and truth.seal_fc == 0
    assert not set(truth.effects) & set(rig.OUTSIDE)
    with pytest.raises(ValueError, match='unknown effect'):
        rig.draw_truth(np.random.default_rng(1), ('end_stop',))


def test_fluid_inertia_closed_form_on_a_sine():
    """A viscous damper with fluid inertia: ``F = c v + m a``, ``a = -w^2 x`` on a sine."""
    t, x = truthcases.sine(freq=3.0)
    w = 2 * np.pi * 3.0
    truth = truthcases.linear_truth(fluid_mass=12.0)
    assert truth.effects == ('fluid_inertia',)
    out = rig.simulate(truth, t, x, np.zeros(t.size))
    inner = slice(50, -50)  # away from the spline's not-a-knot ends
    v = 0.01 * w * np.cos(w * t)
    expect = 1500.0 * v - 12.0 * w ** 2 * x
    assert np.allclose(out['force'][inner], expect[inner], atol=0.01 * 12.0 * w ** 2 * 0.01)
    assert np.allclose(out['inertia_force'], 12.0 * out['acceleration'])
    off = rig.simulate(truth.without('fluid_inertia'), t, x, np.zeros(t.size))
    assert np.allclose(out['force'] - off['force'], out['inertia_force'], rtol=0, atol=1e-9)


def test_seal_friction_closed_form_and_stribeck_dip():
    t, x = truthcases.sine(freq=3.0)
    truth = truthcases.linear_truth(seal_fc=40.0, seal_fs=100.0, seal_vs=0.004)
    assert truth.effects == ('seal_friction',)
    out = rig.simulate(truth, t, x, np.zeros(t.size))
    v = out['velocity']
    expect = (40.0 + 60.0 * np.exp(-(v / 0.004) ** 2)) * np.sign(v)
    assert np.allclose(out['force'] - 1500.0 * v, expect, rtol=1e-12, atol=1e-9)
    # Not monotone near rest: the breakaway level exceeds the Coulomb level, then drops.
    f = rig.seal_force(truth, np.array([1e-5, 0.004, 0.05]))
    assert f[0] == pytest.approx(100.0, rel=1e-4) and f[0] > f[1] > f[2]
    assert f[2] == pytest.approx(40.0, rel=1e-9)
    assert rig.seal_force(truth, np.array([-0.05]))[0] == pytest.approx(-40.0)
    with pytest.raises(ValueError, match='seal_fs'):
        truthcases.linear_truth(seal_fc=50.0, seal_fs=20.0)


@pytest.mark.parametrize('effect, n', [('fluid_inertia', 91000), ('seal_friction', 91010)])
def test_each_outside_effect_changes_the_force_by_its_drawn_strength(effect, n):
    weak = truthcases.case(n, (effect,), strength={effect: 0.0}, duration=DURATION)
    strong = truthcases.case(n, (effect,), strength={effect: 1.0}, duration=DURATION)
    for case in (weak, strong):
        assert case.effects == (effect,)
        assert dict(case.truth.strengths)[effect] in (0.0, 1.0)
        # The contribution is the RMS force change when the effect is switched off, over noise.
        clean = case.clean
        t, x, i = clean['time'], clean['displacement'], clean['current_command']
        off = rig.simulate(case.truth.without(effect), t, x, i)['force']
        rms = float(np.sqrt(np.mean((clean['force'] - off) ** 2)))
        assert case.contributions_n[effect] == pytest.approx(rms, rel=1e-12)
        assert case.contributions[effect] == pytest.approx(rms / case.noise_rms, rel=1e-12)
        part = clean['inertia_force'] if effect == 'fluid_inertia' else clean['seal_force']
        assert rms == pytest.approx(float(np.sqrt(np.mean(part ** 2))), rel=1e-9)
    # Same damper, same programme: the strong draw moves the force several times more, and
    # well above the noise.
    assert strong.contributions[effect] > 4 * weak.contributions[effect]
    assert strong.contributions[effect] >= 3.0
    if effect == 'fluid_inertia':
        assert strong.truth.fluid_mass > 10 * weak.truth.fluid_mass
    else:
        assert strong.truth.seal_fc > 7 * weak.truth.seal_fc
        assert strong.truth.seal_fs / strong.truth.seal_fc > 1.3 - 1e-9
        assert 1e-3 <= strong.truth.seal_vs <= 1e-2


def test_make_case_with_an_outside_effect_is_deterministic_per_seed():
    effs = ('hysteresis', 'seal_friction')
    a = truthcases.case(91020, ('fluid_inertia',), duration=3.0)
    b = truthcases.case(91020, ('fluid_inertia',), duration=3.0)
    assert a.truth == b.truth and a.truth.fluid_mass > 0
    for name in a.columns:
        assert np.array_equal(a.columns[name], b.columns[name])
    assert a.contributions == b.contributions
    c = truthcases.case(91021, ('fluid_inertia',), duration=3.0)
    assert c.truth.fluid_mass != a.truth.fluid_mass
    d = truthcases.case(91022, effs, duration=3.0)
    e = cases.make_case(truthcases.BASE + 91022, effs, duration=3.0)
    assert d.truth == e.truth and d.effects == effs
    assert set(d.contributions) == set(effs)
    assert np.array_equal(d.columns['force'], e.columns['force'])
    # The unseen record is the same damper under another programme.
    u = a.unseen()
    assert u.truth == a.truth and 'fluid_inertia' in u.contributions
    # Switching the effect off gives back the truth without it.
    assert d.truth.without('seal_friction').effects == ('hysteresis',)
