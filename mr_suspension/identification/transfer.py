"""Validation on records of another programme, and which named causes transfer to it.

A cause is named on the records it was fitted on; whether it helps on another programme
(a broadband record after sine tests) is a separate question that those records cannot
answer: an effect fitted where the data say little about it (a loop fitted on full
reversals, met by small ones) may predict the new inputs worse than the baseline.

Given validation records, ``validate`` scores on their samples inside the fitted domain:

* the baseline, the extended model as selected on the fit records, each damper cause alone
  on the baseline (refitted on the fit records) and the extended model with each cause
  switched off (no refit): the *candidates*;
* the model handed on for such inputs: the candidate with the lowest MSE on the validation
  records, where it beats the extended model by a paired block t of at least ``T_MIN`` (else
  the extended model);
* the honest figure of that choice, by cross-fitting: each record is cut in two halves by
  time, the choice is made on one half and scored on the other, both ways: a choice never
  scores itself (Varma and Simon 2006 measure how much that flatters a selection).

NRMSE = RMS(error) / std(measured force) over the kept samples of all validation records.
"""

import copy
from dataclasses import dataclass

import numpy as np

from mr_suspension.identification import diagnose, engine

T_MIN = 2.0  # paired block t a candidate needs over the extended model to replace it
N_BLOCKS = 8  # contiguous blocks per half record for the paired t
EXTENDED = 'extended'
BASELINE = 'baseline'
ALONE = ' alone'
WITHOUT = 'without '


@dataclass(frozen=True)
class Validation:
    """Figures on validation records (see the module docstring).

    ``baseline_nrmse``, ``selected_nrmse``: baseline and extended model as selected on the
    fit records; ``extended_nrmse``: the model handed on for these inputs, cross-fitted;
    ``model``: its candidate name, ``fits`` its fitted models (``engine.FitResult``),
    ``causes`` the damper causes it keeps and ``dropped`` those it leaves out; ``choices``
    the candidate chosen on each half (first half, second half); ``candidates`` every
    candidate's NRMSE on all kept samples; ``reference_nrmse`` the learned reference's (or
    None); ``domain`` one line per stretch outside the fitted domain; ``excluded_share`` the
    share of samples left out for it.
    """

    records: tuple
    baseline_nrmse: float
    selected_nrmse: float
    extended_nrmse: float
    model: str
    fits: tuple
    causes: tuple
    dropped: tuple
    choices: tuple
    candidates: dict
    reference_nrmse: object
    domain: tuple
    excluded_share: float

    @property
    def gain(self):
        """``1 - extended / baseline`` of the model handed on."""
        return 1.0 - self.extended_nrmse / self.baseline_nrmse

    @property
    def selected_gain(self):
        """``1 - selected / baseline``: the extended model as selected on the fit records."""
        return 1.0 - self.selected_nrmse / self.baseline_nrmse


def candidates(res, damper_causes):
    """``{name: (fits, causes)}``: the models the validation records choose among."""
    final = res.final
    out = {EXTENDED: (res.predictors, tuple(damper_causes)), BASELINE: ((res.baseline,), ())}
    for e in damper_causes:
        single = res.singles.get(e)
        if single is not None and e in final.effects and e not in engine.SENSOR_EFFECTS:
            out[e + ALONE] = ((single,), (e,))
    for e in damper_causes:
        if e in final.effects and e not in engine.SENSOR_EFFECTS:
            off = copy.copy(final)
            off.effects = tuple(x for x in final.effects if x != e)
            out[WITHOUT + e] = ((off,), tuple(x for x in damper_causes if x != e))
    return out


def _blocks(n, parts):
    """Edges of ``parts`` contiguous blocks over ``n`` samples (fewer if ``n`` is short)."""
    k = max(1, min(parts, n))
    return np.linspace(0, n, k + 1).astype(int)


