"""``diagnose-fleet``: record sets found, one report each, a fleet table; dask == serial."""

import csv
import json

import pytest

from mr_suspension.cli import main
from mr_suspension.identification import fleet
from mr_suspension.truth import cases

# Short records of the independent truth (about 1 s of diagnosis each). Mid-range effect
# strengths: the fleet's plumbing is under test here, not the diagnosis's hardest records (a
# 3 s record behind a 5e4 N/m spring, the range's softest, drew another cause set from
# every ulp of change in the code: gas spring, series spring, a channel filter, once a crash).
RECORDS = {'car-a': (21, ()), 'car-b': (22, ('series_stiffness',)),
           'car-c': (23, ('current_lag',))}
STRENGTH = 0.5
DURATION = 3.0
TIMING = ('timing_s',)  # the wall-time field of report.json


@pytest.fixture(scope='module')
def fleet_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp('fleet_in')
    for name, (seed, effects) in RECORDS.items():
        case = cases.make_case(seed, effects, sensor_faults=(), duration=DURATION,
                               measured_current=False, strength=STRENGTH)
        case.write_csv(d / f'{name}.csv')
    return d


def _report(path):
    rep = json.loads(path.read_text())
    for k in TIMING:
        rep.pop(k, None)
    return rep


def _rows(out):
    with open(out / 'fleet.csv', newline='') as fh:
        return list(csv.DictReader(fh))


def test_find_record_sets(tmp_path):
    (tmp_path / 'a.csv').write_text('x')
    (tmp_path / 'b.TXT').write_text('x')
    (tmp_path / 'notes.md').write_text('x')
    (tmp_path / '.hidden.csv').write_text('x')
    damper = tmp_path / 'damper_d'
    damper.mkdir()
    (damper / 'r1.csv').write_text('x')
    (damper / 'r2.csv').write_text('x')
    bag = tmp_path / 'bag_e'
    bag.mkdir()
    (bag / 'metadata.yaml').write_text('x')
    (tmp_path / 'empty').mkdir()
    out = tmp_path / 'out'
    (out / 'old').mkdir(parents=True)
    (out / 'old' / 'x.csv').write_text('x')
    other = tmp_path.parent / f'{tmp_path.name}_other'
    other.mkdir()
    (other / 'a.csv').write_text('x')
    sets = fleet.find_record_sets([tmp_path, other / 'a.csv'], exclude=[out])
    assert [s.name for s in sets] == ['a', 'b', 'bag_e', 'damper_d', 'a-2']
    assert sets[3].paths == (str(damper),)
    with pytest.raises(ValueError, match='no record sets'):
        fleet.find_record_sets([tmp_path / 'empty'])
    with pytest.raises(ValueError, match='no such file'):
        fleet.find_record_sets([tmp_path / 'missing'])


def test_two_workers_identical_to_serial(fleet_dir, tmp_path, capsys):
    serial, dask2 = tmp_path / 'serial', tmp_path / 'dask2'
    assert main(['diagnose-fleet', str(fleet_dir), '--out', str(serial), '--workers', '0',
                 '--no-plots']) == 0
    assert main(['diagnose-fleet', str(fleet_dir), '--out', str(dask2), '--workers', '2',
                 '--no-plots', '--quiet']) == 0
    text = capsys.readouterr()
    assert 'running serially' in text.out and '[3/3]' in text.out
    assert 'distributed' not in text.err  # dask's logging is silenced
    for name in RECORDS:
        a, b = _report(serial / name / 'report.json'), _report(dask2 / name / 'report.json')
        assert a == b, name
        assert (serial / name / 'model.json').read_text() == \
            (dask2 / name / 'model.json').read_text()
        assert (dask2 / name / 'report.md').exists()
    rows_s, rows_d = _rows(serial), _rows(dask2)
    assert [r['name'] for r in rows_s] == list(RECORDS) == [r['name'] for r in rows_d]
    for rs, rd in zip(rows_s, rows_d):
        assert not rs['error'] and rs['verdict']
        assert float(rs['wall_s']) > 0
        same = {k for k in fleet.COLUMNS if k not in ('wall_s', 'cpu_s', 'peak_rss_mb')}
        assert {k: rs[k] for k in same} == {k: rd[k] for k in same}
    # the series-stiffness record has a cause, and the extended model is better on it
    assert rows_s[1]['first_cause'] and rows_s[1]['first_cause_location'] == 'damper'
    assert float(rows_s[1]['extended_nrmse']) < float(rows_s[1]['baseline_nrmse'])
    rep = _report(serial / 'car-b' / 'report.json')
    assert rows_s[1]['first_cause'] == rep['causes'][0]['effect']
    assert float(rows_s[1]['baseline_nrmse']) == pytest.approx(
        rep['baseline']['heldout_nrmse'], rel=1e-5)
    md = (dask2 / 'fleet.md').read_text()
    assert 'local dask cluster of 2 worker processes' in md
    assert '[car-b](car-b/report.md)' in md


