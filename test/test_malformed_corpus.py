"""Malformed-input corpus through the real commands: one clear error or a warning, never a trace.

The corpus (``test/malformed/generate.py``) is generated into a temporary directory; every case
runs through ``mr_suspension.cli.main`` in-process (a few in a subprocess) under a time bound,
and ``test/malformed/runner.py`` judges the exit code and the printed lines.
"""

import importlib.util
from pathlib import Path
import sys

import pytest

HERE = Path(__file__).resolve().parent / 'malformed'

# Cases still failing for reasons outside this corpus' owners' files (identification/data.py
# is being reworked by another engineer); each must stay free of tracebacks and hangs, and is
# listed by the summary. Remove an entry once it passes.
KNOWN_OPEN = {}


def _load(name):
    spec = importlib.util.spec_from_file_location(f'malformed_{name}', HERE / f'{name}.py')
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


generate = _load('generate')
runner = _load('runner')


@pytest.fixture(scope='module')
def results(tmp_path_factory):
    """Run the whole corpus once."""
    cases = generate.generate(tmp_path_factory.mktemp('corpus'))
    return runner.run_all(cases, timeout=60)


def test_corpus_covers_the_required_inputs(tmp_path):
    """At least 100 generated inputs over data files, bags, models, YAML and CLI numbers."""
    cases = generate.generate(tmp_path)
    assert len(cases) >= 100
    groups = {c.group for c in cases}
    assert groups == {'data', 'model', 'yaml', 'cli'}
    names = ' '.join(c.name for c in cases)
    for word in ('nan', 'inf', '1e300', 'ms', 'mm', 'kN', 'mA', 'capitalised', 'bracketed',
                 'non_numeric', 'ragged', 'empty_file', 'header_only', 'single_row',
                 'non_monotonic', 'constant_force', 'no_motion', 'no_current_variation',
                 'binary', 'mat_', 'bag_empty_folder', 'bag_empty_metadata', 'truncated_mcap',
                 'zero_byte_mcap', 'model_list_value', 'model_missing', 'model_wrong_law',
                 'vehicle_missing_k_s', 'dead_time_1e9', 'k_series_1e-300', 'height_1e6',
                 'negative_duration', 'rate_zero', 'nan_speed', 'out_is_file'):
        assert word in names, word
    assert sum(c.subprocess for c in cases) >= 3
    assert all(c.expect in ('error', 'warn', 'any', 'ok') for c in cases)


def test_judge_flags_what_it_must():
    """The judge itself: a traceback, a silent acceptance and a vague error are failures."""
    case = generate.Case('x', 'cli', ['simulate'], 'error', ('height',))
    res = runner.judge(runner.Result(case, 0, '', '', 0.1))
    assert res.verdict == 'wrong'
    res = runner.judge(runner.Result(case, 2, '', 'p: error: bad input\n', 0.1))
    assert res.verdict == 'bad_message'
    res = runner.judge(runner.Result(case, 2, '', 'p: error: height 1e6 m\n', 0.1))
    assert res.verdict == 'pass'
    res = runner.judge(runner.Result(case, 1, '', 'Traceback (most recent call last):\n', 0.1))
    assert res.verdict == 'traceback'
    warn = generate.Case('w', 'data', ['diagnose'], 'warn', ('nan',))
    res = runner.judge(runner.Result(warn, 0, '', 'warning: spike masked\n', 0.1))
    assert res.verdict == 'wrong'
    res = runner.judge(runner.Result(warn, 0, '', 'warning: 3 NaN interpolated\n', 0.1))
    assert res.verdict == 'pass'


def test_no_traceback_no_hang_no_wrong_answer(results):
    """Every input: one clear error (exit 2) or a usable result with a warning (exit 0)."""
    print('\n' + runner.summary_line(results))
    bad = [r for r in results if r.verdict != 'pass']
    for r in bad:
        print(f'  {r.verdict}: {r.case.name}: {r.detail[:200]}')
    assert not [r.case.name for r in bad if r.verdict in ('traceback', 'hang')]
    unexpected = [f'{r.verdict}: {r.case.name}: {r.detail[:200]}' for r in bad
                  if r.case.name not in KNOWN_OPEN]
    assert not unexpected, '\n'.join(unexpected)


def test_subprocess_cases_print_no_traceback(results):
    """The subprocess cases ran as a user runs them; their stderr has one line, no trace."""
    sub = [r for r in results if r.case.subprocess]
    assert len(sub) >= 3
    for r in sub:
        assert r.code == 2, (r.case.name, r.stderr)
        assert 'Traceback' not in r.stderr
        assert sum('error:' in ln for ln in r.stderr.splitlines()) == 1
