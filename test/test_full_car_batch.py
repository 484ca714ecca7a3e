"""Full-car batch kernel against the one-car simulator: every law, body kind and fallback.

:func:`mr_suspension.sim.full_car_sim.simulate_batch` runs eligible cars on the vectorised
kernel of :mod:`mr_suspension.sim.full_car_batch`, which repeats
:func:`~mr_suspension.sim.full_car_sim.simulate`'s operations in the same order, so its
metrics must equal the recorded run's online sums (``FullCarResult.metrics``) to a relative
1e-9 (in practice bit for bit: the laws that invert the damper model make the closed loop so
sensitive that any other rounding would show at 1e-3).
"""

from dataclasses import replace

import numpy as np
import pytest

from mr_suspension.control.laws import ControllerParams, LAW_IDS
from mr_suspension.control.modal import ModalParams
from mr_suspension.core import car_road as cr
from mr_suspension.core import road as rd
from mr_suspension.core.paramsets import load_full_car
from mr_suspension.sim import config, full_car_batch as fcb
from mr_suspension.sim import full_car_sim as fs

# One worker compiles the full-car kernels (about a minute from a cold cache), not two.
pytestmark = pytest.mark.xdist_group('full_car')

RTOL = 1e-9
CAR = load_full_car('lisa_full_car')
BINGHAM = config.load_damper('rd1005_bingham')
TANH = config.load_damper('seed002_tanh')
LINEAR = config.load_damper('passive_linear')
BOX = config.load_driver('wonder_box')
IDEAL = config.load_driver('ideal')


def _roads(duration=1.5):
    return [cr.iso8608_two_track('C', 15.0, duration, 1e-3, seed=s, track=CAR.track_f,
                                 wheelbase=CAR.wheelbase) for s in (3, 4)]


def _car(law='skyhook', damper=BINGHAM, driver=BOX, **kw):
    return fs.FullCarConfig(car=kw.pop('car', CAR), damper=damper, driver=driver,
                            controller=ControllerParams(law=law, **kw.pop('gains', {})), **kw)


def _assert_same(out, cfgs, roads, idx):
    for c, cfg in enumerate(cfgs):
        ref = fs.simulate(cfg, roads[idx[c]]).metrics()
        for got, want in ((out.body, ref.body), (out.corners, ref.corners)):
            for key in want:
                np.testing.assert_allclose(got[key][c], want[key][0], rtol=RTOL, atol=1e-300,
                                           err_msg=f'car {c} ({cfg.controller.law}): {key}')
        assert out.comfort[c] == pytest.approx(ref.comfort[0], rel=RTOL)


def test_every_law_and_body_in_one_batch_equals_the_one_car_run():
    roads = _roads()
    cfgs = [_car(law) for law in LAW_IDS]
    cfgs += [
        _car('skyhook', modal=ModalParams()),
        _car('skyhook', damper=TANH, modal=ModalParams(c_heave=6000.0)),
        _car('skyhook_onoff', coupled=False),
        _car('clipped_optimal', coupled=False, damper=LINEAR),
        _car('hybrid', control_delay=0.004, gains={'estimation': 'ideal'}),
        _car('groundhook', damper=TANH, driver=IDEAL),
        _car('pdd', damper=LINEAR, control_delay=0.002),
        _car('febc', damper=TANH),
        # Per-corner dampers and drivers: laws and delays differ inside the car.
        _car('skyhook', damper=(BINGHAM, BINGHAM, TANH, TANH), driver=(BOX, BOX, IDEAL, IDEAL)),
        _car('sh_add', damper=(TANH, LINEAR, BINGHAM, TANH)),
    ]
    # A group larger than a chunk (W cars) with another body each: chunking and padding.
    cfgs += [_car('add', car=replace(CAR, i_xx=float(v)))
             for v in np.linspace(110.0, 160.0, fcb.W + 3)]
    idx = np.arange(len(cfgs)) % 2
    assert {fs.kernel_of(c) for c in cfgs} == {'batch'}
    _assert_same(fs.simulate_batch(cfgs, roads, idx), cfgs, roads, idx)


def test_reference_path_and_fallbacks():
    roads = _roads(1.0)
    cfgs = [_car('skyhook_onoff'),
            _car('skyhook', damper=config.load_damper('seed000_mechanical')),
            _car('skyhook', gains={'noise_acc': 0.05}),
            _car('skyhook', modal=ModalParams(law='modal_clipped_optimal')),
            _car('hybrid', modal=ModalParams())]
    kinds = [fs.kernel_of(c) for c in cfgs]
    assert kinds == ['batch', 'reference', 'reference', 'reference', 'batch']
    assert {fs.kernel_of(c, fast=False) for c in cfgs} == {'reference'}
    idx = np.array([0, 1, 0, 1, 1])
    fast = fs.simulate_batch(cfgs, roads, idx)
    slow = fs.simulate_batch(cfgs, roads, idx, fast=False)
    for key in fs.BODY_METRICS:
        np.testing.assert_allclose(fast.body[key], slow.body[key], rtol=RTOL, atol=1e-300)
    for key in fs.CORNER_METRICS:
        np.testing.assert_allclose(fast.corners[key], slow.corners[key], rtol=RTOL,
                                   atol=1e-300)
    _assert_same(fast, cfgs, roads, idx)


def test_metrics_are_physical():
    roads = _roads(1.0)
    cfgs = [_car('constant', gains={'current': i}) for i in (0.0, 1.0)]
    out = fs.simulate_batch(cfgs, roads)
    assert np.all(out.body['heave_acc_rms'] > 0.0)
    assert np.all(out.corners['damper_energy'] > 0.0)
    assert out.body['heave_acc_rms'][1] != out.body['heave_acc_rms'][0]
    assert np.all(out.corners['working_space_peak'] >= out.corners['working_space_rms'])


def test_bad_inputs_are_clear_value_errors():
    roads = _roads(0.5)
    cfg = _car('skyhook')
    with pytest.raises(ValueError, match='at least one'):
        fs.simulate_batch([], roads)
    with pytest.raises(ValueError, match='FullCarConfig'):
        fs.simulate_batch([cfg, 'car'], roads)
    with pytest.raises(ValueError, match='CarRoad'):
        fs.simulate_batch([cfg], [rd.iso8608('C', duration=0.5)])
    with pytest.raises(ValueError, match='road_index'):
        fs.simulate_batch([cfg], roads, road_index=[2])
    with pytest.raises(ValueError, match='road_index'):
        fs.simulate_batch([cfg, cfg], roads, road_index=[0.0, 1.0])
    with pytest.raises(ValueError, match='same length'):
        fs.simulate_batch([cfg], roads + _roads(0.6))
    with pytest.raises(ValueError, match='share dt'):
        fs.simulate_batch([cfg, cfg.replace(dt=2e-3)], roads)
    with pytest.raises(ValueError, match='dt'):
        fs.simulate_batch([cfg.replace(dt=2e-3)], roads)
    with pytest.raises(ValueError, match='filters'):
        fcb.run([cfg], np.zeros(1, dtype=np.int64), np.stack([r.z for r in roads]),
                np.stack([r.zdot for r in roads]), 1e-3, fs._wk(1e-3)[:3], fs._we(1e-3))
