"""Benchmark of ``diagnose`` on records it did not make: the independent truth (``truth``).

Two families, printed apart:

* **out-of-model**: ``mr_suspension.truth`` (own integrator with substeps, baseline shapes
  Bingham-tanh, algebraic, arctan and Bouc-Wen, effect shapes other than the fit's, parameter
  ranges >= 3x the fit's defaults, weak to strong effects) measured by realistic sensors (white,
  coloured and drifting noise, channel delay or anti-alias filter, derived or missing velocity,
  measured current present or absent, clipping, rounded stamps, dropouts);
* **in-model**: ``identification.synthetic`` (the fit's own kernels), as a reference.

Figures: first physical cause right on single effects whose contribution is >= 3x the noise
(``Case.contributions``), false alarms (a physical cause named on an effect-free record, sensor
faults included; a channel delay alone must come out as ``channel_delay``), exact sets on pairs,
the extended model's NRMSE on an unseen record of the same damper over that record's noise
floor, and the time of a 60 s, 1 kHz record through the whole catalogue. The unseen record's
floor is ``truth.cases.transfer_floor``: its force noise about the *training* record's mean
noise, which is what a perfect model fitted on the training record reaches (a drifting force
channel shifts the mean from record to record); the figure over the unseen record's own floor
is printed too.

The learned reference (``diagnose.ReferenceComparison``): per family, how often it beats the
extended model on held-out data, how often it does so while the extended model is within
1.15x its floor on the unseen record (a flip the requirement forbids), and how many records
with the exact cause set right it turns ``partly_explained`` on its own.

With ``--outside N`` a third family, **outside**, draws one of the truth's effects the
catalogue lacks (``truth.rig.OUTSIDE``: fluid inertia, Stribeck seal friction; alternating),
every other pair of cases with one catalogue effect beside it: how often the verdict is
``partly_explained`` (by the reference alone, by the noise floor).

With ``--clean-inputs`` every out-of-model case is diagnosed a second time, measured with
noise-free displacement, velocity and current sensors (same truth, faults and force noise):
the gap between the two unseen / floor figures is what input noise costs, the rest is the
model; the cause figures of that pass are printed beside (a cause named or missed only with
noisy inputs is the inputs' doing).

With ``--stages`` it counts, per stage of the selection (``diagnose.STAGES``), the records
whose extended model or causes that stage changed: what each check pays for on the benchmark.
``--without CHECK`` leaves a check out and ``--only K,...`` runs only those out-of-model cases:
a check that returns its state unchanged cannot matter, so rerunning the records it changed
without it (``--stages --json`` lists them) is its whole ablation.

Usage: ``python benchmarks/bench_diagnose.py [--cases 300] [--duration 12] [--jobs 2]
[--outside 0] [--stages] [--without CHECK,...] [--only K,...] [--json FILE]``.
"""

import argparse
from concurrent.futures import ProcessPoolExecutor
import functools
import itertools
import json
import time
import warnings

import numpy as np

from mr_suspension.identification import data as dataio
from mr_suspension.identification import diagnose, engine, synthetic
from mr_suspension.truth import cases as truth_cases
from mr_suspension.truth import rig as truth_rig
from mr_suspension.truth import sensors as truth_sensors


