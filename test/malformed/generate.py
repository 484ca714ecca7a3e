"""Generate the malformed-input corpus: files in a temporary directory plus the command lines.

``generate(root)`` writes every input under ``root`` and returns a list of :class:`Case`:
the ``mr-suspension`` arguments, what a correct program does with it (``expect``) and words of
which the error line must contain at least one (``names``, lower case) so that it names the
problem. Expectations:

- ``'error'``: unusable input; exit code 2 and exactly one ``error:`` line;
- ``'warn'``: usable after a repair; exit 0 with a ``warning:`` line, or a refusal (exit 2);
- ``'any'``: a legitimate variant; exit 0 (no warning needed) or a refusal naming it;
- ``'ok'``: valid control input; exit 0.

The truths (expected behaviours) come from the physics and the file formats, not from the code.
Run as a script to list the cases: ``python test/malformed/generate.py [DIR]``.
"""

from dataclasses import dataclass, field
import json
import math
from pathlib import Path
import sys
import tempfile

import numpy as np
import yaml

RATE = 200.0  # [Hz] records are short (diagnose runs on the loadable ones)
DURATION = 2.5  # [s]
HEADER = ['time', 'displacement', 'velocity', 'force', 'current_command']


@dataclass
class Case:
    """One malformed input and the command line that feeds it to ``mr-suspension``."""

    name: str
    group: str
    argv: list
    expect: str = 'error'
    names: tuple = ()
    note: str = ''
    subprocess: bool = False
    extra: dict = field(default_factory=dict)


