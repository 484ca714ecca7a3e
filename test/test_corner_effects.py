"""Corner-level model options of the quarter car: off = unchanged, closed forms, routing, nodes."""

from dataclasses import replace

import numpy as np
import pytest

from mr_suspension.core import road as rd
from mr_suspension.core.quarter_car import (N_STATE, plant_step, strut_extra,
                                            strut_motion, TOP_MOUNT_MASS_FRACTION, VS, VT, VU,
                                            ZS, ZT, ZU)
from mr_suspension.sim import config as cfgmod
from mr_suspension.sim.corner import build_corner
from mr_suspension.sim.simulator import kernel_of, simulate, simulate_batch
from mr_suspension.sim.stepper import ActuatorStepper, PlantStepper

CITY = cfgmod.load_vehicle('city_car')


def _free(car, q0, n, dt, c_lin=0.0, f_d0=0.0):
    """Free response with a linear damper ``F = c_lin v``; returns the states (n+1 x 6)."""
    p = car.to_array(f_d0)
    q = np.zeros(N_STATE)
    q[:len(q0)] = q0
    out = np.empty((n + 1, N_STATE))
    out[0] = q
    for k in range(n):
        v = strut_motion(p, q)[1]
        plant_step(p, q, c_lin * v, c_lin, 0.0, 0.0, dt)
        out[k + 1] = q
    return out


def test_options_off_is_bit_identical():
    """Explicit zero amplitudes (with other inactive shape values) change nothing, bit for bit."""
    base = build_corner('skyhook')
    off = base.replace(car=replace(base.car, f_fric=0.0, v_fric=0.02, x_bs=0.03, k_bs=0.0,
                                   k_s3=0.0, k_tm=0.0, c_tm=0.0))
    assert off.car.options_on == () and base.car.options_on == ()
    road = rd.iso8608(road_class='C', speed=20.0, duration=3.0, seed=4)
    assert np.array_equal(simulate(base, road).data, simulate(off, road).data)
    arr = base.car.to_array(12.5)
    old = [getattr(base.car, f) for f in ('m_s', 'm_u', 'k_s', 'k_t', 'c_t', 'stroke_max',
                                          'stroke_min', 'k_stop', 'g')] + [12.5]
    assert np.array_equal(arr[:10], old) and not arr[[10, 12, 13, 14, 15, 16]].any()
    assert kernel_of(base) == 'exact' and kernel_of(off) == 'exact'


def test_cubic_spring_and_progressive_stop_static_deflection():
    """Static load dF on the strut: k_s x + k_s3 x^3 = dF, and k_s x + k_bs (x - x_bs)^2 = dF."""
    dF = 500.0
    car = replace(CITY, k_s3=5.0e6)
    x = _free(car, (), 6000, 1e-3, c_lin=1500.0, f_d0=dF)
    stroke = x[-1, ZS] - x[-1, ZU]
    roots = np.roots([car.k_s3, 0.0, car.k_s, -dF])
    exact = roots[np.abs(roots.imag) < 1e-12].real.max()
    assert stroke == pytest.approx(exact, rel=1e-6)
    assert stroke < 0.9 * dF / car.k_s  # hardening: less than the linear spring's deflection
    car = replace(CITY, k_bs=2.0e6, x_bs=0.02)
    x = _free(car, (), 6000, 1e-3, c_lin=1500.0, f_d0=dF)
    stroke = x[-1, ZS] - x[-1, ZU]
    roots = np.roots([car.k_bs, car.k_s - 2 * car.k_bs * car.x_bs,
                      car.k_bs * car.x_bs ** 2 - dF])
    exact = roots[(roots.real > car.x_bs)].real.min()
    assert stroke == pytest.approx(exact, rel=1e-6)


def test_option_forces_and_tangents_match_formula():
    car = replace(CITY, k_s3=3.0e6, k_bs=1.5e6, x_bs=0.025, f_fric=60.0, v_fric=0.004)
    p = car.to_array()
    for x in (-0.05, -0.03, -0.01, 0.0, 0.02, 0.04):
        for v in (-0.1, -0.003, 0.0, 0.002, 0.3):
            f, k, c = strut_extra(p, x, v)
            bs = car.k_bs * max(abs(x) - car.x_bs, 0.0) ** 2 * np.sign(x)
            want = car.k_s3 * x ** 3 + bs + car.f_fric * np.tanh(v / car.v_fric)
            assert f == pytest.approx(want, rel=1e-12, abs=1e-9)
            assert car.strut_force(x, v) == pytest.approx(want + car.k_s * x, rel=1e-12,
                                                          abs=1e-9)
            h = 1e-7
            assert k == pytest.approx((strut_extra(p, x + h, v)[0] - strut_extra(p, x - h, v)[0])
                                      / (2 * h), rel=1e-5, abs=1e-3)
            assert c == pytest.approx((strut_extra(p, x, v + h)[0] - strut_extra(p, x, v - h)[0])
                                      / (2 * h), rel=1e-5, abs=1e-3)


