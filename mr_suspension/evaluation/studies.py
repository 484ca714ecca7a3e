"""Studies around the laws: passive and semi-active limits, actuator speed, estimator delays.

* :func:`best_passive`: the best constant current of the MR damper and the best linear damper
  for each ride index (grid over the setting, ideal driver).
* :func:`bound_comparison`: every law against the best passive setting and against the offline
  semi-active reference of :func:`~mr_suspension.control.optimal.semi_active_bound` (full road
  knowledge, ideal actuator), on the same road; "closeness" is the share of the passive-to-bound
  gap that the law closes, ``(J_passive - J_law) / (J_passive - J_bound)`` (1 = reaches the
  reference, 0 = no better than the best passive setting, < 0 = worse).
* :func:`degradation`: each law with the actuator time constants and dead time scaled (0 =
  ideal, 1 = Wonder Box + fluid, about 25 ms on falling current) and with added sensor and
  compute delay.
* :func:`noise_study`: each law with white noise on the accelerometers and the stroke sensor.
* :func:`estimator_delays`: delay of the sensor-based velocity estimates against the truth,
  from the phase of the first harmonic at several frequencies, ``tau = -phase / omega``.
"""

import math

import numpy as np

from mr_suspension.control import estimation as est
from mr_suspension.control.optimal import schedule_from_run, semi_active_bound
from mr_suspension.core import road as rd
from mr_suspension.core.metrics import ride_metrics
from mr_suspension.evaluation import runner
from mr_suspension.evaluation import scenarios as scn
from mr_suspension.sim.simulator import simulate

INDICES = ('body_acc_rms', 'body_acc_wk_rms', 'working_space_rms', 'tyre_load_rms')


def best_passive(scenario='iso_C_20', vehicle='city_car', damper='rd1005_bingham',
                 currents=None, dampings=None):
    """Best passive setting for each index: ``{index: {'current': (I, J), 'linear': (c, J)}}``."""
    currents = np.linspace(0.0, 2.0, 21) if currents is None else np.asarray(currents)
    dampings = np.geomspace(150.0, 12000.0, 25) if dampings is None else np.asarray(dampings)
    mc = runner.passive_sweep(currents, scenario, vehicle, damper, kind='current')
    ml = runner.passive_sweep(dampings, scenario, vehicle, damper, kind='linear')
    out = {}
    for idx in INDICES:
        kc = int(np.argmin(mc[idx]))
        kl = int(np.argmin(ml[idx]))
        out[idx] = {'current': (float(currents[kc]), float(mc[idx][kc])),
                    'linear': (float(dampings[kl]), float(ml[idx][kl]))}
    return out, (currents, mc), (dampings, ml)


def equal_space_comparison(rows, sweep, scenario):
    """Comfort of each law against the passive current family at the same working space.

    ``sweep``: metric arrays of a constant-current sweep on ``scenario``
    (:func:`~mr_suspension.evaluation.runner.passive_sweep`). The passive Wk RMS at the law's
    working-space RMS is interpolated along the family; returns rows with the law's Wk RMS,
    the passive one and the change in % (negative = the law is more comfortable than any
    passive setting using the same working space). NaN outside the family's range.
    """
    ws = np.asarray(sweep['working_space_rms'])
    wk = np.asarray(sweep['body_acc_wk_rms'])
    order = np.argsort(ws)
    out = []
    for r in rows:
        if r['scenario'] != scenario:
            continue
        x = r['working_space_rms']
        inside = ws.min() * (1.0 - 1e-6) <= x <= ws.max() * (1.0 + 1e-6)
        ref = float(np.interp(x, ws[order], wk[order])) if inside else float('nan')
        out.append({'law': r['law'], 'working_space_rms': x, 'body_acc_wk_rms':
                    r['body_acc_wk_rms'], 'passive_wk_same_space': ref,
                    'change_pct': 100.0 * (r['body_acc_wk_rms'] / ref - 1.0)})
    return out


def _short_road(name, dt, duration):
    if name == 'bump':
        return rd.bump(scn.BUMP_HEIGHT, 2.0, 10.0, t0=0.2, duration=duration, dt=dt)
    if name == 'step':
        return rd.step(scn.STEP_HEIGHT, t0=0.2, rise=0.01, duration=duration, dt=dt)
    parts = name.split('_')
    if parts[0] == 'iso' and len(parts) == 3:
        return rd.iso8608(parts[1].upper(), float(parts[2]), duration=duration, dt=dt, seed=7)
    raise ValueError(f'bound_comparison: unsupported road {name!r}')


