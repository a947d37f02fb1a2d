"""The longest call between two safe points (``engine.core.interrupt.check_interrupt``) of each stage at a real size.

    .venv/bin/python benchmarks/reliability/bench_stop_latency.py [--scene ../shared/data/fountain_p11]
        [--size 768] [--views 3] [--json benchmarks/results/bench_stop_latency.json]

A stop request waits for the numba call running when it comes, so the longest such call bounds how long Ctrl-C
takes. Each stage runs on the scene's ground-truth depth as its maps (PatchMatch: view 0's first pass at the
finest level, from random hypotheses, one iteration; counter maps and refinement on the first ``--views`` views,
fusion on all), with every long call wrapped to time each of its calls: PatchMatch's context (window terms, whole
view), initial-cost and half-step row blocks, the counter-map kernel, the fusion kernel (between two chunks of its
output), the refinement's similarity-graph row blocks and its primal-dual steps.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

import engine.consistency as consistency
import engine.fusion.cached as fusion_cached
import engine.patchmatch.context as pm_context
import engine.patchmatch.kernels as pm_kernels
import engine.refinement.graph as ref_graph
import engine.refinement.primal_dual as ref_pd
from engine.consistency import compute_counter_maps
from engine.fusion.options import FusionOptions
from engine.fusion.stream import fuse_views_to_ply
from engine.fusion.views import views_from_scene
from engine.patchmatch import PatchMatchOptions, ViewState, run_view_level
from engine.patchmatch.multiscale import ViewMaps
from engine.refinement.refine import refine_depth
from engine.run.pipeline import patchmatch_views
from engine.scene import SceneOptions, load_scene
from support import bench

CALLS: dict[str, list[float]] = {}

# Top-level keys of this script's result JSON and their types (support/schema.py); the harness adds its own.
SCHEMA = {"scene": str, "size": int, "views": int, "rows": list, "stage_seconds": dict}


def summary(result: dict) -> list[dict]:
    """One row per timed call: how many calls, the longest and the median seconds (a stop waits for one call)."""
    return result["rows"]


def timed(name: str, fn: Callable) -> Callable:
    """``fn`` recording each call's wall seconds under ``name``."""
    def wrapper(*args, **kwargs):
        t = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            CALLS.setdefault(name, []).append(time.perf_counter() - t)
    return wrapper


def normals_facing(depth: np.ndarray, camera) -> np.ndarray:
    """Normals of the GT depth from its gradients, facing the camera (zeros where there is no depth)."""
    rays = camera.pixel_rays()
    pts = rays * depth[..., None]
    n = np.cross(np.gradient(pts, axis=1), np.gradient(pts, axis=0))
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    n[np.einsum("hwc,hwc->hw", n, rays) > 0] *= -1
    n[depth <= 0] = 0
    return n.astype(np.float32)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=str(bench.SHARED_DATA / "fountain_p11"))
    ap.add_argument("--size", type=int, default=768)
    ap.add_argument("--views", type=int, default=3, help="views the counter maps, fusion and refinement use")
    ap.add_argument("--json", default=bench.results_path(__file__))
    args = ap.parse_args()
    context = timed("context: window terms (whole view)", pm_context.build_context)
    consistency.build_context = context
    pm_kernels.init_cost_kernel = timed("patchmatch initial cost block", pm_kernels.init_cost_kernel)
    pm_kernels.half_step_kernel = timed("patchmatch half-step block", pm_kernels.half_step_kernel)
    consistency.counter_kernel = timed("counter map kernel", consistency.counter_kernel)
    fusion_cached.fuse_kernel = timed("fusion kernel", fusion_cached.fuse_kernel)
    ref_graph._graph_kernel = timed("refinement graph block", ref_graph._graph_kernel)
    ref_pd.dual_step = timed("refinement dual step", ref_pd.dual_step)
    ref_pd.primal_step = timed("refinement primal step", ref_pd.primal_step)

    scene = load_scene(args.scene, SceneOptions(max_image_size=args.size))
    every = patchmatch_views(scene)
    depths = [scene.gt_depth(i).astype(np.float32) for i in range(len(every))]
    normals = [normals_facing(d, v.camera) for d, v in zip(depths, every, strict=True)]
    views = every[: args.views]
    for v in views:
        v.source_views = [j for j in v.source_views if j < len(views)]
    maps = [ViewMaps(d, n, np.zeros_like(d), np.zeros(d.shape, np.uint32))
            for d, n in zip(depths[: args.views], normals, strict=False)]
    stage_seconds = {}
    t = time.perf_counter()
    opts = PatchMatchOptions(schedule="acmm", seed=0)
    v = views[0]
    ctx = context(v.image_gray, v.camera, [views[j].image_gray for j in v.source_views],
                        [views[j].camera for j in v.source_views], opts)
    h, w = v.image_gray.shape
    st = ViewState.zeros(h, w)
    pm_kernels.random_init_kernel(st.depth, st.normal, np.linalg.inv(v.camera.K_idx).ravel(), v.depth_min,
                                  v.depth_max, np.uint64(1), False)
    run_view_level(st, ctx, opts, v.depth_min, v.depth_max, iterations=1)
    stage_seconds["patchmatch"] = time.perf_counter() - t
    t = time.perf_counter()
    counter = compute_counter_maps(views, maps)
    stage_seconds["counter maps"] = time.perf_counter() - t
    t = time.perf_counter()
    fusion_views = views_from_scene(scene, depths, normals, None, FusionOptions().check_num_images)
    with tempfile.TemporaryDirectory() as tmp:
        fuse_views_to_ply(Path(tmp) / "fused.ply", fusion_views, FusionOptions())
    stage_seconds["fusion"] = time.perf_counter() - t
    t = time.perf_counter()
    confidence = (counter[0] >= 2).astype(np.float32)
    refine_depth(v.image_gray, depths[0], confidence, v.camera.K_idx, (v.depth_min, v.depth_max), maps[0].normal)
    stage_seconds["refinement"] = time.perf_counter() - t
    rows = [{"call": name, "calls": len(s), "longest s": round(max(s), 3), "median s": round(float(np.median(s)), 3)}
            for name, s in CALLS.items()]
    for row in rows:
        print(f"{row['call']:<32} {row['calls']:>6} calls  longest {row['longest s']:7.3f} s  "
              f"median {row['median s']:7.3f} s")
    print({k: round(s, 1) for k, s in stage_seconds.items()})
    bench.write_result({"scene": args.scene, "size": args.size, "views": args.views, "rows": rows,
                        "stage_seconds": stage_seconds}, args.json)


if __name__ == "__main__":
    main()
