"""Benchmark the offline simulator (issue #2 targets).

Prints the real-time factor of one corner with the full damper and driver model at 1 kHz, and
the batch throughput in corner-seconds per second (vectorised and generic kernels), with ratios
against the single-corner run in the same process.

Targets: >= 2,000x real time for one corner; >= 100,000 corner-seconds per second in batch.
Run: ``.venv/bin/python benchmarks/bench_simulator.py [--duration 60] [--corners 2048]``.
"""

import argparse
import os
import time

import numpy as np

from mr_suspension.control.laws import ControllerParams
from mr_suspension.core import config, road as rd
from mr_suspension.core.simulator import CornerConfig, simulate, simulate_batch


def best_of(fn, repeats):
    """Return the smallest wall time of ``repeats`` calls (after one warm-up call)."""
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main():
    """Run the benchmark and print its figures."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--duration', type=float, default=60.0, help='simulated seconds per corner')
    ap.add_argument('--corners', type=int, default=2048, help='corners in the batch')
    ap.add_argument('--repeats', type=int, default=3)
    args = ap.parse_args()
    car = config.load_vehicle('city_car')
    driver = config.load_driver('wonder_box')
    road = rd.iso8608('C', speed=20.0, duration=args.duration, seed=1)
    print(f'machine: {os.cpu_count()} cores; road ISO 8608 C at 20 m/s, {args.duration:g} s, '
          f'dt = 1 ms, Wonder Box driver + fluid lag')
    print('\n== one corner (time histories of 14 channels recorded)')
    single = {}
    for label, damper, ctrl in [
            ('bingham + skyhook', 'rd1005_bingham', 'skyhook_onoff'),
            ('bingham + constant', 'rd1005_bingham', 'passive_1A'),
            ('seed 000 series model', 'seed000_mechanical', 'skyhook_onoff'),
            ('Bouc-Wen (10 substeps)', 'spencer_bouc_wen', 'skyhook_onoff')]:
        cfg = CornerConfig(car=car, damper=config.load_damper(damper), driver=driver,
                           controller=config.load_controller(ctrl))
        el = best_of(lambda cfg=cfg: simulate(cfg, road), args.repeats)
        single[label] = args.duration / el
        print(f'  {label:<26s} {args.duration / el:10.0f} x real time '
              f'({el / (road.n_steps) * 1e9:6.0f} ns/step)')
    ref = single['bingham + constant']
    print(f'  target >= 2,000x: {"met" if single["bingham + skyhook"] >= 2000 else "NOT met"}')

    print(f'\n== batch of {args.corners} corners (online metrics, 4 roads)')
    roads = [rd.iso8608('C', speed=20.0, duration=args.duration, seed=s) for s in range(4)]
    base = CornerConfig(car=car, damper=config.load_damper('rd1005_bingham'), driver=driver)
    cfgs = [base.replace(controller=ControllerParams(current=float(i)))
            for i in np.linspace(0.0, 2.0, args.corners)]
    idx = np.arange(args.corners) % 4
    corner_s = args.corners * args.duration
    el_fast = best_of(lambda: simulate_batch(cfgs, roads, idx), args.repeats)
    fast = corner_s / el_fast
    print(f'  vectorised kernel (affine-tanh law, constant current): {fast:12.0f} corner-s/s '
          f'= {fast / ref:5.1f}x the single-corner run')
    n_gen = max(8, args.corners // 8)
    sk = [c.replace(controller=config.load_controller('skyhook_onoff')) for c in cfgs[:n_gen]]
    el_gen = best_of(lambda: simulate_batch(sk, roads, idx[:n_gen]), 1)
    gen = n_gen * args.duration / el_gen
    print(f'  generic kernel (skyhook feedback, any law), {n_gen} corners: {gen:12.0f} '
          f'corner-s/s = {gen / single["bingham + skyhook"]:5.1f}x the single-corner run')
    print(f'  target >= 100,000 corner-s/s: {"met" if fast >= 1e5 else "NOT met"}')


if __name__ == '__main__':
    main()
