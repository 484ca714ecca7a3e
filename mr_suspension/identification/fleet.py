"""Fleet diagnosis: one ``diagnose`` per record set, serially or on dask, and a summary table.

``mr-suspension diagnose-fleet DIR... --out OUT`` (``cli.cmd_diagnose_fleet``).

**Record sets** (:func:`find_record_sets`). Every argument is a folder of record sets, or
one set itself:

* a file (``.csv``, ``.txt``, ``.mat``, ``.mcap``, ``.db3``) or a rosbag2 bag folder given
  as an argument is one set;
* in a folder, each record file is one set (named after its stem), each bag folder is one
  set, and each sub-folder holding record files is one set (one damper's records, loaded
  together as ``diagnose SUBFOLDER`` does, e.g. ``vrths/preprocessed_sine``); hidden entries,
  other files and folders without records are skipped, and so is the output folder.

Names are the file stem or folder name; a repeated name gets ``-2``, ``-3``, ... in the order
found (arguments in order, entries sorted).

**Tasks**. One set is one task (:func:`run_set`, a pure function of the set and the settings):
it loads the set, diagnoses it and writes the report into a temporary folder *on the machine
that runs it*, and returns the files' bytes with a summary row; the caller writes them to
``OUT/<name>/`` (so ``OUT`` need only exist where the command runs; the records must be
readable by the workers under the same paths: local paths for a local cluster, absolute paths
on a shared file system for a remote one). Any failure of a set (unreadable file, refused
data, a worker that died) is an error row, never the end of the fleet. On a cluster each task
runs ``diagnose`` single-threaded (``diagnose.JOBS = 1``, one task per worker core); serially
``diagnose`` keeps its own threads. The reports are identical on every path except the wall
times (``timing_s``).
"""

import csv
from dataclasses import dataclass, replace
import os
from pathlib import Path
import tempfile
import time
import warnings

RECORD_SUFFIXES = ('.csv', '.txt', '.mat')
BAG_SUFFIXES = ('.mcap', '.db3')
REPORT_FILES = ('report.json', 'report.md', 'model.json')
ERROR_FILE = 'error.txt'
COLUMNS = ('name', 'records', 'verdict', 'first_cause', 'first_cause_location', 'causes',
           'baseline_nrmse', 'extended_nrmse', 'gain', 'floor_nrmse', 'nrmse_over_floor',
           'wall_s', 'cpu_s', 'peak_rss_mb', 'error', 'path')


@dataclass(frozen=True)
class RecordSet:
    """One damper's input: ``name`` (the report folder), ``paths`` loaded together."""

    name: str
    paths: tuple


@dataclass(frozen=True)
class Settings:
    """What every task needs: load options, catalogue, folds, nominal driver, figures.

    ``jobs`` sets ``diagnose.JOBS`` in the task (1 on a cluster; None keeps the default).
    """

    load: object
    effects: tuple
    folds: int = 5
    nominal: object = None
    make_plots: bool = True
    jobs: int = None


def _is_bag(p):
    if not p.is_dir():
        return False
    if (p / 'metadata.yaml').exists():
        return True
    return any(q.suffix.lower() in BAG_SUFFIXES for q in p.iterdir())


def _record_file(p):
    return p.is_file() and p.suffix.lower() in RECORD_SUFFIXES + BAG_SUFFIXES


def _entry_set(p):
    """Return the set one folder entry stands for, or None (skipped)."""
    if p.name.startswith('.'):
        return None
    if _record_file(p):
        return RecordSet(p.stem, (str(p),))
    if _is_bag(p):
        return RecordSet(p.name, (str(p),))
    if p.is_dir() and any(_record_file(q) and q.suffix.lower() in RECORD_SUFFIXES
                          for q in p.iterdir()):
        return RecordSet(p.name, (str(p),))
    return None