def test_coulomb_friction_linear_decay():
    """Free vibration with Coulomb friction: peaks drop by 4 F / k per cycle (not by a ratio)."""
    f = 40.0
    car = replace(CITY, m_u=2.0, k_t=1.0e8, c_t=0.0, f_fric=f, v_fric=1.0e-3)
    dt = 2e-4
    q = _free(car, (0.05,), 15000, dt)
    x = q[:, ZS] - q[:, ZU]
    w = 500  # a sixth of the period: a cycle's peak, not the wheel's ripple on it
    peaks = [x[0]] + [x[k] for k in range(w, x.size - w)
                      if x[k] == x[k - w:k + w + 1].max() and x[k] > 0.01]
    assert len(peaks) >= 3
    drops = np.diff(peaks[:3])
    k_eff = car.k_s * car.k_t / (car.k_s + car.k_t)
    assert np.allclose(-drops, 4.0 * f / k_eff, rtol=0.03)
    # Energy dissipated in a cycle of amplitude X is about 4 F X (work of the friction force).
    e = 0.5 * k_eff * np.array(peaks[:2]) ** 2
    assert e[0] - e[1] == pytest.approx(4.0 * f * 0.5 * (peaks[0] + peaks[1]), rel=0.03)


def test_bump_stop_is_progressive_on_a_bump():
    base = build_corner('passive_0A')
    road = rd.bump(height=0.08, length=1.0, speed=8.0, duration=1.5)
    peaks = []
    for k_bs in (0.0, 2.0e6, 2.0e7):
        c = base.replace(car=replace(base.car, k_bs=k_bs, x_bs=0.02))
        peaks.append(np.abs(simulate(c, road).stroke).max())
    assert peaks[0] > 0.03
    assert peaks[0] > peaks[1] > peaks[2] > 0.02


def _mount_modes(car):
    """Natural frequencies [Hz] and modes of body, strut top and wheel (test's own eigen)."""
    mt = TOP_MOUNT_MASS_FRACTION * car.m_s
    m = np.diag([car.m_s - mt, mt, car.m_u])
    k = np.array([[car.k_tm, -car.k_tm, 0.0],
                  [-car.k_tm, car.k_tm + car.k_s, -car.k_s],
                  [0.0, -car.k_s, car.k_s + car.k_t]])
    w2, vec = np.linalg.eig(np.linalg.solve(m, k))
    order = np.argsort(w2.real)
    return np.sqrt(w2.real[order]) / (2 * np.pi), vec.real[:, order]


def _energy(car, q):
    mt = TOP_MOUNT_MASS_FRACTION * car.m_s
    x = q[:, ZT] - q[:, ZU]
    return (0.5 * (car.m_s - mt) * q[:, VS] ** 2 + 0.5 * mt * q[:, VT] ** 2
            + 0.5 * car.m_u * q[:, VU] ** 2 + 0.5 * car.k_tm * (q[:, ZT] - q[:, ZS]) ** 2
            + 0.5 * car.k_s * x ** 2 + 0.5 * car.k_t * q[:, ZU] ** 2)


def test_top_mount_body_frequency_and_energy():
    car = replace(CITY, c_t=0.0, k_tm=5.0e4)
    freq, vec = _mount_modes(car)
    # Series springs k_s k_tm / (k_s + k_tm) for the body mode, within the node-mass share.
    k_eff = car.k_s * car.k_tm / (car.k_s + car.k_tm)
    series = replace(car, k_s=k_eff, k_tm=0.0).natural_frequencies()[0]
    assert freq[0] == pytest.approx(series, rel=0.02)
    assert freq[0] < 0.95 * replace(car, k_tm=0.0).natural_frequencies()[0]
    mode = vec[:, 0] * 0.01 / vec[0, 0]
    dt = 1e-3
    q = _free(car, (mode[0], mode[2], 0.0, 0.0, mode[1], 0.0), 8000, dt)
    zs = q[:, ZS]
    cross = [k + zs[k] / (zs[k] - zs[k + 1]) for k in range(zs.size - 1)
             if zs[k] > 0.0 >= zs[k + 1]]
    f_meas = (len(cross) - 1) / ((cross[-1] - cross[0]) * dt)
    assert f_meas == pytest.approx(freq[0], rel=1e-3)
    # Undamped: energy kept (trapezoidal rule on a linear system); the mount damper only takes.
    e = _energy(car, q)
    assert np.ptp(e) < 1e-8 * e[0]
    damped = replace(car, c_tm=2000.0)
    qd = _free(damped, (mode[0], mode[2], 0.0, 0.0, mode[1], 0.0), 3000, dt)
    ed = _energy(damped, qd)
    assert np.all(np.diff(ed) <= 1e-12 * ed[0]) and ed[-1] < 0.5 * ed[0]


