#!/usr/bin/env bash
# Install everything into ./.venv and run the default demo (first README command).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/venv.sh
.venv/bin/mr-suspension demo --out out/demo "$@"
