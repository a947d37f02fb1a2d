"""Cost of the pixel probe and the pass history: PatchMatch time with them off and on, the history's size, and
the latency of a probe and a region re-run on a finished run (engine/run/probe.py).

    nice -n 5 .venv/bin/python benchmarks/performance/bench_probe.py [SCENE] [--max-image-size 768]
        [--schedule acmm] [--repeats 2] [--pixels 8] [--box 96] [--json benchmarks/results/bench_probe.json]

SCENE defaults to sample_scenes/small. 1. ``run_patchmatch`` on all views, alternating off / history on / probe on
(``--pixels`` pixels of view 0) ``--repeats`` times (best wall and CPU time each; CPU seconds of all threads are
the steadier measure on a shared machine); the maps must be bit-identical. 2. A vanilla
``run_pipeline`` with the history into a temporary folder; ``probe_run`` of the ``--pixels`` pixels (the first
call replays the view), then ``rerun_region`` of a ``--box`` square at the view's centre from level 0 pass 0
and pass 1 with the replay cached (median of 3, the interactive latency) and with ``window=7``.

The inspector's latencies (first and second pixel of a view, kept states) are measured by
``benchmarks/performance/inspector_latency.py``.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from engine.patchmatch import PatchMatchOptions, run_patchmatch
from engine.patchmatch.probe.pixel_probe import PixelProbe
from engine.run.pass_history import HISTORY_DIR, PassHistory
from engine.run.pipeline import PipelineOptions, patchmatch_views, run_pipeline
from engine.run.probe import probe_run, rerun_region
from engine.scene import SceneOptions, load_scene
from support import bench

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"scene": str, "views": int, "size": list, "schedule": str, "pixels": int, "box": list,
          "patchmatch_seconds": dict, "patchmatch_seconds_all": dict, "patchmatch_cpu_seconds": dict,
          "identical": bool, "history_mb": float, "stereo_mb": float, "history_ratio": float,
          "pipeline_seconds": float, "probe_run_seconds": float, "region_seconds": dict}


REPO = Path(__file__).resolve().parents[2]


def summary(result: dict) -> list[dict]:
    """One row: the scene, PatchMatch seconds off / history / probe, history size, probe and region latency."""
    t = result["patchmatch_cpu_seconds"]
    return [{"scene": f"{result['scene']} {result['views']} x {result['size'][0]}x{result['size'][1]}",
             "PM off CPU s": t["off"], "history CPU s": t["history"], "probe CPU s": t["probe"],
             "identical": result["identical"], "history MB": result["history_mb"],
             "history / stereo maps": result["history_ratio"], "probe_run s": result["probe_run_seconds"],
             "region s (P0)": result["region_seconds"]["pass0"], "region s (P1)": result["region_seconds"]["pass1"],
             "region s (window 7)": result["region_seconds"]["window7"]}]


def _pixels(width: int, height: int, n: int) -> list[tuple[int, int]]:
    rng = np.random.default_rng(0)
    return [(int(rng.integers(0, width)), int(rng.integers(0, height))) for _ in range(n)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scene", nargs="?", type=Path, default=REPO / "sample_scenes" / "small")
    parser.add_argument("--max-image-size", type=int, default=0)
    parser.add_argument("--schedule", default="acmm")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--pixels", type=int, default=8)
    parser.add_argument("--box", type=int, default=96)
    parser.add_argument("--json", type=Path, default=bench.results_path(__file__))
    args = parser.parse_args()

    scene = load_scene(args.scene, SceneOptions(max_image_size=args.max_image_size))
    views = patchmatch_views(scene)
    pm = PatchMatchOptions(schedule=args.schedule)
    w, h = views[0].camera.width, views[0].camera.height
    pixels = _pixels(w, h, args.pixels)
    times: dict[str, list[float]] = {"off": [], "history": [], "probe": []}
    cpu: dict[str, list[float]] = {k: [] for k in times}  # CPU seconds of all threads: steadier on a shared machine
    maps = {}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeats):
            for variant in times:
                kwargs = {"history": PassHistory(Path(tmp) / "h")} if variant == "history" else (
                    {"probe": PixelProbe(0, pixels)} if variant == "probe" else {})
                t0, c0 = time.perf_counter(), time.process_time()
                maps[variant] = run_patchmatch(views, pm, **kwargs)
                times[variant].append(time.perf_counter() - t0)
                cpu[variant].append(time.process_time() - c0)
                print(f"{variant:>8}: {times[variant][-1]:.2f} s, CPU {cpu[variant][-1]:.2f} s", flush=True)
        identical = all(np.array_equal(getattr(a, k), getattr(b, k)) for other in ("history", "probe")
                        for a, b in zip(maps["off"], maps[other], strict=True)
                        for k in ("depth", "normal", "cost", "selected_views"))

        run = Path(tmp) / "run"
        options = PipelineOptions(patchmatch=pm)
        t0 = time.perf_counter()
        run_pipeline(scene, run, options, history=PassHistory(run / HISTORY_DIR))
        pipeline_seconds = time.perf_counter() - t0
        history_bytes = PassHistory(run / HISTORY_DIR).size_bytes()
        stereo_bytes = sum(p.stat().st_size for p in (run / "stereo").rglob("*") if p.is_file())
        t0 = time.perf_counter()
        probe_run(run, 0, pixels)
        probe_seconds = time.perf_counter() - t0
        cx, cy = max(0, w // 2 - args.box // 2), max(0, h // 2 - args.box // 2)
        box = (cx, cy, min(args.box, w), min(args.box, h))
        region = {}
        for name, kwargs in (("pass0", {}), ("pass1", {"pass_index": 1}), ("window7", {"overrides": {"window": 7}})):
            runs = [rerun_region(run, 0, box, probe_pixels=[(cx + 5, cy + 5)], **kwargs) for _ in range(3)]
            region[name] = statistics.median(r.seconds for r in runs)
            print(f"region {box} {name}: {region[name]:.2f} s, within 1% {runs[0].within_1pct_before} -> "
                  f"{runs[0].within_1pct_after}", flush=True)

    result = {"scene": scene.name, "views": len(views), "size": [w, h], "schedule": args.schedule,
              "pixels": args.pixels, "box": list(box),
              "patchmatch_seconds": {k: min(v) for k, v in times.items()},
              "patchmatch_seconds_all": times, "patchmatch_cpu_seconds": {k: min(v) for k, v in cpu.items()},
              "identical": identical,
              "history_mb": history_bytes / 2**20, "stereo_mb": stereo_bytes / 2**20,
              "history_ratio": history_bytes / stereo_bytes,
              "pipeline_seconds": pipeline_seconds, "probe_run_seconds": probe_seconds, "region_seconds": region}
    bench.print_table(summary(result))
    print(f"wrote {bench.write_result(result, args.json)}")


if __name__ == "__main__":
    main()
