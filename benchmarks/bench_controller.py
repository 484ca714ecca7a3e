"""Time one controller step of every law (Python call of the jitted step, and inside the loop).

Run: ``.venv/bin/python benchmarks/bench_controller.py [--damper NAME] [--calls N]``.
Prints, per law, the median and 99th percentile of one ``controller_step`` call from Python
(what the controller node pays per sample, measurements changing every call) and the cost per
step inside the jitted simulator loop (total run time of a 20 s ISO road minus the same run with
the constant law, divided by the number of steps).
"""

import argparse
import time

import numpy as np

from mr_suspension.control import laws as L
from mr_suspension.core import road as rd
from mr_suspension.sim import config as cfg
from mr_suspension.sim.simulator import CornerConfig, simulate


def python_call_times(ctrl, calls, rng):
    """Per-call times [s] of ``controller_step`` called from Python with fresh measurements."""
    p = ctrl.to_array()
    s = np.zeros(L.N_CTRL_STATE)
    cid = ctrl.law_id
    meas = rng.normal(0.0, [2.0, 20.0, 0.02, 0.2, 0.2, 0.3, 0.3], size=(calls, L.N_MEAS))
    meas[:, L.M_STROKE_RATE:L.M_VEL_U + 1] = np.nan      # sensors only, as the node sends
    step = L.controller_step
    step(cid, p, s, meas[0], 1e-3)
    out = np.empty(calls)
    clock = time.perf_counter
    for k in range(calls):
        m = meas[k]
        t0 = clock()
        step(cid, p, s, m, 1e-3)
        out[k] = clock() - t0
    return out


def main(argv=None):
    """Print the timing table."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--damper', default='rd1005_bingham', help='inverse/plant damper model')
    ap.add_argument('--vehicle', default='city_car')
    ap.add_argument('--calls', type=int, default=20000)
    args = ap.parse_args(argv)
    car = cfg.load_vehicle(args.vehicle)
    damper = cfg.load_damper(args.damper)
    drv = cfg.load_driver('wonder_box')
    road = rd.iso8608('C', 20.0, duration=20.0, seed=1)
    rng = np.random.default_rng(0)
    base = None
    print(f'damper {args.damper}; {args.calls} Python calls per law; loop: 20 s ISO C road')
    print(f'{"law":16s} {"call median [us]":>17s} {"call p99 [us]":>14s} {"in loop [us]":>13s}')
    for law in sorted(L.LAW_IDS, key=lambda n: L.LAW_IDS[n]):
        ctrl = cfg.configure(law, car, damper, drv)
        t = python_call_times(ctrl, args.calls, rng)
        conf = CornerConfig(car=car, damper=damper, driver=drv, controller=ctrl)
        simulate(conf, road)
        runs = []
        for _ in range(3):
            t0 = time.perf_counter()
            simulate(conf, road)
            runs.append(time.perf_counter() - t0)
        loop = min(runs) / road.n_steps
        if base is None:
            base = loop
        print(f'{law:16s} {1e6 * np.median(t):17.2f} {1e6 * np.percentile(t, 99):14.2f} '
              f'{1e6 * (loop - base):13.3f}')


if __name__ == '__main__':
    main()
