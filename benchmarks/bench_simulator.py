"""Benchmark the offline simulator (issues #2 and #14).

Prints, in one run: the real-time factor of one corner with the full damper and driver model
at 1 kHz; then for every control law of ``config/controllers`` the batch throughput in
corner-seconds per second (estimation, Wonder Box, fluid lag and damper in the loop) next to
the one-corner simulator's figure for the same law (its real-time factor is its corner-s/s);
then the affine kernel (constant current) and the generic kernel for reference; then the full
car (7 DOF, :mod:`~mr_suspension.sim.full_car_batch`): for every law and the modal sky-hook the
batch throughput in full-car seconds per second (four corners, each with its law, estimation,
Wonder Box, fluid lag and MR damper, on a two-track road) beside the quarter car's figure.

Targets: >= 2,000x real time for one corner; >= 100,000 corner-seconds per second in batch for
every law; >= 25,000 full-car seconds per second for every law. The machine is shared, so
each figure is the best of ``--repeats`` runs with the range of the others, the load average
is printed before and after, and the batch figure is also given per CPU-second (what one core
does, independent of other tenants' load).
Run: ``.venv/bin/python benchmarks/bench_simulator.py [--duration 10] [--corners 2048]
[--cars 1024]`` (``--cars 0`` skips the full car).
"""

import argparse
from dataclasses import replace
import os
import time

import numpy as np

from mr_suspension.control.laws import ControllerParams
from mr_suspension.control.modal import ModalParams
from mr_suspension.core import car_road as cr, road as rd
from mr_suspension.core.paramsets import load_full_car
from mr_suspension.sim import config, full_car_sim as fs
from mr_suspension.sim.simulator import CornerConfig, kernel_of, simulate, simulate_batch


def timed(fn, repeats):
    """Return (wall times, CPU times) of ``repeats`` calls after one warm-up call."""
    fn()
    walls, cpus = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return np.array(walls), np.array(cpus)


def load():
    """Return the 1-minute load average as text."""
    return f'{os.getloadavg()[0]:.2f}'


