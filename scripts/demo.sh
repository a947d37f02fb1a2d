#!/usr/bin/env bash
# Sets up and runs the main job on the default sample scene: PatchMatch with live rerun streaming,
# a recording in runs/<scene>/recording.rrd, and the fused cloud in the viser viewer at
# http://127.0.0.1:8080. Pass --headless to skip the viewers.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
scene="${DEEPC_SCENE:-sample_scenes/small}"
name=$(basename "$scene")
exec .venv/bin/deepc run "$scene" --out "runs/$name" --record "runs/$name/recording.rrd" "$@"
