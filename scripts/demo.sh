#!/usr/bin/env bash
# Sets up and runs the main job on the default sample scene, watched live in two viewers at once:
#   - the rerun stream: every PatchMatch iteration's maps, view by view (web viewer on 127.0.0.1, or the
#     native viewer when there is a display), also written to runs/<scene>/recording.rrd;
#   - the 3-D viewer at http://127.0.0.1:8080 (viser): the cameras at once, then per view the current depth as
#     a point cloud coloured by its error against GT, and a progress panel (level, pass, iteration, views done,
#     within 1 % so far, the stage after PatchMatch). When the run ends the same page becomes the tuning
#     viewer of the run, on the run's own settings: keep the tab open from the start.
# Uses ACMM's 3/2/2 schedule so the demo takes a few minutes on 2 cores; extra arguments go to
# `deepc run` (e.g. --schedule paper for the paper's up to 8 iterations per pass, --port 8081, or --headless
# for neither viewer).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
scene="${DEEPC_SCENE:-sample_scenes/small}"
name=$(basename "$scene")
echo "demo: open the 3-D viewer's address printed below (\"live 3-D viewer: ...\") before PatchMatch ends"
exec .venv/bin/deepc run "$scene" --out "runs/$name" --record "runs/$name/recording.rrd" --schedule acmm "$@"
