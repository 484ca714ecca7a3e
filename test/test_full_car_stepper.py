"""The full-car steppers, run in the node set's order, reproduce the offline full-car simulator."""

import math

import numpy as np
import pytest

from mr_suspension.control.laws import ControllerParams
from mr_suspension.control.modal import ModalParams
from mr_suspension.core import car_road as cr
from mr_suspension.sim import config
from mr_suspension.sim import full_car_sim as fs
from mr_suspension.sim.full_car_stepper import FullCarPlantStepper, ModalControllerStepper
from mr_suspension.sim.simulator import CHANNELS
from mr_suspension.sim.stepper import ActuatorStepper, ControllerStepper

ROWS = ('a_s', 'a_u', 'stroke', 'stroke_rate', 'f_d', 'f_t', 'i_cmd', 'i_coil', 'z_s', 'v_s',
        'z_u', 'v_u')


def _config(law, modal=False, damper='rd1005_bingham'):
    car = config.load_full_car('lisa_full_car')
    return fs.FullCarConfig(car=car, damper=config.load_damper(damper),
                            driver=config.load_driver('wonder_box'),
                            controller=ControllerParams(law=law),
                            modal=ModalParams() if modal else None)


def _road(kind, car):
    if kind == 'bump_left':
        return cr.bump(0.04, 1.0, 10.0, t0=0.1, side='left', duration=1.0,
                       track=car.track_f, wheelbase=car.wheelbase)
    return cr.iso8608_two_track('C', 15.0, 1.0, 1e-3, seed=2, track=car.track_f,
                                wheelbase=car.wheelbase)


def run_steppers(cfg, road, split=False):
    """Run the node set's order: measurements, controllers, actuators, plant (simulator rows).

    ``split``: the lock-step actuator's order (force from the commands up to ``k - 1``, then
    command ``k``: equal by the driver's dead time).
    """
    plant = FullCarPlantStepper(cfg, road).warm_up()
    acts = [ActuatorStepper(cfg.corner(i)).warm_up() for i in range(4)]
    if cfg.modal is None:
        ctls = [ControllerStepper(cfg.corner(i)).warm_up() for i in range(4)]
    else:
        modal = ModalControllerStepper(cfg).warm_up()
    coil = [math.nan] * 4
    out = np.zeros((4, road.n_steps, len(CHANNELS)))
    body = np.zeros((road.n_steps, 3))
    while not plant.done:
        meas = [(plant.a_s(i), plant.a_u(i), plant.stroke(i), coil[i]) for i in range(4)]
        if cfg.modal is None:
            cmds = [ctls[i].step(*meas[i]) for i in range(4)]
        else:
            cmds = modal.step(plant.imu(), meas)
        forces, tangents = [], []
        for i in range(4):
            x, v = plant.motion(i)
            if split:
                coil[i], _, f, c_d = acts[i].force(x, v)
                acts[i].command(cmds[i])
            else:
                coil[i], _, f, c_d = acts[i].step(cmds[i], x, v)
            forces.append(plant.coupled(i, f, c_d, v))
            tangents.append(c_d)
        k = plant.k
        plant.step(forces, tangents)
        for i in range(4):
            x, v = plant.motion(i)
            z_s, v_s = plant.body_point(i)
            z_u, v_u = plant.wheel(i)
            row = {'a_s': plant.a_s(i), 'a_u': plant.a_u(i), 'stroke': x, 'stroke_rate': v,
                   'f_d': plant.f_d[i], 'f_t': plant.f_t[i], 'i_cmd': cmds[i],
                   'i_coil': coil[i], 'z_s': z_s, 'v_s': v_s, 'z_u': z_u, 'v_u': v_u}
            for name in ROWS:
                out[i, k, CHANNELS.index(name)] = row[name]
        body[k] = plant.imu()
    return out, body


@pytest.mark.parametrize('law, modal, road, split', [
    ('skyhook_onoff', False, 'bump_left', False),
    ('skyhook_onoff', False, 'iso', True),
    ('groundhook', False, 'iso', False),
    ('skyhook', True, 'bump_left', False),
    ('skyhook', True, 'iso', True),
])
def test_steppers_equal_the_full_car_simulator(law, modal, road, split):
    cfg = _config(law, modal)
    car_road = _road(road, cfg.car)
    ref = fs.simulate(cfg, car_road)
    got, body = run_steppers(cfg, car_road, split)
    for name in ROWS:
        j = CHANNELS.index(name)
        scale = np.abs(ref.corners[:, :, j]).max() + 1e-300
        err = np.abs(got[:, :, j] - ref.corners[:, :, j]).max() / scale
        assert err < 1e-12, (name, err)
    for j, name in enumerate(('a_z', 'w_pitch', 'w_roll')):
        np.testing.assert_allclose(body[:, j], ref.channel(name), rtol=0, atol=1e-12
                                   * (np.abs(ref.channel(name)).max() + 1e-300))
    assert np.abs(ref.channel('w_roll')).max() > 1e-3  # the road excites roll


def test_bad_inputs_are_clear():
    cfg = _config('skyhook')
    car_road = _road('bump_left', cfg.car)
    with pytest.raises(ValueError, match='CarRoad'):
        FullCarPlantStepper(cfg, car_road.corner(0))
    with pytest.raises(ValueError, match='FullCarConfig'):
        FullCarPlantStepper(cfg.corner(0), car_road)
    with pytest.raises(ValueError, match='dt'):
        FullCarPlantStepper(cfg.replace(dt=5e-4), car_road)
    with pytest.raises(ValueError, match='modal'):
        ModalControllerStepper(cfg)
    plant = FullCarPlantStepper(cfg, car_road)
    while not plant.done:
        plant.step([0.0] * 4, [0.0] * 4)
    with pytest.raises(IndexError):
        plant.step([0.0] * 4, [0.0] * 4)
    assert plant.k == car_road.n_steps
