"""``diagnose-vehicle --car``: each corner of a full car with the body's coupling accounted for.

A rigid body (small angles, :mod:`mr_suspension.core.full_car`) moves the body point above
corner ``i`` with

    a_i = sum_k A_ik S_k,    A = T M^-1 T^T,   T_i = (1, -x_i, y_i),   M = diag(m_b, I_yy, I_xx),

``S_k`` the force corner ``k``'s strut and anti-roll bar put on the body (the bar's
``-k_arb (x_L - x_R)`` on the left, the opposite on the right). Corner ``i``'s own strut moves
it as a quarter car of effective mass ``m_i = 1 / A_ii``; the other corners and the bars add a
known acceleration once their forces are known,

    a_i - c_i = S_i / m_i,    c_i = sum_{k != i} A_ik S_k + sum_k A_ik F_arb,k,

which is the corner equation :mod:`~mr_suspension.identification.vehicle` fits, with ``c_i`` a
known term. The corners are solved by block coordinate descent (Gauss-Seidel over corners,
Bertsekas, *Nonlinear Programming*, 2nd ed., 2.7):

0. the four baselines (spring and damper refitted) by one least squares over the four
   accelerometers, with an offset per accelerometer;
1. each corner diagnosed with ``c_i`` from the others' latest fits;
2. a corner is diagnosed again when another corner's causes changed, until no cause changes
   (at most :data:`MAX_PASSES` passes).

The effective mass ``m_i`` scales the corner's forces, the reported ``m_s`` is the corner's
static share of the body (its quarter-car file).
"""

from dataclasses import dataclass, field, replace
import json
from pathlib import Path
import time

import numpy as np

from mr_suspension.core.full_car import CORNERS
from mr_suspension.identification import engine, vehicle
from mr_suspension.identification.data import DataError

MAX_PASSES = 3


def coupling_matrix(car):
    """Return ``A = T M^-1 T^T`` (4 x 4, 1/kg): body-point acceleration per corner force."""
    t, m, arb = car.body(coupled=True)
    nb = int(arb[0])
    tt = t[:, :nb]
    return tt @ np.diag(1.0 / m[:nb]) @ tt.T


def arb_forces(car, strokes):
    """Anti-roll bar forces on the body per corner (4 x n) from the strokes (4 x n) [N]."""
    out = np.zeros_like(strokes)
    for axle, k in enumerate((car.k_arb_f, car.k_arb_r)):
        left, right = 2 * axle, 2 * axle + 1
        f = -k * (strokes[left] - strokes[right])
        out[left], out[right] = f, -f
    return out


@dataclass(frozen=True)
class CarNominal:
    """Nominal car: the full-car parameters and the damper and driver of every corner."""

    car: object
    damper: object
    driver: object

    @classmethod
    def load(cls, car='lisa_full_car', damper='rd1005_bingham', driver='wonder_box'):
        """Load from ``config/`` names or YAML paths."""
        from mr_suspension.core.paramsets import load_full_car
        from mr_suspension.sim.corner import load_damper, load_driver
        return cls(load_full_car(car), load_damper(damper), load_driver(driver))

    def corner(self, i):
        """Nominal of corner ``i`` as a quarter car of its effective mass ``1 / A_ii``."""
        a = coupling_matrix(self.car)
        veh = replace(self.car.corner(i), m_s=float(1.0 / a[i, i]))
        return vehicle.Nominal(veh, self.damper, self.driver)


@dataclass
class FullCarDiagnosis:
    """Result: one :class:`~mr_suspension.identification.vehicle.VehicleResult` per corner.

    ``passes``: per pass, the corners diagnosed and their causes (Gauss-Seidel order);
    ``coupling``: ``A`` [1/kg]; ``effective_mass``: ``1 / A_ii`` [kg]; ``baseline``: the
    joint baseline's held-out NRMSE per corner (all four corners fitted at once, no effect).
    """

    corners: dict
    passes: list
    coupling: np.ndarray
    effective_mass: dict
    baseline: dict
    notes: dict = field(default_factory=dict)

    @property
    def causes(self):
        """``(corner, effect)`` of every named cause."""
        return [(c, e) for c, r in self.corners.items() for e in r.causes]

    @property
    def verdict(self):
        """The car's verdict: ``ambiguous``, ``named``, ``partly_explained`` or ``none``.

        The first of these that some corner reports.
        """
        verdicts = [r.verdict for r in self.corners.values()]
        for v in ('ambiguous', 'named', 'partly_explained'):
            if v in verdicts:
                return v
        return 'none'


