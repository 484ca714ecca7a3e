"""Malformed-input corpus: inputs tried, tracebacks, hangs and wrong confident results.

``python benchmarks/bench_corpus.py [--list]`` generates the corpus of ``test/malformed`` into a
temporary directory, runs every case through the real ``mr-suspension`` commands and prints
one summary line (``--list``: also each case that is not handled).
"""

import argparse
import importlib.util
from pathlib import Path
import sys
import tempfile

HERE = Path(__file__).resolve().parents[1] / 'test' / 'malformed'


def _load(name):
    spec = importlib.util.spec_from_file_location(f'malformed_{name}', HERE / f'{name}.py')
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def main(argv=None):
    """Run the corpus and print the counts; exit code 1 on a traceback or hang."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--list', action='store_true', help='print every case not handled')
    ap.add_argument('--timeout', type=int, default=60, help='seconds per case (default 60)')
    args = ap.parse_args(argv)
    generate, runner = _load('generate'), _load('runner')
    with tempfile.TemporaryDirectory() as tmp:
        results = runner.run_all(generate.generate(tmp), args.timeout)
    if args.list:
        for r in results:
            if r.verdict != 'pass':
                print(f'{r.verdict:12s} {r.case.name}: {r.detail[:200]}')
    print(runner.summary_line(results))
    counts = runner.summary(results)
    return 1 if counts['traceback'] or counts['hang'] else 0


if __name__ == '__main__':
    sys.exit(main())
