"""Wonder Box driver and MR-fluid dynamics (seed 000 sections 5.2-5.3)."""

import dataclasses
import math

import numpy as np
import pytest

from mr_suspension.core import driver as drv
from mr_suspension.core.driver import (command_voltage, driver_series, driver_state,
                                       driver_step, driver_step_voltage, DriverParams, prepare,
                                       static_current)
from mr_suspension.sim import config

DT = 1e-4


def _step_response(params, i0, i1, n=4000):
    q = prepare(params, DT)
    cmd = np.concatenate([np.full(n, i0), np.full(n, i1)])
    s = driver_state(i0)
    coil = np.empty(cmd.size)
    field = np.empty(cmd.size)
    for k, c in enumerate(cmd):
        coil[k], field[k] = driver_step(q, s, c)
    return coil[n:], field[n:]


def _time_constant(t, y, y0, y1, dead):
    # First-order response after the dead time: y = y1 + (y0 - y1) exp(-(t - dead) / tau).
    frac = (y - y1) / (y0 - y1)
    sel = (t > dead + 2 * DT) & (frac > 0.05) & (frac < 0.9)
    slope = np.polyfit(t[sel] - dead, np.log(frac[sel]), 1)[0]
    return -1.0 / slope


def test_wonder_box_step_up_time_constant_and_dead_time():
    p = config.load_driver('wonder_box')
    coil, field = _step_response(p, 0.0, 1.0)
    t = (np.arange(coil.size) + 1) * DT
    # Dead time: nothing reaches the coil before it.
    first = t[np.argmax(coil > 1e-9)]
    assert first == pytest.approx(p.dead_time + DT, abs=1.5 * DT)
    assert _time_constant(t, coil, 0.0, 1.0, p.dead_time) == pytest.approx(p.tau_rise, rel=0.02)
    # Rising current: no fluid lag (seed 000: "hard to find any dynamics").
    assert np.allclose(field, coil)
    # Table 2 of seed 000: <= 25 ms to 90 % on a 0 -> 1 A step.
    t90 = t[np.argmax(field >= 0.9)]
    assert t90 <= 0.025


def test_falling_current_is_slower_about_25_ms():
    p = config.load_driver('wonder_box')
    coil, field = _step_response(p, 1.0, 0.0)
    t = (np.arange(coil.size) + 1) * DT
    assert _time_constant(t, coil, 1.0, 0.0, p.dead_time) == pytest.approx(p.tau_fall, rel=0.02)
    # Fluid demagnetisation (16 ms) in series: the field falls much slower than the coil,
    # about 25 ms overall (seed 000 section 5.3).
    t37 = t[np.argmax(field <= math.exp(-1.0))]
    assert 0.018 < t37 < 0.030
    rise_coil, rise_field = _step_response(p, 0.0, 1.0)
    t63_rise = t[np.argmax(rise_field >= 1 - math.exp(-1.0))]
    assert t37 > 1.5 * t63_rise


def test_static_map_dead_zone_linear_range_and_saturation():
    p = config.load_driver('wonder_box').to_array()
    assert static_current(p, 0.0) == 0.0
    assert static_current(p, 0.45) == 0.0          # dead zone up to ~0.5 V
    volts = np.linspace(0.0, 5.0, 501)
    cur = np.array([static_current(p, v) for v in volts])
    assert np.all(np.diff(cur) >= 0.0)             # monotone
    assert cur.max() <= 2.0                        # saturates below 2 A
    lin = (volts > 0.6) & (volts < 2.5)
    slope = np.polyfit(volts[lin], cur[lin], 1)[0]
    assert slope == pytest.approx(0.5, rel=0.02)   # nearly linear gain
    assert static_current(p, 12.0) == static_current(p, 5.0)  # input clamped to v_max


def test_command_voltage_inverts_the_static_map():
    p = config.load_driver('wonder_box').to_array()
    for i in np.linspace(0.01, 1.8, 40):
        assert static_current(p, command_voltage(p, i)) == pytest.approx(i, rel=1e-9)
    assert command_voltage(p, -1.0) == 0.0
    assert command_voltage(p, float('nan')) == 0.0


def test_invalid_commands_give_zero_or_saturate():
    params = config.load_driver('wonder_box')
    q = prepare(params, 1e-3)
    coil, field = driver_series(q, np.array([np.nan] * 50 + [-3.0] * 50 + [50.0] * 200))
    assert np.all(np.isfinite(coil)) and np.all(np.isfinite(field))
    assert coil[:100].max() == 0.0
    assert coil[-1] == pytest.approx(params.i_range, rel=1e-3)


def test_voltage_input_path():
    params = config.load_driver('ideal')
    q = prepare(params, 1e-3)
    s = driver_state()
    coil, field = driver_step_voltage(q, s, 2.5)
    assert coil == pytest.approx(static_current(params.to_array(), 2.5))


def test_bad_driver_parameters_raise():
    with pytest.raises(ValueError, match='tau_rise'):
        DriverParams(tau_rise=-0.001)
    with pytest.raises(ValueError, match='v_max'):
        DriverParams(v_dead=6.0, v_max=5.0)
    with pytest.raises(ValueError, match='dead_time'):
        DriverParams(dead_time=1.0)
    with pytest.raises(ValueError, match='exceeds'):
        prepare(DriverParams(dead_time=0.2), 1e-4)


@pytest.mark.parametrize('dead_time', [0.0, 0.001, 0.003, 0.005])
def test_field_ahead_equals_the_field_that_comes(dead_time):
    """Within the dead time the future field is already decided: prediction is exact."""
    base = config.load_driver('wonder_box')
    q = drv.prepare(dataclasses.replace(base, dead_time=dead_time), 1e-3)
    nd = int(q[drv.Q_NDEAD])
    s = drv.driver_state(0.0)
    rng = np.random.default_rng(4)
    n = 600
    fields = np.zeros(n)
    ahead = {}
    for k in range(n):
        _, fields[k] = drv.driver_output(q, s)
        for d in range(1, 4):
            ahead[(k, d)] = drv.driver_field_ahead(q, s, d)
        assert drv.driver_field_ahead(q, s, 0) == fields[k]
        drv.driver_input(q, s, drv.clip_command(q, rng.choice([0.0, 0.3, 1.0, 2.0])))
    for (k, d), value in ahead.items():
        if k + d < n:
            exact = min(d, max(nd - 1, 0))
            if d == exact:
                assert value == pytest.approx(fields[k + d], abs=1e-15), (k, d)
            elif nd <= 1:
                assert value == fields[k]  # nothing decided beyond the present sample
