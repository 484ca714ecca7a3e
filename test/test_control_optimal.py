"""LQ gain optimality and the offline semi-active reference (consistency with the simulator)."""

import numpy as np
import pytest
from scipy import linalg

from mr_suspension.control.laws import ControllerParams
from mr_suspension.control.optimal import (lqr_gain, open_loop_cost, quarter_car_matrices,
                                           semi_active_bound)
from mr_suspension.core import road as rd
from mr_suspension.core.metrics import ride_metrics, wk_sos
from mr_suspension.sim import config as cfg
from mr_suspension.sim.simulator import CornerConfig, simulate

CAR = cfg.load_vehicle('seed003_passenger')
PLANT = (CAR.m_s, CAR.m_u, CAR.k_s, CAR.k_t, CAR.c_t)
W = (1.0, 1e3, 1e3, 1e-6)


def _lq_cost(k):
    """H2 cost of u = -K X under white road velocity, from the Lyapunov equation."""
    a, b, e = quarter_car_matrices(*PLANT)
    ca = np.array([[-CAR.k_s / CAR.m_s, 0.0, 0.0, 0.0]])
    da = -1.0 / CAR.m_s
    q = W[0] * ca.T @ ca + np.diag([W[1], 0.0, W[2], 0.0])
    n = W[0] * ca.T * da
    r = W[0] * da * da + W[3]
    k = np.atleast_2d(k)
    acl = a - b @ k
    sigma = linalg.solve_continuous_lyapunov(acl, -e @ e.T)
    weight = q - n @ k - k.T @ n.T + r * k.T @ k
    return float(np.trace(weight @ sigma))


def test_lqr_gain_is_stabilising_and_optimal():
    k = lqr_gain(*PLANT, *W)
    a, b, _ = quarter_car_matrices(*PLANT)
    assert np.all(np.linalg.eigvals(a - b @ k[None, :]).real < 0.0)
    j0 = _lq_cost(k)
    rng = np.random.default_rng(0)
    for _ in range(20):
        assert _lq_cost(k * (1.0 + 0.05 * rng.normal(size=4))) >= j0 * (1.0 - 1e-9)


def test_lqr_bad_inputs():
    with pytest.raises(ValueError):
        lqr_gain(*PLANT, q_acc=1.0, r=0.0)
    with pytest.raises(ValueError):
        quarter_car_matrices(0.0, 40.0, 6000.0, 14000.0, 0.0)


def _config(current=0.0):
    damper = cfg.load_damper('rd1005_bingham')
    ideal = cfg.load_driver('ideal')
    ctrl = ControllerParams(law='constant', current=current).with_plant(CAR, damper, ideal)
    return CornerConfig(car=CAR, damper=damper, driver=ideal, controller=ctrl)


def test_open_loop_cost_matches_simulator():
    road = rd.bump(0.05, 2.0, 10.0, t0=0.1, duration=1.0)
    conf = _config(0.6)
    car_p, law, dp, drv_p, _, _ = conf.arrays()
    sched = np.full(5, 0.6)
    for obj, key in ((0, 'body_acc_rms'), (1, 'body_acc_wk_rms'), (2, 'tyre_load_rms'),
                     (3, 'working_space_rms')):
        val = open_loop_cost(car_p, law, dp, drv_p, sched, 200, road.z, road.zdot, conf.dt,
                             wk_sos(conf.dt), obj, 16)
        assert val == pytest.approx(ride_metrics(simulate(conf, road))[key], rel=1e-9)


def test_semi_active_reference_beats_every_constant_current():
    road = rd.bump(0.05, 2.0, 10.0, t0=0.1, duration=1.0)
    val, sched, tb = semi_active_bound(_config(), road, 'body_acc_rms', block=0.1, maxiter=30)
    assert sched.shape == (10,) and tb.shape == (10,)
    assert np.all((sched >= 0.0) & (sched <= 2.0))
    best = min(ride_metrics(simulate(_config(i), road))['body_acc_rms']
               for i in np.linspace(0.0, 2.0, 9))
    assert val <= best + 1e-9
    with pytest.raises(ValueError):
        semi_active_bound(_config(), road, 'comfort')
    with pytest.raises(ValueError):
        semi_active_bound(_config(), road, x0=np.zeros(3), block=0.1)
