"""The pixel inspector's latencies on a finished run: the first pixel of a view, a second pixel of the same view,
that pixel again from the disk store alone (as a new process would), and a region re-run, three ways.

    nice -n 19 .venv/bin/python benchmarks/performance/inspector_latency.py sample_scenes/fountain_p11
        [--max-image-size 384] [--schedule acmm] [--run OUT] [--view 0] [--box 96]

A vanilla run of SCENE with its pass history (or the finished run ``--run``). "whole replay": every probe replays
the view whole (``probe_run(stored_states=False)``); "kept by the first probe": the run's recorded states removed,
the first probe of a view replays it whole and keeps its pass-start states in ``OUT/history/states/``, later ones
trace from them; "recorded by the run": the states ``deepc run`` recorded (``engine/run/probe_states.py``), so the
first probe traces from them too. The second pixel's trace must be the same JSON every way. One probe of another
view first compiles and loads everything (not timed). Wall and CPU seconds (all threads: the steadier measure on
a shared machine). Writes ``inspector_latency_<scene><size>.json``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
import time
from pathlib import Path

from engine.patchmatch import PatchMatchOptions
from engine.run.folder import run_scene
from engine.run.pass_history import HISTORY_DIR, PassHistory
from engine.run.pipeline import PipelineOptions, patchmatch_views, run_pipeline
from engine.run.probe import forget_replays, probe_run, rerun_region
from engine.run.probe_states import STATES_DIR, StateStore
from engine.scene import SceneOptions, load_scene
from support import bench

# Top-level keys of this script's result JSON and their types (support/schema.py); the harness adds its own.
SCHEMA = {"scene": str, "size": list, "schedule": str, "view": int, "first": list, "second": list, "box": list,
          "latency": list, "identical_traces": bool}


def summary(result: dict) -> list[dict]:
    """One row per variant (where the pass-start states come from): seconds of the first and second pixel and the
    region."""
    return [{"scene": f"{result['scene']} {result['size'][0]}x{result['size'][1]} {result['schedule']}", **row}
            for row in result["latency"]]


def latency(run: Path, view: int, box_side: int) -> dict:
    """The inspector's latencies on the finished run ``run``, by where the pass-start states come from (module
    doc)."""
    camera = patchmatch_views(run_scene(run))[view].camera
    width, height = camera.width, camera.height
    first, second = (width // 3, height // 2), (2 * width // 3, height // 3)
    box = (max(0, width // 2 - box_side // 2), max(0, height // 2 - box_side // 2), min(box_side, width),
           min(box_side, height))
    other = 1 if view == 0 else 0
    probe_run(run, other, [(1, 1)], stored_states=False)  # compile and load everything (not timed)
    rows, traces = [], {}

    def timed(row: dict, name: str, fn, *args, **kwargs):
        """Call ``fn``; its wall and CPU seconds (all threads: steadier on a shared machine) into ``row``."""
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn(*args, **kwargs)
        row[f"{name} s"], row[f"{name} CPU s"] = time.perf_counter() - t0, time.process_time() - c0
        return out

    states = run / HISTORY_DIR / STATES_DIR
    recorded = run / HISTORY_DIR / "states_recorded_by_the_run"
    shutil.rmtree(recorded, ignore_errors=True)
    if states.is_dir():
        shutil.copytree(states, recorded)
    for variant in ("whole replay", "kept by the first probe", "recorded by the run"):
        forget_replays()
        shutil.rmtree(states, ignore_errors=True)
        if variant == "recorded by the run":
            if not recorded.is_dir():
                continue  # a run made before runs recorded their states
            shutil.copytree(recorded, states)
        keep = variant != "whole replay"
        row: dict = {"variant": variant}
        timed(row, "first pixel", probe_run, run, view, [first], stored_states=keep)
        traces[variant] = timed(row, "second pixel", probe_run, run, view, [second], stored_states=keep)
        if keep:
            forget_replays()  # as a new process: the states from disk
            again = timed(row, "second from disk", probe_run, run, view, [second])
            assert json.dumps(again, sort_keys=True) == json.dumps(traces[variant], sort_keys=True)
            row["states MB"] = StateStore(states).size_bytes() / 2**20
        timed(row, "region P1", rerun_region, run, view, box, pass_index=1)
        print(row, flush=True)
        rows.append(row)
    shutil.rmtree(recorded, ignore_errors=True)
    identical = len({json.dumps(t, sort_keys=True) for t in traces.values()}) == 1
    return {"view": view, "first": list(first), "second": list(second), "box": list(box), "latency": rows,
            "identical_traces": identical}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scene", type=Path)
    parser.add_argument("--max-image-size", type=int, default=0)
    parser.add_argument("--schedule", default="acmm")
    parser.add_argument("--run", type=Path, help="a finished run (with history/) instead of a new one")
    parser.add_argument("--view", type=int, default=0)
    parser.add_argument("--box", type=int, default=96)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        run = args.run
        if run is None:
            run = Path(tmp) / "run"
            scene = load_scene(args.scene, SceneOptions(max_image_size=args.max_image_size))
            run_pipeline(scene, run, PipelineOptions(patchmatch=PatchMatchOptions(schedule=args.schedule)),
                         history=PassHistory(run / HISTORY_DIR))
        scene = run_scene(run)
        camera = patchmatch_views(scene)[args.view].camera
        schedule = PipelineOptions.from_dict(
            {k: v for k, v in json.loads((run / "metrics.json").read_text())["options"].items() if k != "scene"},
            saved=True).patchmatch.schedule
        result = {"scene": scene.name, "size": [camera.width, camera.height], "schedule": schedule,
                  **latency(run, args.view, args.box)}
    bench.print_table(summary(result))
    size = f"{max(camera.width, camera.height)}"
    print(f"wrote {bench.write_result(result, bench.results_path(__file__, f'{scene.name}{size}'))}")


if __name__ == "__main__":
    main()
