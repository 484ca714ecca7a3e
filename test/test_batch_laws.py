"""Batch kernels against the one-corner simulator: every control law, driver and damper law.

The exact kernel (:func:`mr_suspension.sim.batch.run_exact`) must give what
:func:`~mr_suspension.sim.simulator.simulate` gives corner by corner: metrics and time
histories to a relative 1e-9 (it runs the same operations in the same order, so in practice
bit for bit).
"""

import numpy as np
import pytest
from scipy import signal

from mr_suspension.control import inverse as inv
from mr_suspension.control.laws import ControllerParams
from mr_suspension.core import road as rd
from mr_suspension.core.metrics import wk_sos
from mr_suspension.sim import batch, config
from mr_suspension.sim.simulator import (BATCH_METRICS, CHANNELS, CornerConfig, kernel_of,
                                         simulate, simulate_batch)

RTOL = 1e-9
CAR = config.load_vehicle('city_car')
LAWS = config.available('controllers')


def _corner(law, damper='rd1005_bingham', driver='wonder_box', delay=0.0, **gains):
    dm = config.load_damper(damper)
    drv = config.load_driver(driver)
    ctrl = config.load_controller(law).with_plant(CAR, dm, drv)
    if gains:
        ctrl = ctrl.replace(**gains)
    return CornerConfig(car=CAR, damper=dm, driver=drv, controller=ctrl, control_delay=delay)


def _metrics_of(res):
    """Compute the batch metrics (simulator._metrics_from_acc) from a one-corner run."""
    dt = res.dt
    y = signal.sosfilt(wk_sos(dt), res.a_s)
    v_prev = np.concatenate([[0.0], res.stroke_rate[:-1]])  # stroke rate at each step's start
    return {
        'body_acc_rms': np.sqrt(np.mean(res.a_s ** 2)),
        'body_acc_peak': np.max(np.abs(res.a_s)),
        'body_acc_wk_rms': np.sqrt(np.mean(y ** 2)),
        'vdv': (np.sum(y ** 4) * dt) ** 0.25,
        'working_space_rms': np.sqrt(np.mean(res.stroke ** 2)),
        'working_space_peak': np.max(np.abs(res.stroke)),
        'tyre_load_rms': np.sqrt(np.mean((res.f_t - res.static_tyre_load) ** 2)),
        'ntf_min': np.min(res.f_t),
        'damper_energy': np.sum(res.f_d * v_prev * dt),
    }


def _assert_same(out, configs, roads, idx, data=True):
    for c, cfg in enumerate(configs):
        res = simulate(cfg, roads[idx[c]])
        ref = _metrics_of(res)
        for key in BATCH_METRICS:
            assert out[key][c] == pytest.approx(ref[key], rel=RTOL, abs=1e-12), \
                (cfg.controller.law, cfg.damper.law, key)
        if data:
            scale = np.maximum(np.max(np.abs(res.data), axis=0), 1e-12)
            err = np.max(np.abs(out['data'][c] - res.data), axis=0) / scale
            assert np.all(err <= RTOL), (cfg.controller.law, dict(zip(CHANNELS, err)))


@pytest.mark.parametrize('damper', ['rd1005_bingham', 'seed002_tanh', 'passive_linear'])
def test_every_law_equals_the_one_corner_run(damper):
    roads = [rd.iso8608('C', speed=20.0, duration=2.0, seed=s) for s in range(2)]
    cfgs = []
    for law in LAWS:
        cfgs.append(_corner(law, damper))
        cfgs.append(_corner(law, damper, delay=0.004, estimation='ideal'))
        cfgs.append(_corner(law, damper, driver='ideal', delay=0.002))
        cfgs.append(_corner(law, damper, driver='ideal'))  # no delay at all
    idx = np.arange(len(cfgs)) % 2
    assert {kernel_of(c, record=True) for c in cfgs} == {'exact'}
    _assert_same(simulate_batch(cfgs, roads, idx, record=True), cfgs, roads, idx)
    # Without histories the constant-current corners take the affine kernel: same metrics.
    _assert_same(simulate_batch(cfgs, roads, idx), cfgs, roads, idx, data=False)


def test_inverse_model_of_another_law_and_a_bump():
    # The controller's inverse model differs from the plant damper; a bump drives the end
    # stops and lift-off branches.
    road = [rd.bump(height=0.12, length=1.0, speed=15.0, duration=2.0)]
    cfgs = [_corner(law, 'seed003_bingham', damper_model='seed002_tanh')
            for law in ('skyhook', 'groundhook', 'hybrid', 'pdd', 'clipped_optimal')]
    cfgs += [_corner(law, 'seed002_tanh', damper_model='passive_linear')
             for law in ('skyhook', 'pdd')]
    idx = np.zeros(len(cfgs), dtype=np.int64)
    out = simulate_batch(cfgs, road, idx, record=True)
    assert np.min(out['ntf_min']) == 0.0  # the tyre lifts off on some corner
    _assert_same(out, cfgs, road, idx)