def main():
    """Run the benchmark and print its figures."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--duration', type=float, default=10.0, help='simulated seconds per corner')
    ap.add_argument('--corners', type=int, default=2048,
                    help='corners in the batch (0: skip the quarter-car batch)')
    ap.add_argument('--cars', type=int, default=1024, help='full cars in the batch (0: skip)')
    ap.add_argument('--repeats', type=int, default=3)
    ap.add_argument('--laws', nargs='*', default=None, help='controller sets (default: all)')
    args = ap.parse_args()
    car = config.load_vehicle('city_car')
    driver = config.load_driver('wonder_box')
    damper = config.load_damper('rd1005_bingham')
    road = rd.iso8608('C', speed=20.0, duration=args.duration, seed=1)
    print(f'machine: {os.cpu_count()} cores, load average {load()} (1 min); road ISO 8608 C '
          f'at 20 m/s, {args.duration:g} s, dt = 1 ms, Wonder Box driver + fluid lag')
    print('\n== one corner (time histories of 14 channels recorded)')
    for label, dname, ctrl in [
            ('bingham + skyhook', 'rd1005_bingham', 'skyhook_onoff'),
            ('bingham + constant', 'rd1005_bingham', 'passive_1A'),
            ('seed 000 series model', 'seed000_mechanical', 'skyhook_onoff'),
            ('Bouc-Wen (10 substeps)', 'spencer_bouc_wen', 'skyhook_onoff')]:
        cfg = CornerConfig(car=car, damper=config.load_damper(dname), driver=driver,
                           controller=config.load_controller(ctrl))
        el = timed(lambda cfg=cfg: simulate(cfg, road), args.repeats)[0].min()
        print(f'  {label:<26s} {args.duration / el:10.0f} x real time '
              f'({el / road.n_steps * 1e9:6.0f} ns/step)')

    quarter = {}
    if args.corners > 0:
        quarter_car(args, car, driver, damper, road, quarter)
    if args.cars > 0:
        full_car(args, quarter)
    print(f'load average after: {load()}')


def quarter_car(args, car, driver, damper, road, quarter):
    """Print the quarter car's batch throughput per law and the reference kernels."""
    n = args.corners
    roads = [rd.iso8608('C', speed=20.0, duration=args.duration, seed=s) for s in range(4)]
    idx = np.arange(n) % 4
    corner_s = n * args.duration
    print(f'\n== every law: batch of {n} corners x {args.duration:g} s on 4 roads (online '
          f'metrics) against one corner at a time; RD-1005 Bingham damper, Wonder Box')
    print(f'  {"law":<16s} {"kernel":<7s} {"batch corner-s/s":>17s} {"(range)":>17s} '
          f'{"per CPU-s":>10s} {"one corner":>11s} {"ratio":>6s}')
    worst = np.inf
    for law in args.laws or config.available('controllers'):
        ctrl = config.load_controller(law).with_plant(car, damper, driver)
        cfg = CornerConfig(car=car, damper=damper, driver=driver, controller=ctrl)
        one = args.duration / timed(lambda cfg=cfg: simulate(cfg, road), args.repeats)[0].min()
        # Distinct corners (another body mass each), so set-up cost is counted per corner.
        cfgs = [cfg.replace(car=replace(car, m_s=float(m))) for m in np.linspace(200.0, 280.0, n)]
        walls, cpus = timed(lambda cfgs=cfgs: simulate_batch(cfgs, roads, idx), args.repeats)
        rate = corner_s / walls
        worst = min(worst, rate.max())
        quarter[law] = rate.max()
        print(f'  {law:<16s} {kernel_of(cfgs[0]):<7s} {rate.max():17,.0f} '
              f'{rate.min():8,.0f}-{rate.max():<8,.0f} {corner_s / cpus.min():10,.0f} '
              f'{one:11,.0f} {rate.max() / one:5.1f}x')
    print(f'  target >= 100,000 corner-s/s for every law: '
          f'{"met" if worst >= 1e5 else "NOT met"} (slowest law {worst:,.0f})')

    print('\n== reference kernels')
    cfgs = [CornerConfig(car=car, damper=damper, driver=driver,
                         controller=ControllerParams(current=float(i)))
            for i in np.linspace(0.0, 2.0, n)]
    walls, _ = timed(lambda: simulate_batch(cfgs, roads, idx), args.repeats)
    print(f'  affine kernel (constant current, {n} corners): '
          f'{corner_s / walls.min():12,.0f} corner-s/s')
    n_gen = max(8, n // 8)
    sk = [c.replace(controller=config.load_controller('skyhook_onoff')) for c in cfgs[:n_gen]]
    walls, _ = timed(lambda: simulate_batch(sk, roads, idx[:n_gen], fast=False), 1)
    print(f'  generic kernel (on-off skyhook, one corner per thread, {n_gen} corners): '
          f'{n_gen * args.duration / walls.min():12,.0f} corner-s/s')


def full_car(args, quarter):
    """Print the full car's batch throughput per law beside the quarter car's."""
    car = load_full_car('lisa_full_car')
    damper = config.load_damper('rd1005_bingham')
    driver = config.load_driver('wonder_box')
    n = args.cars
    roads = [cr.iso8608_two_track('C', 20.0, args.duration, 1e-3, seed=s, track=car.track_f,
                                  wheelbase=car.wheelbase) for s in range(4)]
    idx = np.arange(n) % 4
    car_s = n * args.duration
    # Distinct cars (another roll inertia each), so the set-up is counted per car.
    cars = [replace(car, i_xx=float(v)) for v in np.linspace(110.0, 160.0, n)]
    print(f'\n== full car (7 DOF, LISA): batch of {n} cars x {args.duration:g} s on 4 two-track '
          f'roads (ISO 8608 C, 20 m/s), four RD-1005 Bingham dampers and Wonder Boxes; load '
          f'{load()}')
    print(f'  {"law":<16s} {"kernel":<9s} {"full-car s/s":>13s} {"(range)":>17s} '
          f'{"per CPU-s":>10s} {"corner-s/s":>11s} {"quarter car":>12s}')
    worst = np.inf
    laws = list(args.laws or config.available('controllers')) + ['modal_skyhook']
    for law in laws:
        modal = ModalParams() if law == 'modal_skyhook' else None
        ctrl = config.load_controller('skyhook' if modal else law)
        cfgs = [fs.FullCarConfig(car=c, damper=damper, driver=driver, controller=ctrl,
                                 modal=modal) for c in cars]
        walls, cpus = timed(lambda cfgs=cfgs: fs.simulate_batch(cfgs, roads, idx),
                            args.repeats)
        rate = car_s / walls
        worst = min(worst, rate.max())
        q = f'{quarter[law]:12,.0f}' if law in quarter else f'{"-":>12s}'
        print(f'  {law:<16s} {fs.kernel_of(cfgs[0]):<9s} {rate.max():13,.0f} '
              f'{rate.min():8,.0f}-{rate.max():<8,.0f} {car_s / cpus.min():10,.0f} '
              f'{4 * rate.max():11,.0f} {q}')
    print(f'  target >= 25,000 full-car s/s for every law: '
          f'{"met" if worst >= 25000 else "NOT met"} (slowest law {worst:,.0f})')
    n_ref = max(4, n // 32)
    ref = [fs.FullCarConfig(car=c, damper=damper, driver=driver,
                            controller=config.load_controller('skyhook_onoff'))
           for c in cars[:n_ref]]
    walls, _ = timed(lambda: fs.simulate_batch(ref, roads, idx[:n_ref], fast=False), 1)
    print(f'  reference loop (on-off skyhook, one car per thread, {n_ref} cars): '
          f'{n_ref * args.duration / walls.min():12,.0f} full-car s/s')


if __name__ == '__main__':
    main()