def bound_comparison(laws=runner.DEFAULT_LAWS, road='bump', objectives=('body_acc_rms',
                     'tyre_load_rms'), vehicle='city_car', damper='rd1005_bingham',
                     driver='wonder_box', duration=3.0, block=0.02, maxiter=40, dt=1e-3):
    """Laws vs best passive current vs offline semi-active reference (module doc).

    Returns a list of rows ``{objective, law, value, closeness}`` including the rows
    ``best passive (I=...)`` and ``semi-active reference``.
    """
    rd_ = _short_road(road, dt, duration)
    results = {}
    for law in laws:
        conf = runner.build_config(law, vehicle, damper, driver, dt=dt)
        results[law] = simulate(conf, rd_)
    rows = []
    currents = np.linspace(0.0, 2.0, 21)
    for obj in objectives:
        vals = {law: ride_metrics(res)[obj] for law, res in results.items()}
        passive = []
        for i in currents:
            conf = runner.build_config(runner.ControllerParams(law='constant', current=float(i)),
                                       vehicle, damper, 'ideal', dt=dt)
            passive.append(ride_metrics(simulate(conf, rd_))[obj])
        kp = int(np.argmin(passive))
        j_pass = passive[kp]
        # Reference: best of several warm starts (mid current, best passive, best law).
        ref_conf = runner.build_config('passive_0A', vehicle, damper, 'ideal', dt=dt)
        nb = int(math.ceil(rd_.n_steps / max(1, int(round(block / dt)))))
        best_law = min(vals, key=vals.get)
        starts = [None, np.full(nb, currents[kp]),
                  schedule_from_run(results[best_law].i_cmd, dt, block, nb)]
        j_ref = math.inf
        for x0 in starts:
            val, _, _ = semi_active_bound(ref_conf, rd_, obj, block, x0, maxiter)
            j_ref = min(j_ref, val)
        j_ref = min(j_ref, j_pass)
        gap = j_pass - j_ref

        def closeness(j):
            return (j_pass - j) / gap if gap > 1e-12 else float('nan')

        rows.append({'objective': obj, 'law': f'best passive (I={currents[kp]:.1f} A)',
                     'value': j_pass, 'closeness': 0.0})
        rows.append({'objective': obj, 'law': 'semi-active reference', 'value': j_ref,
                     'closeness': 1.0})
        for law, j in vals.items():
            rows.append({'objective': obj, 'law': law, 'value': j, 'closeness': closeness(j)})
    return rows


def degradation(laws=runner.DEFAULT_LAWS, scenario='iso_C_20', scales=(0.0, 0.5, 1.0, 2.0, 4.0),
                delays=(0.0, 0.005, 0.01, 0.02), vehicle='city_car',
                damper='rd1005_bingham', driver='wonder_box', dt=1e-3):
    """Metrics of each law vs actuator speed (``scales``) and vs sensor+compute delay.

    Returns ``(rows_scale, rows_delay)``; each row has ``law``, ``scale`` or ``delay`` and the
    metrics of :data:`~mr_suspension.evaluation.runner.METRICS`.
    """
    sc = scn.make(scenario, dt)
    rows_s, rows_d = [], []
    for law in laws:
        for s in scales:
            conf = runner.build_config(law, vehicle, damper, driver, 0.0, s, dt=dt)
            met = ride_metrics(simulate(conf, sc.road))
            rows_s.append({'law': law, 'scale': s, **{k: met[k] for k in INDICES}})
        for d in delays:
            conf = runner.build_config(law, vehicle, damper, driver, d, 1.0, dt=dt)
            met = ride_metrics(simulate(conf, sc.road))
            rows_d.append({'law': law, 'delay': d, **{k: met[k] for k in INDICES}})
    return rows_s, rows_d


NOISE_LEVELS = ((0.0, 0.0), (0.05, 1e-4), (0.2, 5e-4), (0.5, 1e-3))


