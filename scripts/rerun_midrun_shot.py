"""The README's rerun screenshot: the demo's stream, confidence scored while PatchMatch runs, caught mid-run.

    .venv/bin/python scripts/rerun_midrun_shot.py [--scene sample_scenes/small] [--out docs/rerun.png]
        [--keep runs/midrun.rrd]

Runs the demo's PatchMatch (``scripts/demo.sh``: ACMM's 3/2/2 schedule, the live stream's default
``--stream-confidence-every``) into a recording, stops it in the first geometric pass of the finest level
(``--stop-view``), and replays that recording in the rerun web viewer (headless chromium) with the
``iterations`` layout of the first view: its depth, normals, cost, selected views, error, and the counter,
confidence and GT labels of its latest scored iteration, with the ROC-AUC rising in the scalars.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from screenshots import rerun_shot  # scripts/screenshots.py, beside this script

from engine.core.observer import IterationEvent, NullObserver
from engine.patchmatch import PatchMatchOptions, run_patchmatch
from engine.run.pipeline import PipelineOptions, patchmatch_views
from engine.scene import load_scene
from workbench.rerun.options import DEFAULT_CONFIDENCE_EVERY, StreamOptions
from workbench.rerun.run_recording import open_run_recording


class MidRun(Exception):
    """Raised by :class:`StopAt` to end the run where the screenshot is taken."""


class StopAt(NullObserver):
    """Stops the run after the last iteration of the first geometric pass of level 0 of view ``view``."""

    def __init__(self, view: int, last_iteration: int):
        self.view, self.last_iteration = view, last_iteration

    def on_iteration(self, event: IterationEvent) -> None:
        if (event.level, event.pass_index, event.view, event.iteration) == (0, 1, self.view, self.last_iteration):
            raise MidRun


def record_mid_run(scene_path: Path, path: Path, stop_view: int) -> None:
    scene = load_scene(scene_path)
    options = PipelineOptions(patchmatch=PatchMatchOptions(schedule="acmm")).validate()
    recording = open_run_recording(str(path), scene, options, StreamOptions(confidence_every=DEFAULT_CONFIDENCE_EVERY))
    recording.stream.companions.append(StopAt(stop_view, options.patchmatch.pass_iterations(1) - 1))
    try:
        run_patchmatch(patchmatch_views(scene), options.patchmatch, observer=recording.stream)
    except MidRun:
        pass
    recording.finish()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", type=Path, default=Path("sample_scenes/small"))
    parser.add_argument("--out", type=Path, default=Path("docs/rerun.png"))
    parser.add_argument("--stop-view", type=int, default=3, help="stop after this view's first geometric pass")
    parser.add_argument("--keep", type=Path, default=None, help="keep the recording here")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = args.keep or Path(tmp) / "midrun.rrd"
        record_mid_run(args.scene, path, args.stop_view)
        print(f"recording {path}: {path.stat().st_size / 1e6:.1f} MB")
        rerun_shot(path, args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
