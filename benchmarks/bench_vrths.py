"""Real-data benchmark: the shared vrths sine tests diagnosed, the earthquake record predicted.

Prints, for the physics baseline, the extended model and the learned reference: the NRMSE
on the outer blocks, on the kept-back records, the report's headline, and on the earthquake
record (``validacion.mat``, five current levels, never used in the fit), with the stretches
of it outside the fitted domain; then the causes, verdict and wall time.

Usage: ``python benchmarks/bench_vrths.py [--subset demo|all] [--out DIR]``; the data are
looked for at ``../shared/data/vrths`` (``--vrths DIR`` otherwise).
"""

import argparse
import tempfile
import time
import warnings

from mr_suspension.identification import cli as diag_cli
from mr_suspension.identification import data as dataio
from mr_suspension.identification import engine
from mr_suspension.identification.pipeline import diagnose_to_dir
from mr_suspension.sim.config import load_driver


def _row(name, base, ext, ref):
    def f(x):
        return '-' if x is None else f'{x:.4f}'
    return f'| {name} | {f(base)} | {f(ext)} | {f(ref)} |'


def main():
    """Run the benchmark and print its table."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--subset', choices=('demo', 'all'), default='all',
                    help='the six sine tests of the demo, or all 30 (default)')
    ap.add_argument('--vrths', default=None, help='vrths data folder')
    ap.add_argument('--out', default=None, help='report folder (default: a temporary one)')
    args = ap.parse_args()
    d = diag_cli.find_vrths(args.vrths)
    if d is None:
        raise SystemExit('no vrths data: give --vrths DIR')
    sine = sorted((d / 'preprocessed_sine').glob('*.txt'))
    if args.subset == 'demo':
        sine = [p for p in sine if p.stem in diag_cli.DEMO_TESTS]
    quake = [str(d / 'validation' / 'validacion.mat')]
    out = args.out or tempfile.mkdtemp(prefix='bench_vrths_')
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        rep, _, _ = diagnose_to_dir([str(p) for p in sine], out, dataio.LoadOptions(),
                                    engine.ALL_EFFECTS, 5, load_driver('wonder_box'), quake,
                                    make_plots=False)
    wall = time.perf_counter() - t0
    ho = rep['heldout']
    ref = rep.get('reference') or {}
    v = rep['validation']
    print(f'vrths: {len(sine)} sine tests diagnosed, earthquake record validated; '
          f'{wall:.1f} s wall; report in {out}')
    print()
    print('| figure (NRMSE) | baseline | extended | learned reference |')
    print('|---|---|---|---|')
    for key, what in (('outer_blocks', 'outer blocks'), ('forward', 'kept-back records')):
        if key in ho:
            print(_row(what, ho[key]['baseline_nrmse'], ho[key]['extended_nrmse'],
                       ref.get(f'{key}_nrmse')))
    print(_row(f'headline ({ho.get("headline", "outer")})', rep['baseline']['heldout_nrmse'],
               rep['extended']['heldout_nrmse'], ref.get('heldout_nrmse')))
    print(_row('earthquake record, as selected', v['baseline_nrmse'], v['selected_nrmse'],
               v.get('reference_nrmse')))
    print(_row(f'earthquake record, handed on ({v["model"]}, cross-fitted)',
               v['baseline_nrmse'], v['extended_nrmse'], None))
    print()
    print(f'gain on the sine tests {rep["gain"]:.1%}; on the earthquake record '
          f'{v["selected_gain"]:.1%} as selected, {v["gain"]:.1%} handed on (the halves chose '
          f'{v["choices"][0]} and {v["choices"][1]}); {100 * v["excluded_share"]:.1f} % of '
          'the earthquake samples outside the fitted domain')
    for line in v['domain']:
        print(f'  {line}')
    causes = ', '.join(c['effect'] for c in rep['causes']) or 'none'
    print(f'verdict {rep["verdict"]}; causes {causes}; not transferring '
          f'{", ".join(v["dropped"]) or "none"}')
    for name, n in v['candidates_nrmse'].items():
        print(f'  earthquake, {name}: {n:.4f}')


if __name__ == '__main__':
    main()
