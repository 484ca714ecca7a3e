"""Run malformed-input cases through the real ``mr-suspension`` commands and judge the outcome.

In-process: ``mr_suspension.cli.main(argv)`` with stdout/stderr captured and a time bound
(``signal.alarm``); or in a subprocess (``python -m mr_suspension.cli``) to prove that no
traceback reaches the terminal. Outcomes (``Result.verdict``):

``pass``; ``traceback`` (an exception escaped, or a traceback was printed); ``hang`` (over the
time bound); ``wrong`` (exit 0 without a warning on unusable input: a confident wrong result);
``bad_message`` (refused, but not with exactly one ``error:`` line naming the problem);
``internal`` (the one-line internal-error fallback: a bug, though no traceback);
``refused_valid`` (a valid control input was refused).
"""

import contextlib
from dataclasses import dataclass
import io
import os
import signal
import subprocess
import sys
import time

TIMEOUT = 60  # [s] per case


class CaseTimeout(BaseException):
    """Raised by the alarm; a BaseException so that the CLI's guard does not catch it."""


@dataclass
class Result:
    """Outcome of one case."""

    case: object
    code: object
    stdout: str
    stderr: str
    seconds: float
    verdict: str = ''
    detail: str = ''


def _alarm(signum, frame):
    raise CaseTimeout()


def run_in_process(case, timeout=TIMEOUT):
    """Run ``case.argv`` through ``mr_suspension.cli.main``; returns a judged :class:`Result`."""
    from mr_suspension import cli

    out, err = io.StringIO(), io.StringIO()
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(timeout)
    t0 = time.perf_counter()
    code = None
    escaped = ''
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = cli.main(list(case.argv))
            except SystemExit as exc:  # argparse
                code = exc.code if isinstance(exc.code, int) else 2
    except CaseTimeout:
        code = 'timeout'
    except Exception as exc:  # noqa: B902 - an escaped exception is what we look for
        escaped = f'{type(exc).__name__}: {exc}'
        code = 'exception'
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    res = Result(case, code, out.getvalue(), err.getvalue(), time.perf_counter() - t0)
    return judge(res, escaped)


def run_subprocess(case, timeout=TIMEOUT):
    """Run ``case.argv`` as ``python -m mr_suspension.cli`` in a child process."""
    env = dict(os.environ)
    env.pop('MR_SUSPENSION_DEBUG', None)
    timeout = max(timeout, 2 * TIMEOUT)  # a cold interpreter start on a loaded machine
    t0 = time.perf_counter()
    try:
        proc = subprocess.run([sys.executable, '-m', 'mr_suspension.cli'] + list(case.argv),
                              capture_output=True, text=True, timeout=timeout, env=env)
        code, out, err = proc.returncode, proc.stdout, proc.stderr
    except subprocess.TimeoutExpired as exc:
        code, out, err = 'timeout', str(exc.stdout or ''), str(exc.stderr or '')
    return judge(Result(case, code, out, err, time.perf_counter() - t0))


def judge(res, escaped=''):
    """Set ``res.verdict`` and ``res.detail`` from the exit code and the printed lines."""
    case = res.case
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    errors = [ln for ln in lines if 'error:' in ln]
    warns = [ln for ln in lines if ln.startswith('warning:')]
    if res.code == 'timeout':
        res.verdict, res.detail = 'hang', f'no answer within the time bound ({res.seconds:.0f} s)'
    elif escaped or 'Traceback (most recent call last)' in res.stderr:
        res.verdict = 'traceback'
        res.detail = escaped or res.stderr.strip().splitlines()[-1]
    elif res.code == 1 and any('internal error' in ln for ln in errors):
        res.verdict, res.detail = 'internal', errors[0]
    elif res.code == 0:
        if case.expect == 'error':
            res.verdict = 'wrong'
            res.detail = 'accepted: ' + (warns[0] if warns else 'exit 0 without a warning')
        elif case.expect == 'warn' and not any(n in _without_paths(w, case)
                                               for w in warns for n in case.names or ('',)):
            res.verdict = 'wrong'
            res.detail = (f'exit 0 without a warning naming {"/".join(case.names)}'
                          + (f' (only: {warns[0]})' if warns else ''))
        else:
            res.verdict, res.detail = 'pass', (warns[0] if warns else 'exit 0')
    elif res.code == 2:
        if case.expect == 'ok':
            res.verdict, res.detail = 'refused_valid', errors[0] if errors else res.stderr
        elif len(errors) != 1:
            res.verdict = 'bad_message'
            res.detail = f'{len(errors)} error lines: {" | ".join(errors)[:300]}'
        elif case.names and not any(n in _without_paths(errors[0], case) for n in case.names):
            res.verdict = 'bad_message'
            res.detail = f'does not name {"/".join(case.names)}: {errors[0]}'
        else:
            res.verdict, res.detail = 'pass', errors[0]
    else:
        res.verdict, res.detail = 'bad_message', f'exit code {res.code}: {res.stderr[-300:]}'
    return res


def _without_paths(line, case):
    """Return the error line in lower case without the case's paths (they contain its name)."""
    line = line.lower()
    for arg in sorted(case.argv, key=len, reverse=True):
        if os.sep in arg:
            line = line.replace(arg.lower(), '<path>')
    return line


def run_all(cases, timeout=TIMEOUT):
    """Run every case (in a subprocess where ``case.subprocess``); return the results."""
    # Valid controls do real work (the first one compiles the numba kernels): 3x the bound.
    return [(run_subprocess if c.subprocess else run_in_process)(
        c, 3 * timeout if c.expect == 'ok' else timeout) for c in cases]


def summary(results):
    """Return the counts: inputs, passes, tracebacks, hangs, wrong confident results, ..."""
    count = {v: sum(r.verdict == v for r in results)
             for v in ('pass', 'traceback', 'hang', 'wrong', 'bad_message', 'internal',
                       'refused_valid')}
    count['inputs'] = len(results)
    count['seconds'] = round(sum(r.seconds for r in results), 1)
    return count


def summary_line(results):
    """One line with the counts of :func:`summary`."""
    c = summary(results)
    return (f'malformed corpus: {c["inputs"]} inputs tried, {c["traceback"]} tracebacks, '
            f'{c["hang"]} hangs, {c["wrong"]} wrong confident results, {c["internal"]} '
            f'internal errors, {c["bad_message"]} unclear messages, {c["refused_valid"]} '
            f'valid inputs refused, {c["pass"]} handled ({c["seconds"]} s)')
