"""Where a whole PatchMatch run spends its time: seconds per level, pass and red-black iteration.

    .venv/bin/python benchmarks/performance/profile_patchmatch_passes.py [SCENE] [--size 768] [--schedule acmm]
        [--set patchmatch.window=7 ...] [--json benchmarks/results/profile_patchmatch_passes.json]

Runs ``run_patchmatch`` over all views of the scene (5 source views) and sums ``IterationEvent.seconds``
(the two half-steps of one iteration, all views) per (level, pass) and per iteration. What the events
do not cover (initial costs, the detail restorer's reference costs, bilateral moments, upsampling) is
reported as ``outside_iterations``. NCC windows per pixel update (``IterationEvent.ncc_windows``) are
summed per pass. When the scene has GT depth, pooled within 1 % / 5 % is printed too,
so that option sweeps (``--set``) show quality and time side by side.
"""

from __future__ import annotations

import argparse
import collections
import time

import numpy as np

from engine.evaluation.depth import depth_metrics
from engine.patchmatch import PatchMatchOptions, run_patchmatch
from engine.run.pipeline import patchmatch_views
from engine.scene import SceneOptions, load_scene
from support import bench
from workbench.flags.assignments import section_overrides

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"scene": str, "size": list, "views": int, "options": dict, "total_seconds": float,
          "iteration_seconds": float, "outside_iterations": float, "by_pass": list, "by_iteration": list,
          "depth": dict}



class _Timer:
    def __init__(self) -> None:
        self.by_pass: dict[tuple[int, int], float] = collections.defaultdict(float)
        self.by_iter: dict[tuple[int, int, int], float] = collections.defaultdict(float)
        self.windows: dict[tuple[int, int], int] = collections.defaultdict(int)
        self.updates: dict[tuple[int, int], int] = collections.defaultdict(int)

    def on_iteration(self, e) -> None:
        self.by_pass[(e.level, e.pass_index)] += e.seconds
        self.windows[(e.level, e.pass_index)] += e.ncc_windows
        self.updates[(e.level, e.pass_index)] += e.depth.size
        self.by_iter[(e.level, e.pass_index, e.iteration)] += e.seconds


def _pooled_depth(scene, maps) -> dict[str, float] | None:
    """Depth metrics pooled over every view with GT (engine.evaluation.depth.depth_metrics), or None."""
    pairs = [(m.depth.ravel(), gt.ravel()) for i, m in enumerate(maps) if (gt := scene.gt_depth(i)) is not None]
    if not pairs:
        return None
    return depth_metrics(np.concatenate([p[0] for p in pairs]), np.concatenate([p[1] for p in pairs]))


def summary(result: dict) -> list[dict]:
    """Seconds per level and pass of the whole run, and the total with pooled depth within 1 %."""
    rows = [{"level": p["level"], "pass": "photometric" if p["pass_index"] == 0 else f"geometric {p['pass_index']}",
             "seconds": p["seconds"], "windows per update": p["ncc_windows_per_pixel_update"]}
            for p in sorted(result["by_pass"], key=lambda p: (-p["level"], p["pass_index"]))]
    within = (result.get("depth") or {}).get("within_1pct", float("nan"))
    rows.append({"level": "all", "pass": f"total ({result['options'].get('schedule')} schedule, {result['views']} "
                 f"views {result['size'][0]}x{result['size'][1]}, within 1 % {within:.2f})",
                 "seconds": result["total_seconds"]})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", default=str(bench.SHARED_DATA / "fountain_p11"))
    ap.add_argument("--size", type=int, default=768, help="longest image side (0 = the scene's size)")
    ap.add_argument("--schedule", default="acmm")
    ap.add_argument("--set", action="append", default=[], metavar="patchmatch.NAME=VALUE",
                    help="another PatchMatchOptions field as in `deepc run --set`, e.g. patchmatch.window=7")
    ap.add_argument("--json", default=bench.results_path(__file__))
    args = ap.parse_args()
    scene = load_scene(args.scene, SceneOptions(max_image_size=args.size, num_source_views=5) if args.size
                       else SceneOptions(num_source_views=5))
    views = patchmatch_views(scene)
    overrides = section_overrides(args.set, "patchmatch", PatchMatchOptions)
    options = PatchMatchOptions(schedule=args.schedule, **overrides).validate()
    # compile (or load from the cache) every kernel on a small copy first, outside the timing
    small = patchmatch_views(load_scene(args.scene, SceneOptions(max_image_size=96, num_source_views=5)))
    run_patchmatch(small, options.replace(iterations=1, levels=1))
    timer = _Timer()
    t0 = time.perf_counter()
    maps = run_patchmatch(views, options, observer=timer)
    total = time.perf_counter() - t0
    in_iterations = sum(timer.by_pass.values())
    print(f"{'level':>5} {'pass':>11} {'seconds':>9} {'share':>6} {'windows/update':>14}   per iteration")
    for (level, pass_index), sec in sorted(timer.by_pass.items(), key=lambda kv: (-kv[0][0], kv[0][1])):
        iters = [timer.by_iter[k] for k in sorted(timer.by_iter) if k[:2] == (level, pass_index)]
        kind = "photometric" if pass_index == 0 else f"geometric {pass_index}"
        per_update = timer.windows[(level, pass_index)] / max(timer.updates[(level, pass_index)], 1)
        print(f"{level:>5} {kind:>11} {sec:9.1f} {100 * sec / total:5.1f}% {per_update:14.1f}   "
              + " ".join(f"{s:.1f}" for s in iters))
    print(f"total {total:.1f} s, red-black iterations {in_iterations:.1f} s, outside them "
          f"{total - in_iterations:.1f} s")
    depth = _pooled_depth(scene, maps)
    if depth is not None:
        print(f"pooled depth: within 1 % {depth['within_1pct']:.1f} %, within 5 % {depth['within_5pct']:.1f} %")
    bench.write_result({
        "scene": args.scene, "size": list(views[0].image_gray.shape[::-1]), "views": len(views),
        "options": {"schedule": args.schedule, **overrides},
        "total_seconds": total, "iteration_seconds": in_iterations, "outside_iterations": total - in_iterations,
        "by_pass": [{"level": k[0], "pass_index": k[1], "seconds": v,
                     "ncc_windows_per_pixel_update": timer.windows[k] / max(timer.updates[k], 1)}
                    for k, v in sorted(timer.by_pass.items())],
        "by_iteration": [{"level": k[0], "pass_index": k[1], "iteration": k[2], "seconds": v}
                         for k, v in sorted(timer.by_iter.items())],
        "depth": depth}, args.json)
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
