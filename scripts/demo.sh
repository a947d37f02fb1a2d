#!/usr/bin/env bash
# Sets up and runs the main job on the default sample scene: PatchMatch streaming live to rerun (web
# viewer on 127.0.0.1, or the native viewer when there is a display), a recording in
# runs/<scene>/recording.rrd, then the fused cloud in the viser viewer at http://127.0.0.1:8080.
# Uses ACMM's 3/2/2 schedule so the demo takes a few minutes on 2 cores; extra arguments go to
# `deepc run` (e.g. --schedule paper for the paper's 8 iterations per pass, or --headless).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
scene="${DEEPC_SCENE:-sample_scenes/small}"
name=$(basename "$scene")
exec .venv/bin/deepc run "$scene" --out "runs/$name" --record "runs/$name/recording.rrd" --schedule acmm "$@"
