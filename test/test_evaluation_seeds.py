"""Seed reproductions: seed 001 work-diagram damping and families, seed 003 comparison."""

import math

import numpy as np
import pytest

from mr_suspension.core import damper as dmp
from mr_suspension.evaluation import seeds, studies


def test_work_diagram_ceq_of_linear_damper_is_c():
    # Seed 001 eq. 1 on a viscous damper returns its coefficient.
    assert seeds.work_diagram_ceq(dmp.LinearDamperParams(c=2500.0), 0.0, 1.2) == \
        pytest.approx(2500.0, rel=1e-3)


def test_rd8041_model_matches_quoted_figures():
    p = seeds.rd8041_model()
    f = dmp.force_series(dmp.LAW_EXTENDED, p.to_array(), np.zeros(1), np.array([0.05]),
                         np.array([1.0]), 1e-3)[0]
    assert 2.0 * f == pytest.approx(2447.0, rel=0.05)       # peak-to-peak at 5 cm/s, 1 A
    table = seeds.seed001_ceq_table()
    # Seed 001 Fig. 5: C_eq grows with current and falls with frequency, more so at high I.
    assert np.all(np.diff(table, axis=0) > 0.0)
    assert np.all(np.diff(table, axis=1) < 0.0)
    assert table[-1, 0] / table[-1, -1] > table[0, 0] / table[0, -1]


def test_seed001_claims_on_linear_and_simulated_families():
    res = seeds.seed001_reproduction(n_sim=8)
    lin = {text: ok for text, ok, _ in res['claims_linear']}
    sim = {text: ok for text, ok, _ in res['claims_simulated']}
    assert set(lin) == set(sim) and len(lin) == 10
    # The statements that follow from the physics hold in both.
    for text in lin:
        if 'working space' in text or 'between resonances' in text:
            assert lin[text] and sim[text], text
    # Harder damping of this overdamped car cannot lower the NTF at the body resonance.
    assert not lin['Fig 10: NTF at body resonance falls with current']


def _linear_quarter_car_stroke(car, c, road):
    """Stroke of the linear quarter car (Table 1 car, viscous ``c``) by scipy's exact ``lsim``.

    ``m_s z_s'' = -k_s x - c x'``, ``m_u z_u'' = k_s x + c x' - k_t (z_u - z_r) - c_t (z_u' -
    z_r')`` with ``x = z_s - z_u``, about the static equilibrium (no gravity, stops or tyre
    lift-off); the road enters as ``(z_r, z_r')``.
    """
    from scipy import signal

    ms, mu, ks, kt, ct = car.m_s, car.m_u, car.k_s, car.k_t, car.c_t
    a = [[0.0, 1.0, 0.0, 0.0], [-ks / ms, -c / ms, ks / ms, c / ms], [0.0, 0.0, 0.0, 1.0],
         [ks / mu, c / mu, -(ks + kt) / mu, -(c + ct) / mu]]
    b = [[0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [kt / mu, ct / mu]]
    lti = signal.StateSpace(a, b, [[1.0, 0.0, -1.0, 0.0]], [[0.0, 0.0]])
    _, x, _ = signal.lsim(lti, np.column_stack([road.z, road.zdot]), road.t)
    return x


def test_seed003_reproduction_and_improvements():
    """Seed 003 roads scaled to its passive peaks; the scale agrees with the closed form.

    The reproduction scales each road until the simulated passive peak stroke is the seed's
    (4.9, 2.22, 2.8 cm), so that peak is set by construction. What is not: the linear quarter
    car of Table 1 with the 1000 N s/m damper, solved by scipy (matrix exponential) on the
    same scaled road, must reach the seed's peak too (the simulator's passive response is the
    closed form's).
    """
    from mr_suspension.sim import config as cfg

    car = cfg.load_vehicle('seed003_passenger')
    rows = seeds.seed003_reproduction()
    summary = {s['road']: s for s in seeds.seed003_summary(rows)}
    for road, rep in seeds.SEED003_REPORTED.items():
        passive = next(r for r in rows if r['road'] == road
                       and r['suspension'].startswith('passive'))
        profile = seeds._seed003_road(road, passive['road_scale'], 1e-3)
        peak = np.max(np.abs(_linear_quarter_car_stroke(car, 1000.0, profile)))
        assert peak == pytest.approx(rep['passive_peak'], rel=1e-3), road
        s = summary[road]
        # The 5x harder Bingham damper cuts the stroke at least as much as the seed reports ...
        assert s['improvement_ours'] > 0.9 * rep['improvement']
        # ... and costs comfort, which the seed does not report.
        assert s['body_acc_rms_change'] > 50.0


def test_best_passive_sweeps():
    best, (cur, mc), (_, ml) = studies.best_passive(
        'bump', currents=[0.0, 0.5, 2.0], dampings=[300.0, 3000.0, 30000.0])
    for idx, b in best.items():
        k = int(np.argmin(mc[idx]))
        assert b['current'] == (cur[k], pytest.approx(mc[idx][k]))
        assert b['linear'][1] == pytest.approx(np.min(ml[idx]))
    # Softest linear damper is best for comfort, not for working space.
    assert best['working_space_rms']['linear'][0] > best['body_acc_rms']['linear'][0]
    assert all(math.isfinite(v['current'][1]) for v in best.values())