def rig_columns(seed=0, rate=RATE, duration=DURATION):
    """Columns of a plausible rig record (SI): sine motion, current steps, Bingham-like force."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(round(duration * rate))) / rate
    x = 0.01 * np.sin(2 * np.pi * 1.5 * t) + 0.004 * np.sin(2 * np.pi * 4.1 * t + 0.3)
    v = np.gradient(x, 1.0 / rate)
    cur = np.where((t % 1.0) < 0.5, 0.2, 0.9)
    f = (400.0 + 1200.0 * cur) * v + (20.0 + 400.0 * cur) * np.tanh(v / 0.02)
    f = f + rng.normal(0.0, 5.0, t.size)
    return {'time': t, 'displacement': x, 'velocity': v, 'force': f, 'current_command': cur}


def write_csv(path, cols, header=None, fmt='%.9g'):
    """Write ``cols`` (dict of equal-length arrays) with a header line."""
    header = header or list(cols)
    table = np.column_stack([np.asarray(cols[k], dtype=float) for k in cols])
    np.savetxt(path, table, delimiter=',', header=','.join(header), comments='', fmt=fmt)
    return path


def _vehicle():
    return {'m_s': 110.0, 'm_u': 18.0, 'k_s': 11000.0, 'k_t': 110000.0, 'c_t': 50.0,
            'stroke_max': 0.07, 'stroke_min': -0.07, 'k_stop': 300000.0, 'g': 9.81}


def _damper():
    return {'law': 'bingham', 'f0': 0.0, 'c0': 400.0, 'c1': 1200.0, 'fc0': 20.0, 'fc1': 400.0,
            'v_y': 0.02}


def _driver():
    return {'v_dead': 0.5, 'gain': 0.5, 'i_max': 2.0, 'knee': 6.0, 'v_max': 5.0,
            'tau_rise': 0.007, 'tau_fall': 0.004, 'dead_time': 0.003, 'fluid_tau_rise': 0.0,
            'fluid_tau_fall': 0.016}


def _controller():
    return {'law': 'skyhook', 'i_min': 0.0, 'i_max': 2.0, 'c_sky': 2000.0,
            'estimation': 'sensors'}


def _model():
    damper = {'law': 'extended', 'f0': 0.0, 'c0': 400.0, 'c1': 1200.0, 'fy0': 20.0,
              'fy1': 400.0, 'v_y': 0.02, 'i_sat': 0.0, 'x_h': 0.0, 'k_series': 0.0,
              'k_gas1': 0.0, 'k_gas2': 0.0, 'kappa': 0.0, 'tau_thermal': 600.0, 'rho': 0.0}
    return {'format': 'mr_suspension.fitted_damper/1', 'damper': damper,
            'current_dynamics': {'dead_time': 0.005, 'tau_rise': 0.01, 'tau_fall': 0.01},
            'input': {'signal': 'current_command', 'map': ''}, 'effects': [], 'fitted_on': []}


class _Builder:
    """Collects cases; every input file goes under ``root``."""

    def __init__(self, root):
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        self.cases = []
        self.base_csv = write_csv(self.root / 'base.csv', rig_columns())

    def out(self, name):
        return str(self.root / 'out' / name)

    def add(self, name, group, argv, expect='error', names=(), note='', **kw):
        self.cases.append(Case(name, group, [str(a) for a in argv], expect,
                               tuple(n.lower() for n in names), note, **kw))

    # -- data records through diagnose -----------------------------------------------------
    def diagnose(self, name, path, expect='error', names=(), note='', opts=()):
        self.add(name, 'data', ['diagnose', path, '--out', self.out(name), '--quiet',
                                '--no-plots', '--effects', 'current_delay', '--folds', '2']
                 + list(opts), expect, names, note)

    def csv(self, name, cols, expect='error', names=(), note='', header=None, opts=()):
        path = write_csv(self.root / f'{name}.csv', cols, header)
        self.diagnose(name, path, expect, names, note, opts)

    def text(self, name, text, expect='error', names=(), note='', suffix='.csv', mode='w'):
        path = self.root / f'{name}{suffix}'
        if mode == 'wb':
            path.write_bytes(text)
        else:
            path.write_text(text, encoding='utf-8')
        self.diagnose(name, path, expect, names, note)

    # -- parameter files through simulate --------------------------------------------------
    def yaml_case(self, name, kind, data, expect='error', names=(), raw=None):
        path = self.root / f'{name}.yaml'
        path.write_text(raw if raw is not None else yaml.safe_dump(data), encoding='utf-8')
        self.add(name, 'yaml', ['simulate', f'--{kind}', path, '--duration', '0.2',
                                '--reference', '', '--out', self.out(name)], expect, names)

    def model(self, name, model, expect='error', names=(), raw=None, cmd='predict'):
        path = self.root / f'{name}.json'
        path.write_text(raw if raw is not None else json.dumps(model), encoding='utf-8')
        if cmd == 'predict':
            argv = ['predict', self.base_csv, '--model', path, '--out',
                    self.root / f'{name}_pred.csv']
        else:
            argv = ['simulate', f'--{cmd}', path, '--duration', '0.2', '--reference', '',
                    '--out', self.out(name)]
        self.add(name, 'model', argv, expect, names)

    def simulate(self, name, opts, expect='error', names=(), **kw):
        self.add(name, 'cli', ['simulate', '--duration', '0.2', '--reference', '', '--out',
                               self.out(name)] + list(opts), expect, names, **kw)


def _data_cases(b):
    base = rig_columns()
    n = base['time'].size

    def cols(**changes):
        c = {k: np.array(v, dtype=float) for k, v in base.items()}
        for k, v in changes.items():
            if v is None:
                c.pop(k)
            else:
                c[k] = np.asarray(v, dtype=float)
        return c

    def patched(key, idx, value):
        arr = base[key].copy()
        arr[idx] = value
        return cols(**{key: arr})

    b.diagnose('csv_valid_control', b.base_csv, 'ok')
    for key in ('time', 'displacement', 'force', 'current_command'):
        b.csv(f'csv_missing_{key}', cols(**{key: None}),
              names=(key.split('_')[0], 'column', 'current'))
    b.csv('csv_few_nan_force', patched('force', [10, 200, 301], math.nan), 'warn',
          ('nan', 'interpolat'))
    b.csv('csv_many_nan_force', patched('force', slice(0, n // 5), math.nan), 'warn',
          ('nan',), 'a 0.5 s dropout: usable if masked and said so')
    b.csv('csv_one_inf_displacement', patched('displacement', [77], math.inf), 'warn',
          ('inf', 'nan'))
    b.csv('csv_many_inf_displacement', patched('displacement', slice(0, n // 3), math.inf),
          'error', ('inf', 'nan'))
    b.csv('csv_all_nan_current', cols(current_command=np.full(n, math.nan)), 'error',
          ('nan', 'current'))
    b.csv('csv_nan_time', patched('time', [40], math.nan), 'error', ('time',))
    b.csv('csv_one_force_1e300', patched('force', [123], 1e300), 'warn', ('1e+300', 'force'),
          'one force sample of 1e300 N: usable if masked and said so')
    b.csv('csv_force_1e300', cols(force=base['force'] * 1e300), 'error', ('force',))
    b.csv('csv_huge_displacement', cols(displacement=base['displacement'] * 1e12), 'error',
          ('displacement',))
    b.csv('csv_time_in_ms', cols(time=base['time'] * 1e3), 'warn', ('time', 'ms'),
          'time column in milliseconds, read as seconds')
    b.csv('csv_displacement_mm_as_m', cols(displacement=base['displacement'] * 1e3,
                                           velocity=base['velocity'] * 1e3), 'error',
          ('displacement', 'mm'))
    b.csv('csv_force_kN_as_N', cols(force=base['force'] * 1e-3), 'warn', ('kn', 'force'))
    b.csv('csv_current_mA_as_A', cols(current_command=base['current_command'] * 1e3), 'warn',
          ('ma', 'current'))
    b.csv('csv_velocity_mm_s', cols(velocity=base['velocity'] * 1e3), 'error',
          ('velocity',))
    b.csv('csv_capitalised_header', base, 'any', ('column', 'force', 'time'),
          header=['Time', 'Displacement', 'Velocity', 'Force', 'Current_Command'])
    b.csv('csv_bracketed_header', base, 'any', ('column', 'force', 'time'),
          header=['time [s]', 'displacement [m]', 'velocity [m/s]', 'force [N]',
                  'current_command [A]'])
    b.csv('csv_unknown_extra_column', dict(base, humidity=np.ones(n)), 'any',
          ('column', 'humidity'))
    b.csv('csv_constant_force', cols(force=np.full(n, 250.0)), 'error', ('force', 'constant'))
    b.csv('csv_no_motion', cols(displacement=np.zeros(n), velocity=np.zeros(n)), 'error',
          ('motion', 'displacement', 'stroke', 'velocity'))
    b.csv('csv_no_current_variation', cols(current_command=np.full(n, 0.5)), 'warn',
          ('current',), 'constant current: the current dependence cannot be identified')
    b.csv('csv_zero_current', cols(current_command=np.zeros(n)), 'warn', ('current',))
    b.csv('csv_negative_current', cols(current_command=-base['current_command']), 'warn',
          ('current', 'negative'))
    b.csv('csv_reversed_time', cols(time=base['time'][::-1]), 'error', ('time',))
    shuffled = base['time'].copy()
    shuffled[[50, 51]] = shuffled[[51, 50]]
    b.csv('csv_non_monotonic_time', cols(time=shuffled), 'error', ('time',))
    dup = base['time'].copy()
    dup[100] = dup[99]
    b.csv('csv_duplicate_time', cols(time=dup), 'error', ('time',))
    jitter = base['time'] + np.random.default_rng(3).uniform(-0.3, 0.3, n) / RATE
    b.csv('csv_irregular_sampling', cols(time=jitter), 'warn', ('sampl', 'irregular'))
    b.csv('csv_single_row', {k: v[:1] for k, v in base.items()}, 'error',
          ('short', 'sample', 'row'))
    b.csv('csv_two_columns', {'time': base['time'], 'force': base['force']}, 'error',
          ('column', 'displacement'))
    b.csv('csv_too_short', {k: v[:150] for k, v in base.items()}, 'error', ('short',))
    b.text('csv_empty_file', '', 'error', ('empty',))
    b.text('csv_header_only', ','.join(HEADER) + '\n', 'error',
           ('empty', 'short', 'no data', 'row', 'sample'))
    lines = b.base_csv.read_text().splitlines()
    bad = list(lines)
    cells = bad[40].split(',')
    cells[1] = 'x1.2'
    bad[40] = ','.join(cells)
    b.text('csv_non_numeric_cell', '\n'.join(bad) + '\n', 'error', ('non-numeric', 'line'))
    ragged = list(lines)
    ragged[30] = ragged[30] + ',1.0'
    ragged[60] = ','.join(ragged[60].split(',')[:3])
    b.text('csv_ragged_rows', '\n'.join(ragged) + '\n', 'error', ('column',))
    b.text('csv_semicolon_decimal_comma', '\n'.join(
        ln.replace(',', ';').replace('.', ',') for ln in lines) + '\n', 'error',
        ('non-numeric', 'column', 'line', 'decimal'))
    b.text('csv_whitespace_delimited', '\n'.join(ln.replace(',', '  ') for ln in lines) + '\n',
           'any', ('column',))
    b.text('csv_bom_header', '\ufeff' + '\n'.join(lines) + '\n', 'any', ('column', 'time'))
    noise = np.random.default_rng(5).integers(0, 256, 4000, dtype=np.uint8)
    b.text('csv_binary_garbage', bytes(noise), 'error',
           ('non-numeric', 'column', 'header', 'binary', 'read', 'text'), mode='wb')
    b.text('csv_utf16', ('\n'.join(lines) + '\n').encode('utf-16'), 'any',
           ('non-numeric', 'column', 'header', 'encoding', 'read', 'text', 'utf'), mode='wb')
    b.diagnose('data_missing_path', b.root / 'no_such_record.csv', 'error',
               ('no such', 'not found', 'no_such_record'))
    empty_dir = b.root / 'dir_without_records'
    empty_dir.mkdir(exist_ok=True)
    b.diagnose('data_dir_without_records', empty_dir, 'error', ('directory', 'bag', '.csv'))
    # options
    b.diagnose('opt_columns_unknown_quantity', b.base_csv, 'error', ('quantity', 'columns'),
               opts=['--columns', 'torque=F'])
    b.diagnose('opt_columns_missing_source', b.base_csv, 'error', ('mapped', 'column', 'F_kN'),
               opts=['--columns', 'force=F_kN'])
    b.diagnose('opt_units_unknown', b.base_csv, 'error', ('unit',),
               opts=['--units', 'force=furlong'])
    b.diagnose('opt_effects_unknown', b.base_csv, 'error', ('effect',),
               opts=['--effects', 'warp_drive'])
    b.diagnose('opt_folds_zero', b.base_csv, 'error', ('folds',), opts=['--folds', '0'])
    b.diagnose('opt_velocity_cutoff_nan', b.base_csv, 'error', ('cutoff',),
               opts=['--velocity-cutoff', 'nan'])
    b.diagnose('opt_velocity_cutoff_negative', b.base_csv, 'error', ('cutoff',),
               opts=['--velocity-cutoff', '-5'])
    afile = b.root / 'an_existing_file.txt'
    afile.write_text('not a directory\n')
    b.add('diagnose_out_is_file', 'cli', ['diagnose', b.base_csv, '--out', afile, '--quiet'],
          'error', ('--out', 'file'))


def _mat_cases(b):
    from scipy.io import savemat

    base = rig_columns()
    (b.root / 'garbage.mat').write_bytes(b'MATLAB 5.0 MAT-file' + bytes(range(256)) * 4)
    b.diagnose('mat_garbage', b.root / 'garbage.mat', 'error', ('mat',))
    (b.root / 'zero.mat').write_bytes(b'')
    b.diagnose('mat_zero_bytes', b.root / 'zero.mat', 'error', ('mat', 'empty'))
    savemat(b.root / 'no_force.mat', {k: v for k, v in base.items() if k != 'force'})
    b.diagnose('mat_missing_force', b.root / 'no_force.mat', 'error', ('force',))
    ragged = dict(base)
    ragged['force'] = base['force'][:-7]
    savemat(b.root / 'ragged.mat', ragged)
    b.diagnose('mat_ragged_lengths', b.root / 'ragged.mat', 'error', ('sample', 'length'))
    savemat(b.root / 'nan_force.mat', dict(base, force=np.full(base['force'].size, np.nan)))
    b.diagnose('mat_nan_force', b.root / 'nan_force.mat', 'error', ('nan',))
    savemat(b.root / 'data_wrong_shape.mat', {'data': np.ones((300, 3))})
    b.diagnose('mat_data_wrong_shape', b.root / 'data_wrong_shape.mat', 'error',
               ('column', 'force', 'time'))
    savemat(b.root / 'string_force.mat', dict(base, force='one hundred newton'))
    b.diagnose('mat_string_force', b.root / 'string_force.mat', 'error', ('force', 'numeric'))


def _bag_cases(b):
    bags = b.root / 'bags'
    empty = bags / 'empty_folder'
    empty.mkdir(parents=True, exist_ok=True)
    b.diagnose('bag_empty_folder', empty, 'error', ('bag', 'metadata', 'directory'))
    meta0 = bags / 'empty_metadata'
    meta0.mkdir(exist_ok=True)
    (meta0 / 'metadata.yaml').write_text('')
    b.diagnose('bag_empty_metadata', meta0, 'error', ('bag', 'metadata', 'repair'))
    meta1 = bags / 'garbage_metadata'
    meta1.mkdir(exist_ok=True)
    (meta1 / 'metadata.yaml').write_text('rosbag2_bagfile_information: [\n  {{{\n')
    b.diagnose('bag_garbage_metadata', meta1, 'error', ('bag', 'metadata', 'repair'))
    zero = bags / 'zero.mcap'
    zero.write_bytes(b'')
    b.diagnose('bag_zero_byte_mcap', zero, 'error', ('bag', 'mcap', 'repair', 'empty'))
    zero_db = bags / 'zero.db3'
    zero_db.write_bytes(b'')
    b.diagnose('bag_zero_byte_db3', zero_db, 'error', ('bag', 'db3', 'repair', 'empty'))
    garbage = bags / 'garbage.mcap'
    garbage.write_bytes(b'\x89MCAP0\r\n' + bytes(np.random.default_rng(9).integers(
        0, 256, 3000, dtype=np.uint8)))
    b.diagnose('bag_garbage_mcap', garbage, 'error', ('bag', 'mcap', 'repair'))
    src = _write_bag(bags / 'valid')
    if src is not None:
        mcap = next(src.glob('*.mcap'))
        data = mcap.read_bytes()
        trunc = bags / 'truncated'
        trunc.mkdir(exist_ok=True)
        (trunc / 'metadata.yaml').write_text((src / 'metadata.yaml').read_text())
        (trunc / mcap.name).write_bytes(data[:len(data) // 2])
        b.diagnose('bag_truncated_mcap', trunc, 'any', ('bag', 'mcap', 'repair', 'truncat'),
                   'half of the MCAP file cut off (metadata intact)')
        zero_in = bags / 'zero_mcap_in_bag'
        zero_in.mkdir(exist_ok=True)
        (zero_in / 'metadata.yaml').write_text((src / 'metadata.yaml').read_text())
        (zero_in / mcap.name).write_bytes(b'')
        b.diagnose('bag_zero_byte_mcap_with_metadata', zero_in, 'error',
                   ('bag', 'mcap', 'repair', 'empty'))
        nofile = bags / 'metadata_without_mcap'
        nofile.mkdir(exist_ok=True)
        (nofile / 'metadata.yaml').write_text((src / 'metadata.yaml').read_text())
        b.diagnose('bag_metadata_without_mcap', nofile, 'error',
                   ('bag', 'mcap', 'repair', 'missing', 'no such'))


def _write_bag(path):
    """Write a small valid MCAP bag (Float64 force, stroke, command); None if rosbags lacks it."""
    try:
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.typesys import get_typestore, Stores
    except ImportError:
        return None
    if path.exists():
        return path
    store = get_typestore(Stores.LATEST)
    msg_t = store.types['std_msgs/msg/Float64']
    base = rig_columns()
    with Writer(path, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {q: writer.add_connection(topic, 'std_msgs/msg/Float64', typestore=store)
                 for q, topic in (('force', '/damper/force'), ('displacement', '/stroke'),
                                  ('current_command', '/command'))}
        for k, t in enumerate(base['time']):
            for q, conn in conns.items():
                raw = store.serialize_cdr(msg_t(data=float(base[q][k])), msg_t.__msgtype__)
                writer.write(conn, int(t * 1e9) + 1, raw)
    return path


def _model_cases(b):
    good = _model()

    def changed(block, key, value):
        m = json.loads(json.dumps(good))
        if value is _DROP:
            m[block].pop(key)
        else:
            m[block][key] = value
        return m

    b.model('model_valid_control', good, 'ok')
    b.model('model_list_value', changed('damper', 'c0', [400.0, 500.0]), 'error', ('c0',))
    b.model('model_string_value', changed('damper', 'fy1', 'strong'), 'error', ('fy1',))
    b.model('model_null_value', changed('damper', 'v_y', None), 'error', ('v_y',))
    b.model('model_missing_c0', changed('damper', 'c0', _DROP), 'error', ('c0',))
    b.model('model_missing_k_series', changed('damper', 'k_series', _DROP), 'error',
            ('k_series',))
    b.model('model_nan_f0', None, 'error', ('f0', 'nan'),
            raw=json.dumps(good).replace('"f0": 0.0', '"f0": NaN'))
    b.model('model_infinite_c1', None, 'error', ('c1', 'inf'),
            raw=json.dumps(good).replace('"c1": 1200.0', '"c1": Infinity'))
    b.model('model_wrong_law', changed('damper', 'law', 'bingham'), 'error', ('law',))
    b.model('model_law_list', changed('damper', 'law', ['extended']), 'error', ('law',))
    b.model('model_k_series_1e-300', changed('damper', 'k_series', 1e-300), 'error',
            ('k_series',))
    b.model('model_v_y_zero', changed('damper', 'v_y', 0.0), 'error', ('v_y',))
    b.model('model_rho_large', changed('damper', 'rho', 3.0), 'error', ('rho',))
    b.model('model_unknown_key', changed('damper', 'magic', 1.0), 'error', ('magic',))
    b.model('model_dead_time_1e9', changed('current_dynamics', 'dead_time', 1e9), 'error',
            ('dead_time',))
    b.model('model_negative_tau', changed('current_dynamics', 'tau_rise', -0.01), 'error',
            ('tau_rise',))
    b.model('model_missing_tau_fall', changed('current_dynamics', 'tau_fall', _DROP), 'error',
            ('tau_fall',))
    b.model('model_missing_current_dynamics', {k: v for k, v in good.items()
                                               if k != 'current_dynamics'}, 'error',
            ('current_dynamics',))
    b.model('model_missing_damper', {k: v for k, v in good.items() if k != 'damper'},
            'error', ('damper',))
    b.model('model_damper_is_list', dict(good, damper=[1, 2, 3]), 'error', ('damper',))
    b.model('model_dynamics_is_number', dict(good, current_dynamics=0.01), 'error',
            ('current_dynamics', 'mapping'))
    b.model('model_bad_input_signal', dict(good, input={'signal': 'telepathy'}), 'error',
            ('signal',))
    b.model('model_input_is_list', dict(good, input=['current']), 'error', ('signal', 'input'))
    b.model('model_top_level_list', [good], 'error', ('model', 'damper'))
    b.model('model_not_json', None, 'error', ('model', 'read', 'json'), raw='{"damper": {')
    b.model('model_empty_file', None, 'error', ('model', 'read', 'json'), raw='')
    b.add('model_missing_file', 'model', ['predict', b.base_csv, '--model',
                                          b.root / 'no_model.json', '--out',
                                          b.root / 'p.csv'], 'error', ('no_model', 'read'))
    outdir = b.root / 'pred_out_dir'
    outdir.mkdir(exist_ok=True)
    (b.root / 'good_model.json').write_text(json.dumps(good))
    b.add('predict_out_is_directory', 'cli', ['predict', b.base_csv, '--model',
                                              b.root / 'good_model.json', '--out', outdir],
          'error', ('directory', 'pred_out_dir'))
    b.add('predict_record_without_displacement', 'model', [
        'predict', write_csv(b.root / 'pred_nodisp.csv', {
            k: v for k, v in rig_columns().items() if k != 'displacement'}),
        '--model', b.root / 'good_model.json', '--out', b.root / 'p2.csv'], 'error',
        ('displacement', 'column'))
    b.model('sim_damper_model_list_value', changed('damper', 'c0', [1.0]), 'error', ('c0',),
            cmd='damper')
    b.model('sim_driver_model_dead_time_1e9', changed('current_dynamics', 'dead_time', 1e9),
            'error', ('dead_time',), cmd='driver')


_DROP = object()


def _yaml_cases(b):
    def drop(d, key):
        return {k: v for k, v in d.items() if k != key}

    veh, dmp, drv, ctl = _vehicle(), _damper(), _driver(), _controller()
    b.yaml_case('vehicle_valid_control', 'vehicle', veh, 'ok')
    b.yaml_case('vehicle_missing_k_s', 'vehicle', drop(veh, 'k_s'), 'error', ('k_s',))
    b.yaml_case('vehicle_missing_g', 'vehicle', drop(veh, 'g'), 'error', ('g',))
    b.yaml_case('vehicle_negative_m_s', 'vehicle', dict(veh, m_s=-110.0), 'error', ('m_s',))
    b.yaml_case('vehicle_zero_m_u', 'vehicle', dict(veh, m_u=0.0), 'error', ('m_u',))
    b.yaml_case('vehicle_m_s_1e9', 'vehicle', dict(veh, m_s=1e9), 'error', ('m_s',))
    b.yaml_case('vehicle_k_t_1e-300', 'vehicle', dict(veh, k_t=1e-300), 'error', ('k_t',))
    b.yaml_case('vehicle_k_s_string', 'vehicle', dict(veh, k_s='stiff'), 'error', ('k_s',))
    b.yaml_case('vehicle_k_s_list', 'vehicle', dict(veh, k_s=[11000.0, 12000.0]), 'error',
                ('k_s',))
    b.yaml_case('vehicle_stroke_min_positive', 'vehicle', dict(veh, stroke_min=0.05), 'error',
                ('stroke_min',))
    b.yaml_case('vehicle_unknown_key', 'vehicle', dict(veh, mass=3.0), 'error', ('mass',))
    b.yaml_case('vehicle_is_list', 'vehicle', None, 'error', ('mapping',),
                raw='- 110.0\n- 18.0\n')
    b.yaml_case('vehicle_empty_file', 'vehicle', None, 'error', ('mapping',), raw='')
    b.yaml_case('vehicle_invalid_yaml', 'vehicle', None, 'error', ('yaml',),
                raw='m_s: [110\nm_u: {\n')
    b.yaml_case('vehicle_nan_mass', 'vehicle', None, 'error', ('m_s',),
                raw=yaml.safe_dump(drop(veh, 'm_s')) + 'm_s: .nan\n')
    b.yaml_case('damper_missing_law', 'damper', drop(dmp, 'law'), 'error', ('law',))
    b.yaml_case('damper_unknown_law', 'damper', dict(dmp, law='magnetic_unicorn'), 'error',
                ('law',))
    b.yaml_case('damper_law_list', 'damper', dict(dmp, law=['bingham']), 'error', ('law',))
    b.yaml_case('damper_missing_v_y', 'damper', drop(dmp, 'v_y'), 'error', ('v_y',))
    b.yaml_case('damper_negative_c0', 'damper', dict(dmp, c0=-400.0), 'error', ('c0',))
    b.yaml_case('damper_zero_v_y', 'damper', dict(dmp, v_y=0.0), 'error', ('v_y',))
    b.yaml_case('damper_fc1_1e12', 'damper', dict(dmp, fc1=1e12), 'error', ('fc1',))
    b.yaml_case('damper_c1_string', 'damper', dict(dmp, c1='high'), 'error', ('c1',))
    b.yaml_case('damper_extended_k_series_1e-300', 'damper', dict(
        _model()['damper'], k_series=1e-300), 'error', ('k_series',))
    b.yaml_case('driver_dead_time_1e9', 'driver', dict(drv, dead_time=1e9), 'error',
                ('dead_time',))
    b.yaml_case('driver_missing_tau_rise', 'driver', drop(drv, 'tau_rise'), 'error',
                ('tau_rise',))
    b.yaml_case('driver_zero_i_max', 'driver', dict(drv, i_max=0.0), 'error', ('i_max',))
    b.yaml_case('driver_v_max_below_dead_zone', 'driver', dict(drv, v_max=0.2), 'error',
                ('v_max',))
    b.yaml_case('driver_tau_list', 'driver', dict(drv, tau_fall=[0.004]), 'error',
                ('tau_fall',))
    b.yaml_case('controller_missing_law', 'controller', drop(ctl, 'law'), 'error', ('law',))
    b.yaml_case('controller_unknown_law', 'controller', dict(ctl, law='telepathic'), 'error',
                ('law',))
    b.yaml_case('controller_negative_c_sky', 'controller', dict(ctl, c_sky=-5.0), 'error',
                ('c_sky',))
    b.yaml_case('controller_c_sky_string', 'controller', dict(ctl, c_sky='soft'), 'error',
                ('c_sky',))
    b.yaml_case('controller_i_max_list', 'controller', dict(ctl, i_max=[1, 2]), 'error',
                ('i_max',))
    b.yaml_case('controller_lqr_weights_scalar', 'controller', dict(
        ctl, law='clipped_optimal', lqr_weights=3.0), 'error', ('lqr_weights',))
    b.yaml_case('controller_c_sky_1e300', 'controller', dict(ctl, c_sky=1e300), 'error',
                ('c_sky',), )
    b.yaml_case('controller_m_s_1e-300', 'controller', dict(ctl, law='pdd', m_s=1e-300),
                'error', ('m_s',))


def _cli_cases(b):
    b.simulate('sim_valid_control', [], 'ok')
    b.simulate('sim_bump_height_1e6', ['--height', '1e6'], 'error', ('height',))
    b.simulate('sim_negative_duration', ['--duration', '-1'], 'error', ('duration',))
    b.simulate('sim_duration_1e9', ['--duration', '1e9'], 'error', ('duration',))
    b.simulate('sim_nan_speed', ['--speed', 'nan'], 'error', ('speed',))
    b.simulate('sim_inf_height', ['--height', 'inf'], 'error', ('height',))
    b.simulate('sim_zero_speed', ['--speed', '0'], 'error', ('speed',))
    b.simulate('sim_speed_1e9', ['--speed', '1e9'], 'error', ('speed',))
    b.simulate('sim_dt_zero', ['--dt', '0'], 'error', ('dt',))
    b.simulate('sim_dt_one_second', ['--dt', '1'], 'error', ('dt',))
    b.simulate('sim_control_delay_1e9', ['--control-delay', '1e9'], 'error', ('delay',))
    b.simulate('sim_harmonic_freq_inf', ['--road', 'harmonic', '--freq', 'inf'], 'error',
               ('freq',))
    b.simulate('sim_harmonic_freq_negative', ['--road', 'harmonic', '--freq', '-3'], 'error',
               ('freq',))
    b.simulate('sim_iso_road_class_z', ['--road', 'iso8608', '--road-class', 'Z'], 'error',
               ('class',))
    b.simulate('sim_iso_negative_seed', ['--road', 'iso8608', '--seed', '-1'], 'error',
               ('seed',))
    b.add('nodes_road_spec_list', 'cli', ['nodes', '--road-spec', '[1, 2]', '--out',
                                          b.out('nodes1')], 'error', ('road-spec',))
    b.add('nodes_road_spec_bad_yaml', 'cli', ['nodes', '--road-spec', '{{{', '--out',
                                              b.out('nodes2')], 'error', ('road-spec',))
    b.simulate('sim_harmonic_amplitude_1e6', ['--road', 'harmonic', '--height', '1e6'],
               'error', ('amplitude',))
    b.simulate('sim_step_height_minus_1e6', ['--road', 'step', '--height', '-1e6'], 'error',
               ('height',))
    b.simulate('sim_sweep_nan_amplitude', ['--road', 'sweep', '--height', 'nan'], 'error',
               ('height',))
    b.simulate('sim_unknown_vehicle', ['--vehicle', 'no_such_car'], 'error', ('no_such_car',))
    b.simulate('sim_unknown_controller', ['--controller', 'no_such_law'], 'error',
               ('no_such_law',))
    afile = b.root / 'an_existing_file.txt'
    afile.write_text('not a directory\n')
    b.add('sim_out_is_file', 'cli', ['simulate', '--duration', '0.2', '--out', afile],
          'error', ('--out', 'file'), subprocess=True)
    b.add('sim_out_under_file', 'cli', ['simulate', '--duration', '0.2', '--out',
                                        afile / 'sub'], 'error', ('--out',))
    b.add('doe_rate_zero', 'cli', ['doe', '--rate', '0', '--out', b.root / 'doe.csv'],
          'error', ('rate',), subprocess=True)
    b.add('doe_negative_duration', 'cli', ['doe', '--duration', '-5', '--out',
                                           b.root / 'doe.csv'], 'error', ('duration',))
    b.add('doe_nan_stroke', 'cli', ['doe', '--stroke', 'nan', '--out', b.root / 'doe.csv'],
          'error', ('stroke',))
    b.add('doe_out_is_directory', 'cli', ['doe', '--duration', '2', '--out', b.root],
          'error', ('directory', str(b.root).lower()))
    ev = ['evaluate', '--scenarios', 'bump', '--study', 'none', '--no-plots', '--out']
    b.add('eval_unknown_law', 'cli', ev + [b.out('ev1'), '--laws', 'no_such_law'], 'error',
          ('no_such_law',))
    b.add('eval_unknown_scenario', 'cli', ev + [b.out('ev2'), '--scenarios', 'moon_road'],
          'error', ('moon_road', 'scenario'))
    b.add('eval_delay_1e9', 'cli', ev + [b.out('ev3'), '--delay', '1e9'], 'error', ('delay',))
    b.add('eval_negative_actuator_scale', 'cli', ev + [b.out('ev4'), '--actuator-scale', '-1'],
          'error', ('scale', 'tau', 'dead_time'))
    b.add('eval_nan_dt', 'cli', ev + [b.out('ev5'), '--dt', 'nan'], 'error', ('dt',))
    b.add('eval_unknown_study', 'cli', ev + [b.out('ev6'), '--study', 'astrology'], 'error',
          ('study',))
    b.add('eval_set_string_gain', 'cli', ev + [b.out('ev7'), '--laws', 'skyhook', '--set',
                                               'skyhook.c_sky=abc'], 'error', ('c_sky',))
    b.add('eval_set_unknown_param', 'cli', ev + [b.out('ev8'), '--laws', 'skyhook', '--set',
                                                 'skyhook.warp=3'], 'error', ('warp',))
    b.add('eval_out_is_file', 'cli', ev[:-1] + ['--out', afile], 'error', ('--out', 'file'))
    b.add('cli_unknown_command', 'cli', ['levitate'], 'error', ('levitate', 'choice'),
          subprocess=True)


def generate(root):
    """Write the corpus under ``root``; return the list of :class:`Case`."""
    b = _Builder(root)
    _data_cases(b)
    _mat_cases(b)
    _bag_cases(b)
    _model_cases(b)
    _yaml_cases(b)
    _cli_cases(b)
    names = [c.name for c in b.cases]
    assert len(names) == len(set(names)), 'duplicate case names'
    return b.cases


if __name__ == '__main__':
    where = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp())
    cases = generate(where)
    for c in cases:
        print(f'{c.group:6s} {c.expect:5s} {c.name}')
    print(f'{len(cases)} cases in {where}')
