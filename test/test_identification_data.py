"""Loaders, column/unit mapping and bad-input handling of the identification package."""

from pathlib import Path
import warnings

import numpy as np
import pytest
import truthcases

from mr_suspension.identification import data as dataio

SHARED = Path(__file__).resolve().parents[1].parent / 'shared'
VRTHS = SHARED / 'data' / 'vrths'


def _table(n=2000, dt=1e-3):
    t = np.arange(n) * dt
    x = 0.01 * np.sin(2 * np.pi * 2 * t)
    v = np.gradient(x, dt)
    f = 2000 * v + 300 * np.tanh(v / 0.01)
    i = np.where(t % 0.5 < 0.25, 0.8, 0.2)
    return t, x, v, f, i


def _csv(path, header, cols):
    np.savetxt(path, np.column_stack(cols), delimiter=',', header=','.join(header),
               comments='')
    return path


def test_csv_with_mapping_and_units(tmp_path):
    t, x, v, f, i = _table()
    p = _csv(tmp_path / 'r.csv', ['t_ms', 'stroke_mm', 'F_kN', 'I'],
             [t * 1e3, x * 1e3, f * 1e-3, i])
    opts = dataio.LoadOptions(
        columns=dataio.parse_mapping(['time=t_ms,displacement=stroke_mm', 'force=F_kN',
                                      'current_command=I'], 'c'),
        units=dataio.parse_mapping(['time=ms,displacement=mm,force=kN'], 'u'))
    (rec,) = dataio.load_records([p], opts)
    assert rec.dt == pytest.approx(1e-3)
    np.testing.assert_allclose(rec.force, f, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(rec.displacement, x, atol=1e-9)
    assert rec.velocity_source.startswith('derived')
    inner = slice(50, -50)
    assert np.max(np.abs(rec.velocity[inner] - v[inner])) < 0.01 * np.max(np.abs(v))
    assert rec.input_kind == 'current_command'


def test_voltage_command_and_measured_current(tmp_path):
    t, x, v, f, i = _table()
    volt = 0.5 + i / 0.5
    p = _csv(tmp_path / 'v.csv', ['time', 'displacement', 'force', 'voltage_command'],
             [t, x, f, volt])
    (rec,) = dataio.load_records([p])
    assert rec.input_kind == 'voltage_command'
    assert np.all(np.diff(np.unique(np.round(rec.i_in, 6))) > 0)
    p = _csv(tmp_path / 'c.csv', ['time', 'displacement', 'force', 'current_command',
                                  'current'], [t, x, f, i, 0.9 * i])
    (rec,) = dataio.load_records([p])
    assert rec.input_kind == 'current'
    np.testing.assert_allclose(rec.i_in, 0.9 * i)


@pytest.mark.parametrize('case, match', [
    ('missing', 'missing column'),
    ('no_current', 'current_command'),
    ('nan_many', 'NaN'),
    ('backwards', 'strictly increasing'),
    ('short', 'too short'),
    ('mm_as_m', 'units displacement=mm'),
    ('velocity_units', 'check --units'),
    ('unknown_unit', 'unit'),
])
def test_bad_input_gives_clear_errors(tmp_path, case, match):
    t, x, v, f, i = _table()
    header = ['time', 'displacement', 'velocity', 'force', 'current_command']
    cols = [t, x, v, f, i]
    units = {}
    if case == 'missing':
        header[3] = 'Kraft'
    elif case == 'no_current':
        header[4] = 'amps'
    elif case == 'nan_many':
        cols[3] = f.copy()
        cols[3][::20] = np.nan
    elif case == 'backwards':
        cols[0] = t.copy()
        cols[0][500] = cols[0][498]
    elif case == 'short':
        cols = [c[:150] for c in cols]
    elif case == 'mm_as_m':
        cols[1] = x * 1e3
        cols[2] = v * 1e3
    elif case == 'velocity_units':
        cols[2] = v * 1e3
    elif case == 'unknown_unit':
        units = {'force': 'lbf'}
    p = _csv(tmp_path / 'bad.csv', header, cols)
    with pytest.raises(dataio.DataError, match=match):
        dataio.load_records([p], dataio.LoadOptions(units=units))


def test_warnings_for_patchable_problems(tmp_path):
    t, x, v, f, i = _table()
    f2 = f.copy()
    f2[100] = np.nan
    p = _csv(tmp_path / 'nan.csv', ['time', 'displacement', 'force', 'current_command'],
             [t, x, f2, i])
    with pytest.warns(UserWarning, match='interpolated'):
        (rec,) = dataio.load_records([p])
    assert np.all(np.isfinite(rec.force))
    p = _csv(tmp_path / 'kn.csv', ['time', 'displacement', 'force', 'current_command'],
             [t, x, f * 1e-3, i])
    with pytest.warns(UserWarning, match='kN'):
        dataio.load_records([p])
    with pytest.raises(dataio.DataError, match='header'):
        np.savetxt(tmp_path / 'nohead.csv', np.column_stack([t, x, f, i]), delimiter=',')
        dataio.load_records([tmp_path / 'nohead.csv'])
    with pytest.raises(dataio.DataError, match='no such file'):
        dataio.load_records([tmp_path / 'absent.csv'])


def test_vrths_files_load_through_the_same_path():
    (rec,) = dataio.load_records([VRTHS / 'preprocessed_sine' / '10mm1Hz0x25A.txt'])
    assert rec.dt == pytest.approx(1e-3)
    assert np.all(rec.i_in == 0.25)
    assert 0.009 < np.max(np.abs(rec.displacement)) < 0.011
    assert rec.meta['frequency_hz'] == 1.0
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        recs = dataio.load_records([VRTHS / 'validation' / 'validacion.mat'])
    assert [r.i_in[0] for r in recs] == [0.2, 0.4, 0.6, 0.8, 1.0]
    assert all(r.n == 64648 and r.velocity_source.startswith('derived') for r in recs)


def test_rosbag2_round_trip(tmp_path):
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import get_typestore, Stores

    ts = get_typestore(Stores.LATEST)
    Float64 = ts.types['std_msgs/msg/Float64']
    t, x, v, f, i = _table(1500)
    bag = tmp_path / 'bag'
    with Writer(bag, version=9) as w:
        conns = {name: w.add_connection(name, Float64.__msgtype__, typestore=ts)
                 for name in ('/damper/stroke', '/damper/force', '/damper/current_command',
                              '/damper/current')}
        for k in range(t.size):
            stamp = int(1e9 + t[k] * 1e9)
            for name, val in (('/damper/stroke', x[k]), ('/damper/force', f[k]),
                              ('/damper/current_command', i[k]),
                              ('/damper/current', 0.95 * i[k])):
                w.write(conns[name], stamp, ts.serialize_cdr(Float64(data=float(val)),
                                                             Float64.__msgtype__))
    (rec,) = dataio.load_records([bag])
    assert rec.n == t.size
    np.testing.assert_allclose(rec.force, f, atol=1e-6)
    assert rec.input_kind == 'current'
    np.testing.assert_allclose(rec.command, i)


def test_driver_identified_from_measured_current():
    """The truth rig's driver (a 3.4 ms dead time, rise and fall lags 8.7 and 23 ms).

    Measured coil current (with its own noise) and command: the driver's dead time within a
    sample, its lags within 20 %. Without the coil current there is no driver to identify.
    """
    from mr_suspension.identification import diagnose

    case = truthcases.case(28005, ('current_delay', 'current_lag_asymmetric'),
                           strength={'current_delay': 0.3, 'current_lag_asymmetric': 0.15},
                           current_site='driver', driver_tau=0.0, measured_current=True,
                           sensor_faults=(), duration=8.0)
    tr = case.truth
    assert tr.tau_rise > 3e-3 and tr.tau_fall > 3e-3
    drv = diagnose.identify_driver([truthcases.record(case.columns)])
    assert drv['dead_time'] == pytest.approx(tr.dead_time, abs=1e-3)
    assert drv['tau_rise'] == pytest.approx(tr.tau_rise, rel=0.2)
    assert drv['tau_fall'] == pytest.approx(tr.tau_fall, rel=0.2)
    cols = {k: v for k, v in case.columns.items() if k != 'current'}
    assert diagnose.identify_driver([truthcases.record(cols)]) is None


def _lag(u, dt, tau):
    """First-order lag settled at ``u[0]``, exact for a held input (scipy, not the engine)."""
    from scipy import signal

    a = np.exp(-dt / tau)
    return signal.lfilter([0.0, 1.0 - a], [1.0, -a], u, zi=[u[0]])[0]


def test_measured_current_noise_is_cleaned_by_the_command_through_the_driver():
    from mr_suspension.identification import diagnose

    rec = truthcases.record(truthcases.case(28100, (), sensor_faults=(), duration=10.0,
                                            measured_current=False).columns)
    dt, cmd = rec.dt, rec.i_in
    rng = np.random.default_rng(8)
    noise = 0.005  # [A] white
    # Dead time 3 ms and a 6 ms lag, written apart from the engine.
    coil = np.r_[np.full(3, cmd[0]), _lag(cmd, dt, 0.006)[:-3]]
    cols = {'time': rec.time, 'displacement': rec.displacement, 'velocity': rec.velocity,
            'force': rec.force, 'current_command': cmd,
            'current': coil + noise * rng.standard_normal(cmd.size)}
    meas = dataio.build_record('noisy-coil', cols)
    drv = diagnose.identify_driver([meas])
    clean = diagnose.denoise_current(meas, drv)
    assert clean.meta['current_source'].startswith('measured coil current fused with the command')
    assert np.std(clean.i_in - coil) < 0.2 * noise
    # A saved model carries the driver, and predict cleans a new record's current the same way.
    from mr_suspension.core.extended import ExtendedDamperParams
    from mr_suspension.identification import engine, model_io

    params = ExtendedDamperParams(c0=800.0, c1=900.0, fy0=50.0, fy1=600.0, v_y=0.01)
    dyn = {'dead_time': 0.0, 'tau_rise': 0.0, 'tau_fall': 0.0}
    model = model_io.model_dict(params, dyn, (), 'current', extra={'driver': drv})
    np.testing.assert_array_equal(model_io.predict(model, meas),
                                  engine.simulate(clean, params, dyn))
    assert not np.array_equal(engine.simulate(meas, params, dyn),
                              engine.simulate(clean, params, dyn))
    # A driver the model cannot draw (two lags in series): the difference's band widens and
    # the result is still closer to the coil current than the measurement.
    coil2 = _lag(_lag(cmd, dt, 0.004), dt, 0.004)
    cols2 = dict(cols, current=coil2 + noise * rng.standard_normal(cmd.size))
    meas2 = dataio.build_record('two-lag-coil', cols2)
    clean2 = diagnose.denoise_current(meas2, diagnose.identify_driver([meas2]))
    assert np.std(clean2.i_in - coil2) < 0.8 * np.std(meas2.i_in - coil2)
    # Nothing to do: no measured current, no driver, or a noise-free coil current.
    assert diagnose.denoise_current(rec, drv) is rec
    assert diagnose.denoise_current(meas, None) is meas
    exact = dataio.build_record('exact-coil', dict(cols, current=coil))
    assert diagnose.denoise_current(exact, diagnose.identify_driver([exact])) is exact


def test_rosbag2_from_node_set_topics(tmp_path):
    """Read stroke/force JointState topics as the node set records them; ignore truth."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import get_typestore, Stores

    ts = get_typestore(Stores.LATEST)
    js = ts.types['sensor_msgs/msg/JointState']
    hdr = ts.types['std_msgs/msg/Header']
    stamp_t = ts.types['builtin_interfaces/msg/Time']
    f64 = ts.types['std_msgs/msg/Float64']
    t, x, v, f, i = _table(1200)
    bag = tmp_path / 'nodes'
    with Writer(bag, version=9) as w:
        cs = {n: w.add_connection(n, ty.__msgtype__, typestore=ts) for n, ty in (
            ('/mr/stroke', js), ('/mr/damper/force', js), ('/mr/current_command', f64),
            ('/mr/coil_current', f64), ('/mr/truth/tyre_force', f64))}
        for k in range(t.size):
            ns = int(5e9 + t[k] * 1e9)
            h = hdr(stamp=stamp_t(sec=ns // 10 ** 9, nanosec=ns % 10 ** 9), frame_id='s')
            msgs = (('/mr/stroke', js(header=h, name=['s'], position=np.array([x[k]]),
                                      velocity=np.array([v[k]]), effort=np.array([])), js),
                    ('/mr/damper/force', js(header=h, name=['d', 't'],
                                            position=np.array([x[k], 0.0]),
                                            velocity=np.array([v[k], 0.0]),
                                            effort=np.array([f[k], 1.0])), js),
                    ('/mr/current_command', f64(data=float(i[k])), f64),
                    ('/mr/coil_current', f64(data=float(i[k])), f64),
                    ('/mr/truth/tyre_force', f64(data=1e6), f64))
            for name, msg, ty in msgs:
                w.write(cs[name], ns, ts.serialize_cdr(msg, ty.__msgtype__))
    (rec,) = dataio.load_records([bag])
    assert rec.n == t.size
    np.testing.assert_allclose(rec.force, f, atol=1e-6)
    np.testing.assert_allclose(rec.displacement, x, atol=1e-12)
    np.testing.assert_allclose(rec.velocity, v, atol=1e-9)
    assert rec.velocity_source == 'measured' and rec.input_kind == 'current'


def test_time_in_ms_is_converted_with_a_warning_or_refused(tmp_path):
    t, x, v, f, i = _table(3000)
    p = _csv(tmp_path / 'ms.csv', ['time', 'displacement', 'force', 'current_command'],
             [t * 1e3, x, f, i])
    with pytest.warns(UserWarning, match='time taken as ms'):
        (rec,) = dataio.load_records([p])
    assert rec.dt == pytest.approx(1e-3) and rec.duration == pytest.approx(3.0)
    with pytest.raises(dataio.DataError, match='units time=ms'):
        dataio.load_records([p], dataio.LoadOptions(units={'time': 's'}))


@pytest.mark.parametrize('what', ['still', 'noise_only'])
def test_no_motion_is_an_error(tmp_path, what):
    t, x, v, f, i = _table()
    rng = np.random.default_rng(0)
    x = np.zeros_like(t) if what == 'still' else 5e-6 * rng.standard_normal(t.size)
    f = 50 + rng.standard_normal(t.size)
    p = _csv(tmp_path / 'still.csv', ['time', 'displacement', 'force', 'current_command'],
             [t, x, f, i])
    with pytest.raises(dataio.DataError, match='no motion'):
        dataio.load_records([p])


def test_one_huge_force_value_is_excluded_not_fatal(tmp_path):
    t, x, v, f, i = _table()
    f2 = f.copy()
    f2[700] = 1e300
    p = _csv(tmp_path / 'huge.csv', ['time', 'displacement', 'force', 'current_command'],
             [t, x, f2, i])
    with pytest.warns(UserWarning, match='non-physical'):
        (rec,) = dataio.load_records([p])
    assert np.all(np.isfinite(rec.force)) and np.max(np.abs(rec.force)) < 1.01 * np.max(np.abs(f))
    e = rec.velocity_edge
    assert np.flatnonzero(~rec.mask[e:rec.n - e]).tolist() == [700 - e]
    assert np.isfinite(np.std(rec.force[rec.mask]))


def test_headers_with_case_and_units_are_mapped(tmp_path):
    t, x, v, f, i = _table()
    p = _csv(tmp_path / 'caps.csv', ['Time [s]', 'Displacement (mm)', 'Velocity_mm_s', 'Force_N',
                                     'Current_Command'], [t, x * 1e3, v * 1e3, f, i])
    (rec,) = dataio.load_records([p])
    np.testing.assert_allclose(rec.displacement, x, atol=1e-12)
    np.testing.assert_allclose(rec.force, f)
    assert rec.velocity_source == 'measured'
    p = _csv(tmp_path / 'lbf.csv', ['time', 'displacement', 'Force [lbf]', 'current_command'],
             [t, x, f, i])
    with pytest.raises(dataio.DataError, match='lbf'):
        dataio.load_records([p])
    p = _csv(tmp_path / 'two.csv', ['time', 'displacement', 'Force', 'force_N',
                                    'current_command'], [t, x, f, f, i])
    (rec,) = dataio.load_records([p])     # the exact name wins over name_unit
    p = _csv(tmp_path / 'dup.csv', ['time', 'displacement', 'Force', 'FORCE',
                                    'current_command'], [t, x, f, f, i])
    with pytest.raises(dataio.DataError, match='--columns force='):
        dataio.load_records([p])


def _model_file(tmp_path):
    from mr_suspension.core.extended import ExtendedDamperParams
    from mr_suspension.identification import model_io

    params = ExtendedDamperParams(f0=0.0, c0=800.0, c1=1200.0, fy0=80.0, fy1=600.0, v_y=0.01)
    path = tmp_path / 'model.json'
    model_io.save_model(path, model_io.model_dict(
        params, {'dead_time': 0.0, 'tau_rise': 0.0, 'tau_fall': 0.0}, (), 'current_command'))
    return path, params


@pytest.mark.parametrize('stamps', ['rounded_3khz', 'missing_rows'])
def test_predict_writes_rows_at_the_input_stamps(tmp_path, stamps):
    """Capitalised header, no force column; rows come back at the input's own times."""
    from mr_suspension.identification import cli

    model, _ = _model_file(tmp_path)
    n = 9000
    if stamps == 'rounded_3khz':
        t = np.round(5.0 + np.arange(n) / 3000.0, 4)
    else:
        t = np.delete(np.arange(n) * 1e-3, np.r_[2000:2003, 7000])
    x = 0.01 * np.sin(2 * np.pi * 1.5 * t)
    i = np.full(t.size, 0.6)
    p = _csv(tmp_path / 'in.csv', ['Time', 'Displacement', 'Current_Command'], [t, x, i])
    out = tmp_path / 'pred.csv'
    assert cli.main(['predict', '--model', str(model), str(p), '--out', str(out)]) == 0
    got = np.loadtxt(out, delimiter=',', skiprows=1)
    assert got.shape == (t.size, 2)
    np.testing.assert_allclose(got[:, 0], t - t[0], atol=1e-9)
    # truth independent of the loader: the law on the exact motion at those stamps
    vt = 0.01 * 2 * np.pi * 1.5 * np.cos(2 * np.pi * 1.5 * t)
    inner = slice(200, -200)
    ref = 800 * vt + 1200 * 0.6 * vt + (80 + 600 * 0.6) * np.tanh(vt / 0.01)
    assert np.max(np.abs(got[inner, 1] - ref[inner])) < 0.02 * np.max(np.abs(ref))


def test_unreadable_bags_are_one_line_errors(tmp_path):
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import get_typestore, Stores

    empty_meta = tmp_path / 'meta'
    empty_meta.mkdir()
    (empty_meta / 'metadata.yaml').write_text('')
    with pytest.raises(dataio.DataError, match='bag repair') as exc:
        dataio.load_records([empty_meta])
    assert '\n' not in str(exc.value)
    ts = get_typestore(Stores.LATEST)
    f64 = ts.types['std_msgs/msg/Float64']
    empty = tmp_path / 'empty'
    with Writer(empty, version=9) as w:
        w.add_connection('/damper/force', f64.__msgtype__, typestore=ts)
    with pytest.raises(dataio.DataError, match='no messages'):
        dataio.load_records([empty])
    good = tmp_path / 'good'
    t, x, v, f, i = _table(800)
    with Writer(good, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        cs = {n: w.add_connection(n, f64.__msgtype__, typestore=ts)
              for n in ('/damper/stroke', '/damper/force', '/damper/current_command')}
        for k in range(t.size):
            for name, val in (('/damper/stroke', x[k]), ('/damper/force', f[k]),
                              ('/damper/current_command', i[k])):
                w.write(cs[name], int(1e9 + t[k] * 1e9),
                        ts.serialize_cdr(f64(data=float(val)), f64.__msgtype__))
    (mcap,) = good.glob('*.mcap')
    data = mcap.read_bytes()
    mcap.write_bytes(data[:len(data) // 2])
    with pytest.raises(dataio.DataError, match=f'bag repair {good}'):
        dataio.load_records([good])
    (good / 'metadata.yaml').unlink()
    with pytest.raises(dataio.DataError, match='bag repair'):
        dataio.load_records([good])


def test_fast_and_slow_text_readers_agree_on_vrths():
    path = VRTHS / 'preprocessed_sine' / '5mm3Hz0x5A.txt'
    header, fast = dataio._read_table(path)
    slow = dataio._read_table_slow(path, None, None, 0)
    assert header is None
    np.testing.assert_array_equal(fast, slow)
