"""Cost of streaming PatchMatch to rerun, and the size of a recording.

    .venv/bin/python benchmarks/performance/bench_stream.py [--scene sample_scenes/small] [--iterations 2] [--repeats 2]
                                                [--out benchmarks/results/bench_stream.json]

Runs the same PatchMatch twice per repeat, without an observer and with the rerun stream writing an
.rrd (default thinning), alternating, and reports the overhead as a ratio of the best times (target:
at most 10 % of engine time). The recording size is extrapolated to the full default schedule from the
bytes per logged view-iteration (target: under 200 MB for the demo scene).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from engine.patchmatch import PatchMatchOptions, run_patchmatch
from engine.run.pipeline import patchmatch_views
from engine.scene import load_scene
from support import bench
from workbench.rerun.recording import Recording
from workbench.rerun.stream import RerunStream, StreamOptions

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"scene": str, "views": int, "size": list, "iterations_per_pass": int, "engine_s": list,
          "with_stream_s": list, "overhead_pct": float, "rrd_bytes": int, "logged_view_iterations": int,
          "rrd_bytes_full_default_schedule": float, "targets": dict}



def timed_run(scene, options: PatchMatchOptions, record: Path | None) -> tuple[float, int, int]:
    views = patchmatch_views(scene)
    recording = stream = None
    if record is not None:
        recording = Recording(record)
        stream = RerunStream(recording.rec, [(v.name, v.camera, scene.image(v.index), v.source_views)
                                             for v in scene.views],
                             [scene.gt_depth(v.index) for v in scene.views], StreamOptions(),
                             pass_iterations=options.pass_iterations)
        stream.set_depth_ranges([v.depth_range for v in scene.views])
    start = time.perf_counter()
    run_patchmatch(views, options, observer=stream)
    if recording is not None:
        recording.finish()
    seconds = time.perf_counter() - start
    return seconds, (record.stat().st_size if record else 0), (stream.logged_steps if stream else 0)


def summary(result: dict) -> list[dict]:
    """Best engine seconds without and with the rerun stream, the overhead and the recording size."""
    return [{"scene": result["scene"], "engine s": min(result["engine_s"]),
             "with stream s": min(result["with_stream_s"]), "overhead %": result["overhead_pct"],
             "recording MB": result["rrd_bytes"] / 1e6,
             "full schedule MB": result["rrd_bytes_full_default_schedule"] / 1e6}]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", type=Path, default=bench.REPO_ROOT / "sample_scenes" / "small")
    parser.add_argument("--iterations", type=int, default=2, help="iterations per pass for the timing runs")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--out", type=Path, default=bench.results_path(__file__))
    args = parser.parse_args()

    scene = load_scene(args.scene)
    options = PatchMatchOptions(iterations=args.iterations)
    timed_run(scene, PatchMatchOptions(iterations=1, levels=1, geom_passes=0), None)  # compile / warm caches
    plain, streamed, size, logged = [], [], 0, 0
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.repeats):
            plain.append(timed_run(scene, options, None)[0])
            seconds, size, logged = timed_run(scene, options, Path(tmp) / f"run{r}.rrd")
            streamed.append(seconds)
    overhead = 100.0 * (min(streamed) / min(plain) - 1.0)
    default = PatchMatchOptions()
    levels = default.levels
    passes = 1 + default.geom_passes
    iters_default = levels * sum(default.pass_iterations(p) for p in range(passes))
    iters_here = levels * passes * args.iterations
    full_size = size / iters_here * iters_default
    result = {"scene": scene.name, "views": len(scene.views),
              "size": [scene.views[0].camera.width, scene.views[0].camera.height],
              "iterations_per_pass": args.iterations, "engine_s": plain, "with_stream_s": streamed,
              "overhead_pct": overhead, "rrd_bytes": size, "logged_view_iterations": logged,
              "rrd_bytes_full_default_schedule": full_size,
              "targets": {"overhead_pct": 10.0, "rrd_mb_demo": 200}}
    print(f"{scene.name}: {len(scene.views)} views {result['size'][0]}x{result['size'][1]}, "
          f"{args.iterations} iterations per pass")
    print(f"{'run':<14} {'best s':>8} {'all s':>24}")
    print(f"{'engine':<14} {min(plain):>8.2f} {', '.join(f'{t:.2f}' for t in plain):>24}")
    print(f"{'engine+stream':<14} {min(streamed):>8.2f} {', '.join(f'{t:.2f}' for t in streamed):>24}")
    print(f"overhead {overhead:.1f} % (target <= 10 %); recording {size / 1e6:.1f} MB for {logged} logged "
          f"view-iterations; full default schedule ({iters_default} iterations per view): "
          f"{full_size / 1e6:.0f} MB (target < 200 MB)")
    bench.write_result(result, args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