def _aligned(corner_records):
    """Check that the corners' records share their sample times; trim to common lengths."""
    names = list(corner_records)
    first = corner_records[names[0]]
    for c in names[1:]:
        if len(corner_records[c]) != len(first):
            raise DataError(f'{c}: {len(corner_records[c])} records, {names[0]}: '
                            f'{len(first)}; every corner needs the same records')
    out = {c: [] for c in names}
    for k, r0 in enumerate(first):
        recs = [corner_records[c][k] for c in names]
        n = min(r.n for r in recs)
        for c, r in zip(names, recs):
            if abs(r.dt - r0.dt) > 1e-9 * r0.dt or abs(r.start - r0.start) > 0.5 * r0.dt:
                raise DataError(f'{c}: record {r.name} is sampled at other instants than '
                                f'{names[0]} ({r.dt:g} s from {r.start:.6f} s against '
                                f'{r0.dt:g} s from {r0.start:.6f} s); the corners must be '
                                'recorded on one clock')
            if r.n - n > 2:
                raise DataError(f'{c}: record {r.name} has {r.n} samples, another corner '
                                f'{n}; the corners must cover the same time')
            out[c].append(r if r.n == n else r.trimmed(n))
    return out


def _force(P, fit, m):
    """Return a corner's force on the body without its offset [N] from its fit (mass ``m``)."""
    if 'top_mount' in fit.effects:
        vehicle.mount_refresh(P, fit)
    X, names = vehicle.columns(P, fit.effects, fit.eta)
    th = np.array(fit.theta, dtype=float)
    th[names.index('offset')] = 0.0
    return m * (X @ th + P.stop)


def joint_baseline(Ps, a_mat, masses, arb):
    """Baselines of the four corners fitted at once; returns their forces and outer NRMSE.

    ``a_j - sum_k A_jk (m_k stop_k + F_arb,k) = sum_k A_jk m_k X_k theta_k + b_j`` over the
    rows every corner uses, ``X_k`` the baseline regressors of corner ``k`` (spring and
    damper, acceleration per unit effective mass), ``b_j`` one offset per accelerometer.
    """
    inner = np.all([P.search_rows for P in Ps], axis=0) & (Ps[0].fold != engine.OUTER)
    xs = []
    for P in Ps:
        X, names = vehicle.columns(P, (), vehicle.base_eta(P.nominal, P.coil))
        xs.append(X[:, [j for j, nm in enumerate(names) if nm != 'offset']])
    p = xs[0].shape[1]
    known = a_mat @ (np.stack([m * P.stop for P, m in zip(Ps, masses)]) + arb)
    blocks, ys = [], []
    for j, P in enumerate(Ps):
        cols = [a_mat[j, k] * masses[k] * xs[k][inner] for k in range(4)]
        off = np.zeros((int(inner.sum()), 4))
        off[:, j] = 1.0
        blocks.append(np.hstack(cols + [off]))
        ys.append(P.y_all[inner] - known[j][inner])
    X, y = np.vstack(blocks), np.concatenate(ys)
    theta = engine.solve_normal(X.T @ X, X.T @ y)
    forces = np.stack([masses[k] * (xs[k] @ theta[k * p:(k + 1) * p] + Ps[k].stop)
                       for k in range(4)])
    pred = a_mat @ (forces + arb)
    outer = Ps[0].fold == engine.OUTER
    nrmse = {}
    for j, P in enumerate(Ps):
        e = P.y_all[outer] - pred[j][outer]
        nrmse[CORNERS[j]] = float(np.sqrt(np.mean((e - e.mean()) ** 2))
                                  / np.std(P.y_all[outer]))
    return forces, nrmse


def run(corner_records, nominal=None, effects=vehicle.ALL_EFFECTS, progress=None):
    """Diagnose the four corners of a car; ``corner_records``: corner name -> records.

    Returns ``(FullCarDiagnosis, {corner: (Prepared, predictions)})``.
    """
    nominal = nominal or CarNominal.load()
    missing = [c for c in CORNERS if c not in corner_records]
    if missing:
        raise DataError(f'full car: no data for corner(s) {missing}; a full-car record has '
                        f'{", ".join(CORNERS)}')
    recs = _aligned({c: corner_records[c] for c in CORNERS})
    a_mat = coupling_matrix(nominal.car)
    masses = 1.0 / np.diag(a_mat)
    Ps = [vehicle.Prepared(recs[c], nominal.corner(i)) for i, c in enumerate(CORNERS)]
    arb = arb_forces(nominal.car, np.stack([np.concatenate(P.x) for P in Ps]))
    forces, base_nrmse = joint_baseline(Ps, a_mat, masses, arb)
    tick = progress or (lambda label: None)
    tick('joint baseline')
    results, outs, passes = [None] * 4, [None] * 4, []
    fitted = [()] * 4   # the causes each corner's force in ``forces`` was fitted with
    context = [None] * 4  # the others' causes at a corner's last diagnosis

    def others(i):
        return tuple(fitted[k] for k in range(4) if k != i)

    for _ in range(MAX_PASSES):
        done = {}
        for i in range(4):
            if context[i] == others(i):
                continue
            rest = [k for k in range(4) if k != i]
            Ps[i].set_coupling(a_mat[i, rest] @ forces[rest] + a_mat[i] @ arb)
            res, _, preds = vehicle.run(None, effects=effects, prepared=Ps[i])
            context[i] = others(i)
            results[i], outs[i], fitted[i] = res, preds, tuple(res.causes)
            forces[i] = _force(Ps[i], res.final, masses[i])
            done[CORNERS[i]] = list(res.causes)
            tick(f'{CORNERS[i]} pass {len(passes) + 1}')
        if not done:
            break
        passes.append(done)
    converged = all(context[i] == others(i) for i in range(4))
    for i, c in enumerate(CORNERS):
        share = nominal.car.static_share('front' if i < 2 else 'rear')
        results[i].corner['m_s'] = share
        results[i].notes['sprung_mass'] = (
            f'full car: forces fitted per unit effective mass 1/A_ii = {masses[i]:.1f} kg (the '
            f'body seen from this corner); m_s = {share:.1f} kg is the static share of the corner')
        results[i].notes.pop('m_s_if_nominal_damper', None)
    diag = FullCarDiagnosis(
        corners=dict(zip(CORNERS, results)), passes=passes, coupling=a_mat,
        effective_mass={c: float(m) for c, m in zip(CORNERS, masses)}, baseline=base_nrmse,
        notes={'method': 'block coordinate descent over the corners (module docstring)',
               'converged': converged})
    return diag, {c: (P, o) for c, P, o in zip(CORNERS, Ps, outs)}