def find_record_sets(dirs, exclude=()):
    """Return the :class:`RecordSet` list of the arguments (see the module docstring).

    ``exclude`` lists folders never scanned (the output folder). A missing argument or a folder
    without any record set is a ``DataError``.
    """
    from mr_suspension.identification.data import DataError

    skip = {Path(e).resolve() for e in exclude}
    sets = []
    for d in dirs:
        d = Path(d)
        if not d.exists():
            raise DataError(f'{d}: no such file or directory')
        if d.is_file() or _is_bag(d):
            sets.append(RecordSet(d.stem if d.is_file() else d.name, (str(d),)))
            continue
        found = [s for s in (_entry_set(q) for q in sorted(d.iterdir())
                             if q.resolve() not in skip) if s is not None]
        if not found:
            raise DataError(f'{d}: no record sets (no .csv/.txt/.mat files, bags, or '
                            'sub-folders of them)')
        sets.extend(found)
    seen = {}
    out = []
    for s in sets:
        k = seen[s.name] = seen.get(s.name, 0) + 1
        out.append(s if k == 1 else replace(s, name=f'{s.name}-{k}'))
    return out


def _peak_rss_mb():
    try:
        import resource
    except ImportError:  # pragma: no cover - not POSIX
        return float('nan')
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _error_text(exc):
    text = ' '.join(str(exc).split()) or type(exc).__name__
    if isinstance(exc, (ValueError, OSError)):
        return text
    return f'internal error ({type(exc).__name__}: {text})'


def summary_row(rep):
    """Fleet-table fields of one report dict (report.json)."""
    causes = rep.get('causes') or []
    floor = rep.get('noise_floor') or {}
    ext = rep['extended']['heldout_nrmse']
    return {'verdict': rep['verdict'],
            'first_cause': causes[0]['effect'] if causes else '',
            'first_cause_location': causes[0]['location'] if causes else '',
            'causes': ';'.join(f'{c["effect"]}@{c["location"]}' for c in causes),
            'baseline_nrmse': rep['baseline']['heldout_nrmse'],
            'extended_nrmse': ext, 'gain': rep.get('gain'),
            'floor_nrmse': floor.get('nrmse'),
            'nrmse_over_floor': ext / floor['nrmse'] if floor.get('nrmse') else None}


def run_set(settings, rset):
    """Diagnose one record set (the task); return its row, files and warnings.

    Never raises for the set's own failures: they come back as ``row['error']``.
    """
    import json

    from mr_suspension.identification import diagnose
    from mr_suspension.identification.pipeline import diagnose_to_dir

    t0, c0 = time.time(), time.process_time()
    if settings.jobs:
        diagnose.JOBS = int(settings.jobs)
    row = {'name': rset.name, 'path': os.pathsep.join(rset.paths), 'error': ''}
    files = {}
    with tempfile.TemporaryDirectory(prefix='mr-fleet-') as tmp:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter('always')
            try:
                rep, _, notes = diagnose_to_dir(
                    list(rset.paths), tmp, settings.load, settings.effects, settings.folds,
                    settings.nominal, make_plots=settings.make_plots)
                row['records'] = len(rep.get('data', ()))
                row.update(summary_row(rep))
                for p in sorted(Path(tmp).rglob('*')):
                    if p.is_file():
                        files[p.relative_to(tmp).as_posix()] = p.read_bytes()
                json.loads(files['report.json'])  # written and readable
            except Exception as exc:  # noqa: B902 - one bad set is an error row
                row['error'] = _error_text(exc)
                files, notes = {}, []
    notes = list(dict.fromkeys(notes + [str(w.message) for w in caught]))
    row['wall_s'] = time.time() - t0
    row['cpu_s'] = time.process_time() - c0
    row['peak_rss_mb'] = _peak_rss_mb()
    return {'row': row, 'files': files, 'warnings': notes}


def write_result(out, result):
    """Write one task's files into ``out/<name>/`` (an error leaves ``error.txt`` only)."""
    row = result['row']
    d = Path(out) / row['name']
    d.mkdir(parents=True, exist_ok=True)
    if row.get('error'):
        for name in REPORT_FILES:  # no stale report of an earlier run next to the error
            (d / name).unlink(missing_ok=True)
        (d / ERROR_FILE).write_text(row['error'] + '\n')
        return d
    (d / ERROR_FILE).unlink(missing_ok=True)
    for rel, data in result['files'].items():
        p = d / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(data)
    return d


def _fmt(v, spec='.4f'):
    if v is None or v == '':
        return ''
    if isinstance(v, float):
        return format(v, spec) if v == v else ''
    return str(v)