def case_list(n, seed, effects):
    """Cases: 1/6 effect-free (sensor faults drawn), 1/2 single effects (cycled), 1/3 pairs."""
    pairs = [p for p in itertools.combinations(effects, 2)
             if not any(set(p) <= ex for ex in diagnose.EXCLUSIVE)]
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        r = k % 6
        if r == 0:
            effs = ()
        elif r <= 3:
            effs = (effects[(k // 6 * 3 + r - 1) % len(effects)],)
        else:
            effs = pairs[rng.integers(len(pairs))]
        out.append(effs)
    return out


def outside_list(n, seed):
    """Cases of the ``outside`` family: one ``OUTSIDE`` effect each, alternating.

    Every other pair of cases has one catalogue effect (drawn) beside it.
    """
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        effs = (truth_rig.OUTSIDE[k % len(truth_rig.OUTSIDE)],)
        if (k // 2) % 2 == 1:
            effs = (truth_rig.EFFECTS[rng.integers(len(truth_rig.EFFECTS))],) + effs
        out.append(effs)
    return out


def _record(columns, name):
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        return dataio.build_record(name, columns)


_STAGE_LOG = []  # (stage, changed the model, changed the causes) of the case being diagnosed


def watch_stages():
    """Wrap ``diagnose.STAGES`` (once per process) so each case logs what each stage changed."""
    if getattr(diagnose, '_stages_watched', False):
        return

    def watched(stage):
        @functools.wraps(stage)  # keeps the stage's name for --without and the summary
        def run(s, c):
            t = stage(s, c)
            if t is not s:
                _STAGE_LOG.append((stage.__name__.removeprefix('_stage_'),
                                   t.final is not s.final, sorted(t.chosen) != sorted(s.chosen)))
            return t
        return run

    diagnose.STAGES = tuple(watched(st) for st in diagnose.STAGES)
    diagnose._stages_watched = True


def summarise_stages(results):
    """Per stage of the selection: records whose model or causes it changed."""
    rows = [r for r in results if 'stages' in r]
    print(f'\n== stages of the selection, over {len(rows)} diagnosed records '
          '(model: the extended model changed; causes: the named set changed)')
    seen = {st.__name__.removeprefix('_stage_'): [0, 0, []] for st in diagnose.STAGES}
    for r in rows:
        for name, model, causes in r['stages']:
            entry = seen.setdefault(name, [0, 0, []])
            entry[0] += bool(model)
            entry[1] += bool(causes)
            if causes:
                entry[2].append(r['k'])
    for name, (m, c, ks) in seen.items():
        print(f'  {name:24s} model {m:4d}  causes {c:4d}  {"cases " + str(ks) if ks else ""}')


def _unseen_scores(rec, unseen):
    """Fit ``rec``; return the fit, its unseen NRMSE (extended, baseline) and a flag.

    The flag: ``predict`` warned that the unseen record leaves the fitted range.
    """
    d = diagnose.Diagnosis()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        res = d.fit([rec])
        del caught[:]
        score = d.score(unseen)
        outside = any('outside the range' in str(w.message) for w in caught)
        return res, score, d.score(unseen, 'baseline'), outside


def _over(score, floor):
    return score / floor if floor > 0 else np.nan


def _clean_inputs(seed, effs, duration):
    """Diagnose the same case measured with noise-free motion and current sensors.

    Returns ``(unseen / floor, physical causes, sensor causes)``.
    """
    case = truth_cases.make_case(seed, effs, sensor_faults=None, duration=duration,
                                 measured_current=None, input_noise=False)
    u_case = case.unseen()
    res, score, _, _ = _unseen_scores(_record(case.columns, f'truth-{seed}-ci'),
                                      _record(u_case.columns, f'truth-{seed}-ci-unseen'))
    return (_over(score, truth_cases.transfer_floor(case, u_case)),) + _causes(res)


def _reference(res):
    """``(beats, gain, by_reference, by_floor)`` of a diagnosis's learned reference.

    ``beats``/``gain`` None without a reference; ``by_reference``: the verdict is
    ``partly_explained`` although the extended model is within ``PARTLY_FACTOR`` of the
    estimated floor (or no floor), so the reference alone made it; ``by_floor``: the floor did.
    """
    ref = getattr(res, 'reference', None)
    beats = None if ref is None else bool(ref.beats)
    gain = None if ref is None else float(ref.gain)
    eof = res.heldout.get('extended_over_floor')
    over = eof is not None and np.isfinite(eof) and eof > diagnose.PARTLY_FACTOR
    partly = res.verdict == 'partly_explained'
    return beats, gain, partly and not over, partly and over


def _causes(res):
    """``(physical causes, sensor causes)`` of a diagnosis."""
    return res.physical_causes, tuple(c for c in res.causes if c not in res.physical_causes)


def without_stages(names):
    """Drop the named checks (``diagnose.CHECKS``, names without ``_stage_``) from the run."""
    names = set(names)
    known = {st.__name__.removeprefix('_stage_') for st in diagnose.CHECKS}
    if names - known:
        raise SystemExit(f'--without: unknown check(s) {sorted(names - known)}; '
                         f'checks: {sorted(known)}')
    diagnose.STAGES = tuple(st for st in diagnose.STAGES
                            if st.__name__.removeprefix('_stage_') not in names)


def run_case(job):
    """Diagnose one case; return a dict of outcomes (runs in a worker process)."""
    family, k, effs, seed, duration, clean_inputs, stages, without = job
    diagnose.JOBS = 1  # the cases run in parallel processes already
    if without:
        without_stages(without)
    if stages:
        watch_stages()
    _STAGE_LOG.clear()
    t0 = time.time()
    if family == 'in-model':
        rec, truth = synthetic.make_record(effs, seed=seed, duration=duration)
        unseen, _ = synthetic.make_record(effs, seed=seed + 77, duration=duration,
                                          truth={'damper': truth['damper'],
                                                 'current_dynamics':
                                                     truth['current_dynamics']})
        floor = truth['noise_rms'] / np.std(rec.force)
        u_floor = own_floor = truth['noise_rms'] / np.std(unseen.force)
        contrib = {e: np.inf for e in effs}
        faults = ()
        shape = 'bingham_tanh'
        driver = 0.0
    else:
        try:
            case = truth_cases.make_case(seed, effs, sensor_faults=None, duration=duration,
                                         measured_current=None)
            rec = _record(case.columns, f'truth-{seed}')
            u_case = case.unseen()
            unseen = _record(u_case.columns, f'truth-{seed}-unseen')
        except ValueError as exc:  # DataError included: refused by the input checks
            return {'family': family, 'k': k, 'effects': effs, 'error': str(exc)}
        floor = case.floor_nrmse
        u_floor = truth_cases.transfer_floor(case, u_case)
        own_floor = u_case.floor_nrmse
        contrib = case.contributions
        faults = case.sensor['spec'].faults
        shape = case.truth.shape
        # The truth's driver always has a small lag (0.05-0.5 ms); seen through the command
        # it is a real current lag.
        driver = case.driver_contribution if case.sensor['spec'].current == 'absent' else 0.0
    try:
        res, score, b_score, outside = _unseen_scores(rec, unseen)
        changed = list(_STAGE_LOG)
        ci_ratio, ci_causes, ci_sensor = (
            _clean_inputs(seed, effs, duration) if clean_inputs and family == 'out-of-model'
            else (np.nan, None, None))
    except (dataio.DataError, ValueError) as exc:
        return {'family': family, 'k': k, 'effects': effs, 'error': str(exc)}
    est = res.floor.nrmse if res.floor is not None else float('nan')
    physical, sensor = _causes(res)
    ref_beats, ref_gain, by_ref, by_floor = _reference(res)
    return {'family': family, 'k': k, 'effects': effs, 'faults': faults, 'shape': shape,
            'driver': driver,
            'causes': physical, 'sensor': sensor,
            'verdict': res.verdict, 'contrib': contrib, 'floor': floor,
            'floor_est': est, 'unseen_ratio': _over(score, u_floor),
            'unseen_baseline_ratio': _over(b_score, u_floor), 'unseen_outside': outside,
            'unseen_ratio_own_floor': _over(score, own_floor),
            'unseen_ratio_clean_inputs': ci_ratio, 'causes_clean_inputs': ci_causes,
            'sensor_clean_inputs': ci_sensor, 'seed': seed, 'ref_beats': ref_beats,
            'ref_gain': ref_gain, 'partly_by_reference': by_ref, 'partly_by_floor': by_floor,
            'heldout': res.heldout['extended_nrmse'], 'seconds': time.time() - t0,
            **({'stages': changed} if stages else {})}


# The truth's driver lag (at a command edge the force sample still reads the old current,
# so seen through the command it is a sample of dead time or a sub-sample lag) is present
# when its contribution c (RMS / noise) would pass diagnose's own materiality bar: an MSE
# share c^2 / (1 + c^2) >= G_MIN, i.e. c >= 0.18 at G_MIN = 3 %.
DRIVER_PRESENT = float(np.sqrt(diagnose.G_MIN / (1.0 - diagnose.G_MIN)))


def shape_extras(shape, driver=0.0, driver_bar=DRIVER_PRESENT):
    """Causes that describe the truth's baseline itself, not a hidden effect.

    The fit's baseline is a tanh yield; a truth with another yield sigmoid really has a
    different ``yield_shape``, a Bouc-Wen baseline really has a pre-yield ``hysteresis``
    loop, and the truth's small driver lag (0.05-0.5 ms), seen through the command, is a real
    current lag (or, a sample late behind the DAC's hold, a dead time) when its force
    contribution is at least ``driver_bar`` times the noise. Naming them is right; they are
    left out of the scores (the strict figures count them).
    """
    out = {'current_lag', 'current_delay'} if driver >= driver_bar else set()
    if shape != 'bingham_tanh':
        out.add('yield_shape')
    if shape == 'bouc_wen':
        out.add('hysteresis')
    return out


def _scored(results, strict, driver_bar=DRIVER_PRESENT):
    out = []
    for r in results:
        r = dict(r)
        extra = set() if strict else shape_extras(r['shape'], r['driver'], driver_bar)
        r['causes'] = tuple(c for c in r['causes'] if c not in extra or c in r['effects'])
        out.append(r)
    return out


def _ratio_line(label, values):
    """Print median, 95th percentile, max and the count above 3x of the finite ``values``."""
    a = np.asarray(values, dtype=float)
    a = a[np.isfinite(a)]
    if a.size:
        print(f'{label}: median {np.median(a):.2f}, 95th percentile {np.percentile(a, 95):.2f}, '
              f'max {a.max():.2f}, above 3x: {int(np.sum(a > 3))}/{a.size}')


def _cause_counts(res):
    """Count the cause figures of scored results.

    Returns the per-effect first cause ``{e: [right, n]}``, then the first cause over all
    effects, false alarms, channel delay alone and exact pairs, each ``(hits, n)``.
    """
    ok = {e: [0, 0] for e in engine.EFFECTS}
    for r in res:
        if len(r['effects']) == 1:
            e = r['effects'][0]
            if r['contrib'].get(e, 0.0) >= 3.0:
                ok[e][1] += 1
                ok[e][0] += bool(r['causes']) and r['causes'][0] == e
    free = [r for r in res if not r['effects']]
    dl = [r for r in free if 'channel_delay' in r['faults']]
    pairs = [r for r in res if len(r['effects']) == 2
             and all(r['contrib'].get(e, 0.0) >= 3.0 for e in r['effects'])]
    return (ok, (sum(v[0] for v in ok.values()), sum(v[1] for v in ok.values())),
            (sum(bool(r['causes']) for r in free), len(free)),
            (sum('channel_delay' in r['sensor'] and not r['causes'] for r in dl), len(dl)),
            (sum(set(r['causes']) == set(r['effects']) for r in pairs), len(pairs)))


def summarise(family, results, strict=False):
    """Print the figures of one family."""
    res = [r for r in results if r['family'] == family]
    err = [r for r in res if 'error' in r]
    raw = [r for r in res if 'error' not in r]
    res = _scored(raw, strict)
    print(f'\n== {family}{" (strict: shape causes count)" if strict else ""}: {len(res)} '
          f'cases diagnosed, {len(err)} refused by the input checks')
    for r in err[:5]:
        print(f'   refused: {"+".join(r["effects"]) or "none"}: {r["error"][:110]}')
    ok, tot, fa, dl, pk = _cause_counts(res)
    print('first physical cause right, single effects >= 3x noise:')
    for e, (a, n) in ok.items():
        print(f'  {e:24s} {a:3d}/{n:3d}')
    print(f'  {"all":24s} {tot[0]:3d}/{tot[1]:3d} = {100 * tot[0] / max(tot[1], 1):.1f} %')
    print(f'false alarms (physical cause on an effect-free record): {fa[0]}/{fa[1]} = '
          f'{100 * fa[0] / max(fa[1], 1):.1f} % (the driver lag present from '
          f'{DRIVER_PRESENT:.2f}x the noise)')
    if not strict:
        old = [r for r in _scored(raw, strict, 1.0) if not r['effects']]
        print(f'  same, the driver lag present only from 1x the noise (a stricter count): '
              f'{sum(bool(r["causes"]) for r in old)}/{len(old)}')
    if dl[1]:
        print(f'channel delay alone named channel_delay (no physics): {dl[0]}/{dl[1]}')
    print(f'exact sets on pairs (both >= 3x noise): {pk[0]}/{pk[1]} = '
          f'{100 * pk[0] / max(pk[1], 1):.1f} %')
    clean = [dict(r, causes=r['causes_clean_inputs'], sensor=r['sensor_clean_inputs'])
             for r in raw if r.get('causes_clean_inputs') is not None]
    if clean:
        _, tot, fa, dl, pk = _cause_counts(_scored(clean, strict))
        print(f'  the same cases with noise-free displacement, velocity and current sensors: '
              f'first cause {tot[0]}/{tot[1]}, false alarms {fa[0]}/{fa[1]}, channel delay '
              f'alone {dl[0]}/{dl[1]}, pairs {pk[0]}/{pk[1]}')
    for key, label in (('unseen_ratio', 'extended model on an unseen record / its noise floor'),
                       ('unseen_ratio_own_floor',
                        "  over the unseen record's own noise floor (noise about its own mean: "
                        "a drift's record-to-record level shift counted as model error)"),
                       ('unseen_ratio_clean_inputs', '  the same cases with noise-free '
                        'displacement, velocity and current sensors')):
        _ratio_line(label, [r.get(key, np.nan) for r in res])
    if any('unseen_outside' in r for r in res):
        for flag, where in ((True, 'outside the fitted range (predict warns)'),
                            (False, 'inside it')):
            sub = [r.get('unseen_ratio', np.nan) for r in res
                   if r.get('unseen_outside') is flag]
            _ratio_line(f'  unseen records {where}: {len(sub)}', sub)
    fe = np.array([r['floor_est'] / r['floor'] for r in res
                   if np.isfinite(r['floor_est']) and r['floor'] > 0])
    nf = sum(not np.isfinite(r['floor_est']) for r in res)
    if fe.size:
        print(f'noise floor estimated from the data / true floor: median {np.median(fe):.2f},'
              f' 10-90 % {np.percentile(fe, 10):.2f}-{np.percentile(fe, 90):.2f} '
              f'(not estimable: {nf})')
    verdicts = {}
    for r in res:
        verdicts[r['verdict']] = verdicts.get(r['verdict'], 0) + 1
    print('verdicts: ' + ', '.join(f'{k} {v}' for k, v in sorted(verdicts.items())))
    _reference_lines(res)
    print(f'seconds per case: median {np.median([r["seconds"] for r in res]):.1f}')


FLIP_RATIO = 1.15  # extended model within this many floors: the reference must not flip it


def _reference_lines(res):
    """Print the learned reference's figures of scored results."""
    have = [r for r in res if r.get('ref_beats') is not None]
    beats = [r for r in have if r['ref_beats']]
    near = [r for r in beats if r.get('unseen_ratio', np.nan) <= FLIP_RATIO]
    exact = [r for r in res if set(r['causes']) == set(r['effects'])]
    flipped = [r for r in exact if r.get('partly_by_reference')]
    forbidden = [r for r in flipped if r.get('unseen_ratio', np.nan) <= FLIP_RATIO]
    gains = [r['ref_gain'] for r in have]
    print(f'learned reference beats the extended model: {len(beats)}/{len(have)} (no reference: '
          f'{len(res) - len(have)}; gain median '
          f'{np.median(gains) if gains else np.nan:.3f})')
    print(f'  of those, extended model within {FLIP_RATIO:g}x its floor on the unseen record: '
          f'{len(near)} (flips the requirement forbids)')
    print(f'  verdict partly_explained by the reference alone: '
          f'{sum(bool(r.get("partly_by_reference")) for r in res)}/{len(res)}, by the floor: '
          f'{sum(bool(r.get("partly_by_floor")) for r in res)}/{len(res)}')
    print(f'exact cause set right: {len(exact)} ({sum(bool(r["effects"]) for r in exact)} '
          f'with effects); turned partly_explained by the reference: {len(flipped)} (of them '
          f'effect-free {sum(not r["effects"] for r in flipped)}, within {FLIP_RATIO:g}x the '
          f'floor {len(forbidden)})')


def summarise_outside(results):
    """Print the figures of the ``outside`` family (is an effect the catalogue lacks caught)."""
    res = [r for r in results if r['family'] == 'outside']
    err = [r for r in res if 'error' in r]
    raw = {r['k']: r['causes'] for r in res if 'error' not in r}
    res = _scored([r for r in res if 'error' not in r], False)
    print(f'\n== outside (effects the catalogue lacks: {", ".join(truth_rig.OUTSIDE)}): '
          f'{len(res)} cases diagnosed, {len(err)} refused by the input checks')
    for r in err[:5]:
        print(f'   refused: {"+".join(r["effects"])}: {r["error"][:110]}')

    def line(label, sub):
        n = len(sub)
        pe = sum(r['verdict'] == 'partly_explained' for r in sub)
        print(f'  {label:44s} partly_explained {pe:3d}/{n:3d} = {100 * pe / max(n, 1):5.1f} % '
              f'(by the reference alone {sum(bool(r["partly_by_reference"]) for r in sub)}, '
              f'by the floor {sum(bool(r["partly_by_floor"]) for r in sub)})')

    def strong(r):
        return all(r['contrib'].get(e, 0.0) >= 3.0 for e in r['effects']
                   if e in truth_rig.OUTSIDE)

    line('all', res)
    line('outside effect >= 3x noise', [r for r in res if strong(r)])
    line('outside effect < 3x noise', [r for r in res if not strong(r)])
    for e in truth_rig.OUTSIDE:
        line(f'{e} alone', [r for r in res if r['effects'] == (e,)])
        line(f'{e} with a catalogue effect',
             [r for r in res if e in r['effects'] and len(r['effects']) == 2])
    with_cat = [r for r in res if len(r['effects']) == 2]
    named = sum(bool(set(r['effects']) & set(r['causes'])) for r in with_cat)
    print(f'  catalogue effect beside it named: {named}/{len(with_cat)}')
    _ratio_line('extended model on an unseen record / its noise floor',
                [r.get('unseen_ratio', np.nan) for r in res])
    verdicts = {}
    for r in res:
        verdicts[r['verdict']] = verdicts.get(r['verdict'], 0) + 1
    print('verdicts: ' + ', '.join(f'{k} {v}' for k, v in sorted(verdicts.items())))
    for r in res:
        c = ', '.join(f'{e} {r["contrib"].get(e, np.nan):.1f}x' for e in r['effects'])
        print(f'  {r["k"]:3d} {c:52s} found={"+".join(raw[r["k"]]) or "none":30s} '
              f'{r["verdict"]:16s} ref beats={r["ref_beats"]} unseen/floor '
              f'{r["unseen_ratio"]:.2f}')


def timing():
    """Time a 60 s, 1 kHz record (out-of-model, two effects) through the whole catalogue."""
    case = truth_cases.make_case(12345, ('current_lag_asymmetric', 'series_stiffness'),
                                 sensor_faults=('channel_delay',), duration=60.0)
    rec = _record(case.columns, 'timing')
    # The compiled kernels are cached on disk at their first use after an install or an
    # edit; that one-off compilation is timed apart, on a 3 s piece of the same record.
    t0 = time.time()
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        diagnose.Diagnosis().fit([dataio.window(rec, 0, int(3.0 / rec.dt))])
    print(f'\nTiming: warm-up (3 s piece; compiles the kernels once per install) '
          f'{time.time() - t0:.2f} s')
    t0, c0 = time.time(), time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        res = diagnose.Diagnosis().fit([rec])
    print(f'\nTiming: 60 s at 1 kHz, whole catalogue with pairs: {time.time() - t0:.2f} s wall,'
          f' {time.process_time() - c0:.2f} s CPU (found {list(res.causes)}, '
          f'verdict {res.verdict})')


def _jsonable(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, (set, tuple, np.ndarray)):
        return list(o)
    return str(o)


def _case_numbers(text):
    """``--only``: comma-separated case numbers (a set of int; empty: all cases)."""
    try:
        return {int(k) for k in text.split(',') if k.strip()}
    except ValueError:
        raise argparse.ArgumentTypeError(f'case numbers separated by commas, got {text!r}')


def main(argv=None):
    """Run the benchmark and print the figures."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--cases', type=int, default=300, help='out-of-model cases')
    ap.add_argument('--in-model', type=int, default=60, help='in-model reference cases')
    ap.add_argument('--duration', type=float, default=12.0)
    ap.add_argument('--seed', type=int, default=0)
    ap.add_argument('--jobs', type=int, default=2)
    ap.add_argument('--no-timing', action='store_true')
    ap.add_argument('--json', default=None, help='write every case outcome to this JSON file')
    ap.add_argument('--clean-inputs', action='store_true',
                    help='also diagnose every out-of-model case measured with noise-free '
                         'displacement, velocity and current (doubles the time): how much of '
                         'the unseen / floor figure is input noise, how much the model')
    ap.add_argument('--outside', type=int, default=0,
                    help='cases of the outside family: an effect the catalogue lacks '
                         '(truth.rig.OUTSIDE), every other pair with a catalogue effect')
    ap.add_argument('--without', default='',
                    help='comma-separated checks of diagnose.CHECKS to leave out (ablation)')
    ap.add_argument('--only', default='', type=_case_numbers,
                    help='comma-separated out-of-model case numbers to run (no other family)')
    ap.add_argument('--stages', action='store_true',
                    help='log, per record, which stages of the selection changed the model or '
                         'the causes, and print how often each did')
    args = ap.parse_args(argv)
    ci, st = args.clean_inputs, args.stages
    wo = tuple(w for w in args.without.split(',') if w)
    if wo:
        without_stages(wo)  # checked here, applied in every worker
    jobs = [('out-of-model', k, e, args.seed * 100003 + k, args.duration, ci, st, wo)
            for k, e in enumerate(case_list(args.cases, args.seed, truth_rig.EFFECTS))]
    jobs += [('in-model', k, e, args.seed * 100003 + 50000 + k, args.duration, False, st, wo)
             for k, e in enumerate(case_list(args.in_model, args.seed + 1, engine.EFFECTS))]
    jobs += [('outside', k, e, args.seed * 100003 + 70000 + k, args.duration, False, st, wo)
             for k, e in enumerate(outside_list(args.outside, args.seed + 2))]
    if args.only:
        jobs = [j for j in jobs if j[0] == 'out-of-model' and j[1] in args.only]
    t0 = time.time()
    results = []
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        for r in pool.map(run_case, jobs, chunksize=1):
            results.append(r)
            found = '+'.join(r.get('causes', ())) or ('ERROR' if 'error' in r else 'none')
            print(f'{r["family"]:12s} {r["k"]:3d} {r.get("shape", ""):12s} '
                  f'truth={"+".join(r["effects"]) or "none":42s}'
                  f' faults={",".join(r.get("faults", ())):36s} found={found:40s}'
                  f' {r.get("verdict", "")}', flush=True)
    print(f'\n{len(jobs)} cases of {args.duration:g} s in {time.time() - t0:.0f} s, '
          f'{args.jobs} worker(s); sensor faults drawn from {truth_sensors.FAULTS}')
    if args.json:
        with open(args.json, 'w') as fh:
            json.dump(results, fh, indent=1, default=_jsonable)
    for family in ('out-of-model', 'in-model'):
        summarise(family, results)
    summarise('out-of-model', results, strict=True)
    if args.outside:
        summarise_outside(results)
    if args.stages:
        summarise_stages(results)
    if not args.no_timing:
        timing()


if __name__ == '__main__':
    main()