def test_options_route_to_generic_kernel_and_stepper_matches():
    base = build_corner('passive_1A')
    car = replace(base.car, f_fric=50.0, k_bs=1.0e6, x_bs=0.03, k_s3=1.0e6, k_tm=3.0e5,
                  c_tm=150.0, m_s=125.0)
    c = base.replace(car=car)
    assert set(car.options_on) == {'strut_friction', 'bump_stop', 'spring_nonlinearity',
                                   'top_mount'}
    assert kernel_of(c) == 'generic' and kernel_of(c, record=True) == 'generic'
    road = rd.iso8608(road_class='D', speed=20.0, duration=2.0, seed=2)
    res = simulate(c, road)
    met = simulate_batch([c, base], [road], record=True)
    assert np.array_equal(met['data'][0], res.data)
    assert met['body_acc_rms'][1] == pytest.approx(np.sqrt(np.mean(simulate(base, road).a_s
                                                                   ** 2)), rel=1e-9)
    assert met['body_acc_rms'][0] != pytest.approx(met['body_acc_rms'][1], rel=0.01)
    # The node set's pieces (constant-current law: the command is fixed) give the same run.
    act = ActuatorStepper(c)
    plant = PlantStepper(c, road).warm_up()
    i_cmd = c.controller.current
    acc = []
    while not plant.done:
        _, _, f_d, c_d = act.step(i_cmd, plant.stroke, plant.stroke_rate)
        acc.append(plant.step(f_d, c_d)[0])
    assert np.array_equal(np.array(acc), res.a_s)


def test_option_params_validated_and_loaded_from_yaml(tmp_path):
    for bad in ({'f_fric': -1.0}, {'v_fric': 0.0}, {'k_bs': -5.0}, {'x_bs': -0.01},
                {'k_s3': -1.0}, {'k_tm': 10.0}, {'c_tm': -1.0}, {'c_tm': 100.0},
                {'f_fric': float('nan')}, {'k_tm': 'stiff'}):
        with pytest.raises(ValueError):
            replace(CITY, **bad)
    text = (cfgmod.config_dir() / 'vehicles' / 'city_car.yaml').read_text()
    path = tmp_path / 'hidden.yaml'
    path.write_text(text + 'f_fric: 45.0\nk_tm: 200000.0\nc_tm: 100.0\n')
    car = cfgmod.load_vehicle(str(path))
    assert (car.f_fric, car.k_tm, car.c_tm) == (45.0, 2.0e5, 100.0)
    path.write_text(text + 'k_fric: 45.0\n')
    with pytest.raises(ValueError, match='unknown'):
        cfgmod.load_vehicle(str(path))


def test_node_set_runs_a_hidden_effect_from_a_vehicle_yaml(tmp_path):
    """In-process lock-step node set, plant on a YAML car with hidden effects = offline run."""
    from mr_suspension.nodes.launch import agreement, offline_summary
    from mr_suspension.nodes.testing import run_in_process
    text = (cfgmod.config_dir() / 'vehicles' / 'city_car.yaml').read_text()
    path = tmp_path / 'hidden.yaml'
    path.write_text(text + 'f_fric: 45.0\nk_tm: 300000.0\nc_tm: 150.0\nk_s3: 2000000.0\n')
    road = '{type: bump, height: 0.05, t0: 0.05, speed: 20.0}'
    nodes, counters = run_in_process(road, 0.5, 'skyhook_onoff', True, coupling_delay=0,
                                     vehicle=str(path))
    # Hidden: the controller keeps the nominal car's plant knowledge, only the plant changes.
    nominal = build_corner('skyhook_onoff')
    hidden = nominal.replace(car=cfgmod.load_vehicle(str(path)))
    diffs = agreement(nodes, offline_summary(hidden, road, 0.5))
    assert counters['late_forces'] == 0
    assert all(abs(d) < 1e-6 for d in diffs.values()), diffs
    plain = agreement(nodes, offline_summary(nominal, road, 0.5))
    assert abs(plain['body_acc_rms']) > 1e-3  # the effect is there