def write_summary(out, rows, header=()):
    """Write ``out/fleet.csv`` (one row per set, :data:`COLUMNS`) and ``out/fleet.md``."""
    out = Path(out)
    with open(out / 'fleet.csv', 'w', newline='') as fh:
        w = csv.DictWriter(fh, fieldnames=COLUMNS, extrasaction='ignore')
        w.writeheader()
        for r in rows:
            w.writerow({k: _fmt(r.get(k), '.6g') for k in COLUMNS})
    counts = {}
    for r in rows:
        key = 'error' if r.get('error') else r.get('verdict', '')
        counts[key] = counts.get(key, 0) + 1
    lines = ['# Fleet diagnosis', '']
    lines += list(header)
    lines += ['', 'Verdicts: ' + ', '.join(f'{k} {v}' for k, v in sorted(counts.items())) + '.',
              '', '| record set | verdict | first cause | location | baseline NRMSE | '
              'extended NRMSE | NRMSE / floor | wall [s] | error |',
              '|---|---|---|---|---|---|---|---|---|']
    for r in rows:
        name = r['name']
        link = f'[{name}]({name}/report.md)' if not r.get('error') else name
        err = r.get('error', '').replace('|', '\\|')
        lines.append(f'| {link} | {r.get("verdict", "")} | {r.get("first_cause", "")} | '
                     f'{r.get("first_cause_location", "")} | {_fmt(r.get("baseline_nrmse"))} '
                     f'| {_fmt(r.get("extended_nrmse"))} | '
                     f'{_fmt(r.get("nrmse_over_floor"), ".2f")} | '
                     f'{_fmt(r.get("wall_s"), ".1f")} | {err} |')
    lines += ['', 'NRMSE: held-out (outer blocks), RMS error / std of the measured force; floor: '
              'the noise floor estimated from the data (empty when not estimable); wall: one '
              'task (load, diagnose, figures) where it ran. Each report: `<name>/report.md`.',
              '']
    (out / 'fleet.md').write_text('\n'.join(lines))


def run_fleet(sets, out, settings, workers=0, scheduler=None, log=None):
    """Diagnose every set (serially, on ``workers`` local processes or at ``scheduler``).

    Writes each report as it arrives (:func:`write_result`; the caller writes the summary,
    :func:`write_summary`); ``log(line)`` gets one line per finished set. Returns
    ``(rows in the order of sets, wall seconds)``.
    """
    from functools import partial

    from mr_suspension import parallel

    out = Path(out)
    if scheduler or workers:
        settings = replace(settings, jobs=1)
    if scheduler:  # a remote worker's working folder is not ours
        sets = [replace(s, paths=tuple(str(Path(p).resolve()) for p in s.paths))
                for s in sets]
    t0 = time.time()
    rows = [None] * len(sets)
    done = 0
    for k, res in parallel.iter_tasks(partial(run_set, settings), sets, workers=workers,
                                      scheduler=scheduler, names=[s.name for s in sets],
                                      errors='return'):
        if isinstance(res, BaseException):  # the worker itself failed (killed, lost)
            res = {'row': {'name': sets[k].name, 'path': os.pathsep.join(sets[k].paths),
                           'error': _error_text(getattr(res, 'original', res))},
                   'files': {}, 'warnings': []}
        write_result(out, res)
        rows[k] = res['row']
        done += 1
        if log is not None:
            log(_progress_line(done, len(sets), res))
    wall = time.time() - t0
    return rows, wall


def _progress_line(done, total, res):
    r = res['row']
    head = f'[{done}/{total}] {r["name"]}'
    if r.get('error'):
        return f'{head}: error: {r["error"]}'
    cause = (f'{r["first_cause"]} ({r["first_cause_location"]})' if r.get('first_cause')
             else 'no cause')
    warn = f', {len(res["warnings"])} warnings' if res['warnings'] else ''
    return (f'{head}: {r["verdict"]}, {cause}, NRMSE {r["baseline_nrmse"]:.4f} -> '
            f'{r["extended_nrmse"]:.4f}, {r["wall_s"]:.1f} s{warn}')