def noise_study(laws=runner.DEFAULT_LAWS, scenario='iso_C_20', levels=NOISE_LEVELS,
                vehicle='city_car', damper='rd1005_bingham', driver='wonder_box', dt=1e-3):
    """Metrics of each law with white sensor noise ``(accelerometers [m/s^2], stroke [m])``.

    The noise enters the measurements the control core sees (reproducible, seed 1), so the
    estimator, the resolution thresholds and the switching laws all face it.
    """
    sc = scn.make(scenario, dt)
    rows = []
    for law in laws:
        for n_acc, n_x in levels:
            conf = runner.build_config(law, vehicle, damper, driver, dt=dt, overrides={
                '*': {'noise_acc': n_acc, 'noise_stroke': n_x}})
            met = ride_metrics(simulate(conf, sc.road))
            rows.append({'law': law, 'noise_acc': n_acc, 'noise_stroke': n_x,
                         **{k: met[k] for k in INDICES}})
    return rows


def _phase(t, y, f):
    w = 2.0 * math.pi * f
    a = np.column_stack([np.sin(w * t), np.cos(w * t), np.ones_like(t)])
    c, *_ = np.linalg.lstsq(a, y, rcond=None)
    return math.atan2(c[1], c[0])


def run_estimator(a_s, a_u, x, dt, f_hp=0.1, f_cr=2.0, f_lp=40.0):
    """Run the sensor-based estimator over records; returns ``(v_s_hat, v_hat)`` arrays.

    The accelerations are those of the preceding step (as the simulator fills ``m``).
    """
    s = np.zeros(4)
    n = len(x)
    vs = np.empty(n)
    v = np.empty(n)
    prev_as, prev_au = 0.0, 0.0
    for k in range(n):
        vs[k], v[k] = est.estimate_step(s, prev_as, prev_au, x[k], dt, f_hp, f_cr, f_lp)
        prev_as, prev_au = a_s[k], a_u[k]
    return vs, v


def estimator_delays(freqs=(0.5, 1.0, 2.0, 5.0, 10.0), vehicle='city_car', dt=1e-3,
                     f_hp=0.1, f_cr=2.0, f_lp=40.0):
    """Delay [ms] of the estimates vs the true velocities at each frequency (module doc).

    Rows: ``freq``, ``body_velocity_ms``, ``stroke_rate_ms`` (with wheel accelerometer),
    ``stroke_rate_no_wheel_acc_ms`` (filtered derivative only), and the amplitude ratios.
    The stroke is sampled at the end of the step and the accelerations over the previous step,
    as in the simulator; a positive delay means the estimate lags.
    """
    conf = runner.build_config('passive_0A', vehicle, 'rd1005_bingham', 'ideal', dt=dt)
    rows = []
    for f in freqs:
        periods = 6
        road = rd.harmonic(0.01, f, duration=4.0 + periods / f, dt=dt)
        res = simulate(conf, road)
        t = res.t
        x = res.stroke
        vs_hat, v_hat = run_estimator(res.a_s, res.a_u, x, dt, f_hp, f_cr, f_lp)
        _, v_nw = run_estimator(res.a_s, np.full_like(x, np.nan), x, dt, f_hp, f_cr, f_lp)
        sel = t >= t[-1] - periods / f
        w = 2.0 * math.pi * f
        row = {'freq': f}
        for key, est_sig, true in (('body_velocity', vs_hat, res.v_s),
                                   ('stroke_rate', v_hat, res.stroke_rate),
                                   ('stroke_rate_no_wheel_acc', v_nw, res.stroke_rate)):
            dphi = _phase(t[sel], true[sel], f) - _phase(t[sel], est_sig[sel], f)
            dphi = (dphi + math.pi) % (2.0 * math.pi) - math.pi
            row[f'{key}_ms'] = 1e3 * dphi / w
            row[f'{key}_gain'] = float(np.std(est_sig[sel]) / np.std(true[sel]))
        rows.append(row)
    return rows


def bias_drift(bias=0.05, duration=60.0, dt=1e-3, f_hp=0.1):
    """Body-velocity error after ``duration`` with a constant accelerometer bias [m/s^2].

    Bounded by ``bias / (2 pi f_hp)`` (module doc of the estimator); returns the final error.
    """
    n = int(round(duration / dt))
    s = np.zeros(4)
    v = 0.0
    for _ in range(n):
        v, _ = est.estimate_step(s, bias, 0.0, 0.0, dt, f_hp, 2.0, 40.0)
    return float(v)