def load(paths, road_topic=None):
    """Load every corner of full-car bags (namespaces :data:`CORNERS`)."""
    from mr_suspension.identification import vehicle_data
    return {c: vehicle_data.load(paths, c, road_topic) for c in CORNERS}


def markdown(diag, reports):
    """Return the car's summary report (Markdown)."""
    lines = ['# diagnose-vehicle report: full car', '',
             f'**Verdict: {diag.verdict}**; causes: '
             + (', '.join(f'`{e}` at {c}' for c, e in diag.causes) or 'none'), '',
             '| corner | verdict | causes | held-out NRMSE joint baseline | baseline -> '
             'extended | report |', '|---|---|---|---|---|---|']
    for c, r in diag.corners.items():
        h = r.heldout
        lines.append(f'| {c} | {r.verdict} | {", ".join(r.causes) or "none"} | '
                     f'{diag.baseline[c]:.4f} | {h["baseline_nrmse"]:.4f} -> '
                     f'{h["extended_nrmse"]:.4f} | [{c}/report.md]({c}/report.md) |')
    lines += ['', '## Body coupling', '',
              'The body-point acceleration above each corner is `a_i = sum_k A_ik S_k` '
              '(rigid body, small angles); each corner is fitted with the forces of the other '
              'corners and the anti-roll bars as a known term, corners refitted until no '
              'cause changes.', '',
              '| A [1/t] | ' + ' | '.join(CORNERS) + ' |', '|---' * 5 + '|']
    for i, c in enumerate(CORNERS):
        lines.append(f'| {c} | ' + ' | '.join(f'{1e3 * v:.3f}' for v in diag.coupling[i])
                     + ' |')
    lines += ['', 'Effective masses 1/A_ii: ' + ', '.join(
        f'{c} {m:.1f} kg' for c, m in diag.effective_mass.items()), '', '## Passes', '']
    for k, p in enumerate(diag.passes, 1):
        lines.append(f'- pass {k}: ' + '; '.join(
            f'{c}: {", ".join(d) or "none"}' for c, d in p.items()))
    if not diag.notes.get('converged', True):
        lines.append(f'- not converged after {MAX_PASSES} passes: causes still changing')
    return '\n'.join(lines) + '\n'


def diagnose_full_car(paths, out_dir, nominal=None, effects=vehicle.ALL_EFFECTS,
                      make_plots=True, progress=None):
    """Load a full car's bags, diagnose and write per corner and a summary.

    Writes ``out_dir/<corner>/`` (the corner reports and files of ``diagnose-vehicle``) and
    ``out_dir/report.md``, ``report.json``; returns ``(report dict, FullCarDiagnosis)``.
    """
    t0 = time.time()
    nominal = nominal or CarNominal.load()
    diag, data = run(load(paths), nominal, effects, progress)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    reports = {}
    for i, (c, res) in enumerate(diag.corners.items()):
        P, preds = data[c]
        reports[c] = vehicle.write(res, P, preds, out / c, nominal.corner(i), None, make_plots)
    rep = {'tool': 'mr-suspension diagnose-vehicle (full car)', 'verdict': diag.verdict,
           'causes': [{'corner': c, 'effect': e} for c, e in diag.causes],
           'corners': {c: {'verdict': r['verdict'], 'causes': [x['effect'] for x in
                                                               r['causes']],
                           'heldout': r['heldout'], 'report': f'{c}/report.json'}
                       for c, r in reports.items()},
           'joint_baseline_nrmse': diag.baseline, 'coupling_per_kg': diag.coupling.tolist(),
           'effective_mass': diag.effective_mass, 'passes': diag.passes, 'notes': diag.notes,
           'elapsed_s': time.time() - t0}
    (out / 'report.json').write_text(json.dumps(vehicle._jsonable(rep), indent=1),
                                     encoding='utf-8')
    (out / 'report.md').write_text(markdown(diag, reports), encoding='utf-8')
    return rep, diag
