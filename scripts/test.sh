#!/usr/bin/env bash
# Sets up (with test extras and the browser) and runs the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh --test
export NUMBA_THREADING_LAYER="${NUMBA_THREADING_LAYER:-workqueue}"
exec .venv/bin/python -m pytest -q "$@"
