"""Size of a run's recording against its budget: the demo's recording, made as ``scripts/demo.sh`` makes it.

    .venv/bin/python benchmarks/performance/bench_recording.py [--scene sample_scenes/small] [--schedule acmm]
        [--budget-mb 15] [--full] [--json benchmarks/results/bench_recording.json]

Runs the pipeline with a recording as the demo does (ACMM's schedule, counter and confidence scored every third
iteration as when streaming live) with the stream's budget plan (``workbench/rerun/budget.py``), and with
``--full`` also with whole maps of every iteration (the budget off), and prints a table: file size, the plan
(map size, every k-th iteration), the budget's estimate, and the compressed size of each kind of map (each
kind written to a recording of its own). The constants of ``workbench/rerun/budget.py`` come from these rows.
"""

from __future__ import annotations

import argparse
import os
import re
import tempfile
from pathlib import Path

from engine.patchmatch import PatchMatchOptions, effective_levels
from engine.run.pipeline import PipelineOptions, run_pipeline
from engine.scene import load_scene
from support import bench
from workbench.rerun.budget import logged_iterations, planned_bytes
from workbench.rerun.options import StreamOptions
from workbench.rerun.run_recording import open_run_recording, recording_plan

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"scene": str, "schedule": str, "rows": list}
# The shipped networks this script runs by default: their sha256 is recorded with every result.
WEIGHTS = ("deepc_middle.pt",)

KINDS = ("depth", "normal", "cost", "error", "selected_count", "selected_views", "counter", "confidence", "label")


def kind_sizes(path: Path) -> dict[str, float]:
    """MB of each kind of map, of the fused cloud and of the cameras, each written alone (rerun compresses)."""
    from rerun.chunk import RrdReader  # lazy: rerun

    summary = str(RrdReader(str(path)).stream().collect().summary())
    views = sorted(set(re.findall(r"^/maps/([^/ ]+)/", summary, re.M)))
    groups = {kind: [f"/maps/{v}/{kind}" for v in views] for kind in KINDS}
    groups.update(cloud="/world/fused/**", cameras="/world/cameras/**")
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, content in groups.items():
            target = Path(tmp) / f"{name}.rrd"
            RrdReader(str(path)).stream().filter(content=content).write_rrd(str(target), application_id="x",
                                                                          recording_id="y")
            out[name] = os.path.getsize(target) / 1e6
    return out


def record(scene, options: PipelineOptions, stream_options: StreamOptions, folder: Path) -> dict:
    plan = recording_plan(scene, options, stream_options)
    pm = options.patchmatch
    recording = open_run_recording(str(folder / "recording.rrd"), scene, options, stream_options, live_url=None)
    # as live: counter and confidence scored every third iteration
    with bench.Stopwatch() as watch:
        run_pipeline(scene, folder / "out", options, observer=recording.stream)
        recording.finish()
    sizes = [(v.camera.width, v.camera.height) for v in scene.views]
    estimate = planned_bytes(sizes, effective_levels(scene.views, pm),
                             logged_iterations([pm.pass_iterations(p) for p in range(1 + pm.geom_passes)],
                                               plan.every), plan.max_size, plan.max_points)
    return {"budget_mb": stream_options.budget_mb, "map_size": plan.max_size, "every": plan.every,
            "estimate_mb": estimate / 1e6, "file_mb": (folder / "recording.rrd").stat().st_size / 1e6,
            "seconds": watch.wall, "kinds_mb": kind_sizes(folder / "recording.rrd")}


def summary(result: dict) -> list[dict]:
    """Per case: the plan (map size, every k-th iteration), the budget's estimate and the file's size (MB)."""
    return [{"case": r["case"], "budget MB": r["budget_mb"], "map size": r["map_size"], "every": r["every"],
             "estimate MB": r["estimate_mb"], "file MB": r["file_mb"], "seconds": r["seconds"]}
            for r in result["rows"]]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="sample_scenes/small")
    parser.add_argument("--schedule", default="acmm")
    parser.add_argument("--budget-mb", type=float, default=StreamOptions().budget_mb)
    parser.add_argument("--full", action="store_true", help="also record whole maps of every iteration")
    parser.add_argument("--json", default=str(bench.results_path(__file__)))
    args = parser.parse_args(argv)
    scene = load_scene(args.scene)
    options = PipelineOptions(patchmatch=PatchMatchOptions(schedule=args.schedule))
    cases = {"budget": StreamOptions(budget_mb=args.budget_mb, confidence_every=3)}
    if args.full:
        cases["whole maps"] = StreamOptions(max_size=0, every=1, confidence_every=3)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, stream_options in cases.items():
            folder = Path(tmp) / name.replace(" ", "_")
            folder.mkdir()
            rows.append({"case": name, **record(scene, options, stream_options, folder)})
    bench.print_table([{k: v for k, v in r.items() if k != "kinds_mb"} for r in rows])
    bench.print_table([{"case": r["case"], **r["kinds_mb"]} for r in rows])
    bench.write_result({"scene": args.scene, "schedule": args.schedule, "rows": rows}, args.json)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