def block_mse(errors):
    """Per-block sums of squares of each half of each record: ``(sums, counts, half)``.

    ``errors`` holds, per record, the error on its kept samples in time order. Returns the
    blocks' sums of squares, their sample counts and which half each block lies in (0, 1).
    """
    sums, counts, half = [], [], []
    for e in errors:
        cuts = (0, len(e) // 2, len(e))
        for h, (a, b) in enumerate(zip(cuts[:-1], cuts[1:])):
            edges = _blocks(b - a, N_BLOCKS)
            for lo, hi in zip(edges[:-1], edges[1:]):
                if hi > lo:
                    seg = e[a + lo:a + hi]
                    sums.append(float(np.dot(seg, seg)))
                    counts.append(hi - lo)
                    half.append(h)
    return np.array(sums), np.array(counts), np.array(half)


def choose(stats, use):
    """Candidate chosen on the blocks ``use``: the lowest MSE that beats the extended model.

    ``stats`` maps each candidate to its ``(sums, counts)`` per block (same blocks for all).
    A candidate replaces the extended model only with a lower MSE on the blocks used and a
    paired t of the block MSE differences of at least ``T_MIN``.
    """
    ext_s, cnt = stats[EXTENDED]
    if not np.any(use):
        return EXTENDED
    cnt = cnt[use]
    ext = ext_s[use] / cnt
    best, best_mse = EXTENDED, float(ext_s[use].sum() / cnt.sum())
    for name, (s, _) in stats.items():
        if name == EXTENDED:
            continue
        mse = float(s[use].sum() / cnt.sum())
        d = ext - s[use] / cnt
        sd = float(np.std(d, ddof=1)) if d.size > 1 else 0.0
        t = float(np.mean(d) / (sd / np.sqrt(d.size))) if sd > 0.0 else 0.0
        if mse < best_mse and t >= T_MIN:
            best, best_mse = name, mse
    return best


def validate(res, records, damper_causes=()):
    """Score ``res`` on the validation ``records`` and choose the model for such inputs.

    Every record is checked against the fitted domain (``diagnose.domain_lines``); its flagged
    stretches are left out of every figure. Returns ``(Validation or None, domain lines)``:
    None when no sample lies inside the fitted domain (nothing to score).
    """
    keep, lines, excluded = [], [], 0
    for r in records:
        chk, found = diagnose.domain_lines(res, r)
        m = np.asarray(r.mask, dtype=bool)
        if chk is not None:
            excluded += int(np.count_nonzero(m & ~chk.mask))
            m = m & chk.mask
        keep.append(m)
        lines += found
    used = sum(int(np.count_nonzero(m)) for m in keep)
    if used < 2:
        return None, tuple(lines)
    std = float(np.std(np.concatenate([r.force[m] for r, m in zip(records, keep)])))
    cands = candidates(res, damper_causes)
    errors = {name: [(r.force - diagnose.predict_force(r, fits, channel=False))[m]
                     for r, m in zip(records, keep)]
              for name, (fits, _) in cands.items()}

    def nrmse(errs):
        return float(np.sqrt(np.mean(np.concatenate(errs) ** 2)) / std)

    stats, half = {}, None
    for name, errs in errors.items():
        s, c, half = block_mse(errs)
        stats[name] = (s, c)
    first, second = half == 0, half == 1
    on_first, on_second = choose(stats, first), choose(stats, second)
    # Cross-fitting: the first half is scored with the choice made on the second, and back.
    cnt = stats[EXTENDED][1]
    sse = stats[on_second][0][first].sum() + stats[on_first][0][second].sum()
    crossed = float(np.sqrt(sse / cnt.sum()) / std)
    chosen = choose(stats, np.ones_like(first))
    ref = None
    if res.reference_model is not None:
        ref = nrmse([r.force[m] - res.reference_model.predict(r, m)[m]
                     for r, m in zip(records, keep)])
    fits, kept = cands[chosen]
    return Validation(
        records=tuple(r.name for r in records), baseline_nrmse=nrmse(errors[BASELINE]),
        selected_nrmse=nrmse(errors[EXTENDED]), extended_nrmse=crossed, model=chosen,
        fits=tuple(fits), causes=kept,
        dropped=tuple(e for e in damper_causes if e not in kept
                      and e not in engine.SENSOR_EFFECTS),
        choices=(on_first, on_second),
        candidates={name: nrmse(errs) for name, errs in errors.items()},
        reference_nrmse=ref, domain=tuple(lines),
        excluded_share=excluded / max(used + excluded, 1)), tuple(lines)