def test_mixed_batch_is_regrouped_and_returned_in_order():
    rng = np.random.default_rng(3)
    roads = [rd.iso8608('D', speed=25.0, duration=1.5, seed=s) for s in range(3)]
    pool = [_corner(law, damper, delay=d) for law in LAWS
            for damper in ('rd1005_bingham', 'seed002_tanh') for d in (0.0, 0.003)]
    pool.append(_corner('skyhook', 'seed000_mechanical'))  # stateful law: generic kernel
    pool.append(_corner('skyhook_onoff', noise_acc=0.05))  # sensor noise: generic kernel
    cfgs = [pool[j] for j in rng.integers(0, len(pool), 90)] + pool[-2:]
    idx = rng.integers(0, len(roads), len(cfgs))
    kinds = {kernel_of(c) for c in cfgs}
    assert kinds == {'affine', 'exact', 'generic'}
    _assert_same(simulate_batch(cfgs, roads, idx, record=True), cfgs, roads, idx)
    generic = simulate_batch(cfgs, roads, idx, fast=False)
    fast = simulate_batch(cfgs, roads, idx)
    for key in BATCH_METRICS:
        np.testing.assert_allclose(fast[key], generic[key], rtol=RTOL, atol=1e-12)


def test_kernel_choice():
    assert kernel_of(_corner('passive_1A')) == 'affine'
    assert kernel_of(_corner('passive_1A'), record=True) == 'exact'
    assert kernel_of(_corner('skyhook')) == 'exact'
    assert kernel_of(_corner('skyhook'), fast=False) == 'generic'
    assert kernel_of(_corner('skyhook', 'spencer_bouc_wen')) == 'generic'
    assert kernel_of(_corner('skyhook', damper_model='seed000_mechanical')) == 'generic'
    assert kernel_of(_corner('skyhook_onoff', damper_model='seed000_mechanical')) == 'exact'
    assert kernel_of(_corner('add', noise_stroke=1e-4)) == 'generic'


def test_vector_inverse_step_matches_the_scalar_inverse():
    # The kernel's one-step inverse (exact for an affine law) against inverse.semi_active_current
    # on random motions and requests, including saturation, passivity and i_min == i_max.
    dm = config.load_damper('rd1005_bingham')
    p = dm.to_array()
    f_stat = inv.static_force(dm)
    rng = np.random.default_rng(5)
    s = np.zeros(8)
    tmp = np.zeros(8)
    checked = 0
    for _ in range(3000):
        x = rng.normal(0.0, 0.02)
        v = rng.choice([0.0, 1e-5, -1e-5]) if rng.random() < 0.1 else rng.normal(0.0, 0.3)
        f_des = rng.normal(0.0, 800.0) if rng.random() < 0.9 else 0.0
        a, b = sorted(rng.choice([0.0, 0.3, 1.0, 2.0], 2))
        want = inv.semi_active_current(dm.law_id, p, s, tmp, x, v, f_des, f_stat, a, b, 1e-3)
        g_a = batch._bingham(*p, v, a)[0] - f_stat - f_des
        g_b = batch._bingham(*p, v, b)[0] - f_stat - f_des
        ci = batch._illinois_first(g_a, g_b, a, b)
        g_c = batch._bingham(*p, v, ci)[0] - f_stat - f_des
        got, more = batch._illinois_pick(g_a, g_b, g_c, a, b, ci, x, v, f_des)
        if not more:  # otherwise the kernel redoes the lane with the scalar function
            assert got == want
            checked += 1
    assert checked > 2900


def test_bad_input_is_a_clear_value_error():
    roads = [rd.bump(duration=0.5), rd.bump(duration=0.5, height=0.02)]
    cfgs = [_corner('skyhook'), _corner('febc')]
    with pytest.raises(ValueError, match='road_index'):
        simulate_batch(cfgs, roads, [0, 2])
    with pytest.raises(ValueError, match='road_index'):
        simulate_batch(cfgs, roads, [0])
    with pytest.raises(ValueError, match='road_index'):
        simulate_batch(cfgs, roads, [0.0, 1.0])
    with pytest.raises(ValueError, match='road_index'):
        simulate_batch(cfgs, roads, [-1, 0])
    z = roads[0].z.copy()
    z[10] = np.nan
    with pytest.raises(ValueError, match='NaN'):
        simulate_batch(cfgs, [rd.Road('bad', 1e-3, z, roads[0].zdot)])
    with pytest.raises(ValueError, match='same length'):
        simulate_batch(cfgs, [roads[0], rd.bump(duration=0.6)], [0, 1])
    with pytest.raises(ValueError, match='dt'):
        simulate_batch(cfgs, [rd.bump(duration=0.5, dt=2e-3)])
    with pytest.raises(ValueError, match='CornerConfig'):
        simulate_batch([ControllerParams()], roads)
    with pytest.raises(ValueError, match='share dt'):
        simulate_batch([cfgs[0], cfgs[0].replace(dt=2e-3)], roads)
