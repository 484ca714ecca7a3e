#!/usr/bin/env bash
# Create ./.venv with the pinned dependencies and the package (editable); idempotent.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null 2>&1 || PY=python3
stamp=.venv/.installed-$(sha1sum requirements.txt setup.py | sha1sum | cut -c1-12)
if [ ! -f "$stamp" ]; then
  if [ ! -x .venv/bin/python ] && ! "$PY" -m venv .venv; then
    # Debian ships venv separately; install it when we may, else say what is missing.
    if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
      rm -rf .venv
      apt-get update -qq && apt-get install -y -qq python3-venv
      "$PY" -m venv .venv
    else
      echo "error: '$PY -m venv' failed; install python3-venv (Debian) and retry" >&2
      exit 1
    fi
  fi
  .venv/bin/python -m pip install -q --upgrade pip
  .venv/bin/python -m pip install -q -r requirements.txt
  .venv/bin/python -m pip install -q --no-deps -e .
  rm -f .venv/.installed-*
  touch "$stamp"
fi
