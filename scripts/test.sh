#!/usr/bin/env bash
# Sets up (with test extras and the browser), runs the whole test suite, then (when no pytest arguments are
# given, as in CI) the regression suite sample_scenes/suite.toml against tests/baselines: a quality metric that
# changed beyond its tolerance, either way, fails the script (times are information only, never a failure);
# the report is written to runs/regress/report.html.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh --test
export NUMBA_THREADING_LAYER="${NUMBA_THREADING_LAYER:-workqueue}"
.venv/bin/python -m pytest -q "$@"
if [ "$#" -eq 0 ]; then
    .venv/bin/deepc regress --report runs/regress
fi
