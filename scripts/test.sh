#!/usr/bin/env bash
# Run the whole test suite: ament-rule linters (flake8, pep257) and pytest (second README command).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/venv.sh
export PATH="$PWD/.venv/bin:$PATH"
echo '== flake8 (ament configuration)'
flake8 mr_suspension test benchmarks setup.py
echo '== pep257 (as ament_pep257 runs it)'
pydocstyle --convention=pep257 --add-ignore=D100,D101,D102,D103,D104,D105,D106,D107,D404 \
  mr_suspension test benchmarks setup.py
echo '== pytest'
python -m pytest -q "$@"
