"""Print the ``tune`` figures: wall time of one law over three roads, semi-active vs passive.

Tunes continuous skyhook on the default city-car corner (RD-1005 class Bingham damper, Wonder
Box) over ISO 8608 B at 30 m/s, C at 20 m/s and the 5 cm bump for comfort (Wk RMS) with the
working-space RMS at most 90 % of the 0 A damper's on every road, then prints the wall time and
what the tuned law buys over the best constant current that uses no more working space.
A warm-up tuning run first compiles the kernels (numba caches them per source version).

    .venv/bin/python benchmarks/bench_tune.py [--law skyhook] [--workers N] [--repeats 3]
"""

import argparse
import time

import numpy as np

from mr_suspension.evaluation import tune


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--law', default='skyhook')
    parser.add_argument('--workers', type=int, default=0)
    parser.add_argument('--repeats', type=int, default=3)
    parser.add_argument('--maxiter', type=int, default=25)
    args = parser.parse_args()
    plant = tune.Plant(roads=tune.DEFAULT_ROADS)
    t0 = time.perf_counter()
    tune.study([args.law], plant, maxiter=1, n_passive=11)
    print(f'warm-up (compilation) {time.perf_counter() - t0:.1f} s')
    walls, laws = [], []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        res = tune.study([args.law], plant, maxiter=args.maxiter, workers=args.workers)
        walls.append(time.perf_counter() - t0)
        laws.append(res['tuned'][0])
    t = laws[-1]
    eq = t['equal_space']
    print(f'tune {args.law} over {", ".join(res["roads"])} (workers {args.workers}): '
          f'wall {np.median(walls):.2f} s median of {args.repeats} '
          f'(min {min(walls):.2f}, max {max(walls):.2f}); optimiser {t["wall_s"]:.2f} s, '
          f'{t["evaluations"]} candidates x {len(res["roads"])} roads')
    print('gains: ' + ', '.join(f'{k} {t["default"]["gains"][k]:.4g} -> {v:.4g}'
                                for k, v in t['tuned']['gains'].items()))
    print(f'objective J (road-set mean Wk RMS / 0 A damper): {t["default"]["J"]:.4f} default '
          f'-> {t["tuned"]["J"]:.4f} tuned')
    best = res['best_passive']
    print(f'best passive within the limit: {best["current"]:.3f} A, J {best["J"]:.4f}; '
          f'tuned law vs it: {100.0 * (t["tuned"]["J"] / best["J"] - 1.0):+.1f} %')
    print(f'at equal working space (passive {eq["current"]:.3f} A, no more working space on '
          f'any road): Wk RMS {eq["wk_change_pct"]:+.1f} %, dynamic tyre load '
          f'{eq["tyre_change_pct"]:+.1f} %')
    for name, r in zip(res['roads'], eq['per_road']):
        print(f'  {name}: Wk RMS {r["wk_change_pct"]:+.1f} % vs passive {r["current"]:.3f} A '
              f'(tyre load {r["tyre_change_pct"]:+.1f} %)')


if __name__ == '__main__':
    main()