def _write_bag(path, seed, effects):
    """Write a rosbag2 of one truth record on the node set's topic names."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import get_typestore, Stores

    cols = cases.make_case(seed, effects, sensor_faults=(), duration=DURATION,
                           measured_current=False).columns
    ts = get_typestore(Stores.LATEST)
    f64 = ts.types['std_msgs/msg/Float64']
    topics = {'/damper/stroke': 'displacement', '/damper/force': 'force',
              '/damper/current_command': 'current_command'}
    with Writer(path, version=9) as w:
        conns = {t: w.add_connection(t, f64.__msgtype__, typestore=ts) for t in topics}
        for k, t in enumerate(cols['time']):
            for topic, q in topics.items():
                w.write(conns[topic], int(1e9 + t * 1e9),
                        ts.serialize_cdr(f64(data=float(cols[q][k])), f64.__msgtype__))


def test_broken_record_is_an_error_row(fleet_dir, tmp_path, capsys):
    src = tmp_path / 'in'
    src.mkdir()
    (src / 'car-a.csv').write_bytes((fleet_dir / 'car-a.csv').read_bytes())
    (src / 'broken.csv').write_text('time,force\n0,1\n1,2\n')
    _write_bag(src / 'car-bag', 24, ('gas_spring',))
    out = tmp_path / 'out'
    (out / 'broken').mkdir(parents=True)
    (out / 'broken' / 'report.json').write_text('{}')  # stale report of an earlier run
    assert main(['diagnose-fleet', str(src), '--out', str(out), '--workers', '0']) == 0
    rows = {r['name']: r for r in _rows(out)}
    assert list(rows) == ['broken', 'car-a', 'car-bag']
    assert 'missing column' in rows['broken']['error'] and not rows['broken']['verdict']
    for name in ('car-a', 'car-bag'):
        assert not rows[name]['error'] and rows[name]['verdict'] and rows[name]['records'] == '1'
    assert (out / 'broken' / 'error.txt').exists()
    assert not (out / 'broken' / 'report.json').exists()
    rep = json.loads((out / 'car-a' / 'report.json').read_text())
    assert rep['figures'] and all((out / 'car-a' / f).exists() for f in rep['figures'])
    assert 'broken: error: ' in capsys.readouterr().out
    assert 'error 1' in (out / 'fleet.md').read_text()


def test_bad_scheduler_and_inputs_are_one_line_errors(fleet_dir, tmp_path, capsys):
    out = str(tmp_path / 'o')
    assert main(['diagnose-fleet', str(fleet_dir), '--out', out,
                 '--scheduler', 'no-port-here']) == 2
    err = capsys.readouterr().err
    assert 'bad dask scheduler address' in err and len(err.strip().splitlines()) == 1
    assert main(['diagnose-fleet', str(tmp_path / 'nothing'), '--out', out]) == 2
    assert main(['diagnose-fleet', str(fleet_dir), '--out', out, '--workers', '-1']) == 2
