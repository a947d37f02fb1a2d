"""Fresh against reused (pooled) arrays for the per-pass work of one view: window terms and cost caches.

    .venv/bin/python benchmarks/performance/bench_patchmatch_buffers.py [--scene /work/shared/data/fountain_p11]
        [--size 768] [--view 5] [--rounds 5] [--json benchmarks/results/bench_patchmatch_buffers.json]

Every view pass of a PatchMatch run builds its reference window terms (two (H, W, 36) float32 arrays) and
(re)starts its cost caches (P, the candidate row cache): ~300 MB at 768x512 with 5 sources. Allocated fresh,
each 4 KiB page faults when first written, inside the parallel kernels. The engine hands these arrays to a
``buffers.BufferPool`` after each pass and takes them again for the next view. This measures one view's
window terms and its initial cost (which allocates the caches) both ways, alternating fresh and pooled in one
process, best of ``--rounds``, with the numba threads of the run (default: all); and the initial cost with one
half-step from the random start, whose first writes of the row cache are where its pages fault.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from engine.patchmatch import PatchMatchOptions, ViewState, kernel_params
from engine.patchmatch.buffers import BufferPool
from engine.patchmatch.context import build_context, fine_window_region
from engine.patchmatch.kernels import random_init_kernel
from engine.patchmatch.view_pass import half_step, init_cost, n_regions, pattern_of
from engine.run.pipeline import patchmatch_views
from engine.scene import SceneOptions, load_scene
from support import bench

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"scene": str, "size": list, "view": int, "rounds": int, "rows": dict, "how": str}



def summary(result: dict) -> list[dict]:
    """Per stage: best milliseconds with fresh and with pooled arrays, and their ratio."""
    return [{"stage": name, "fresh ms": 1e3 * r["fresh_s"], "pooled ms": 1e3 * r["pooled_s"], "ratio": r["ratio"]}
            for name, r in result["rows"].items()]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", type=Path, default=bench.SHARED_DATA / "fountain_p11")
    ap.add_argument("--size", type=int, default=768)
    ap.add_argument("--view", type=int, default=5)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--json", default=str(bench.results_path(__file__)), help="output file ('' = none)")
    args = ap.parse_args()
    scene = load_scene(args.scene, SceneOptions(max_image_size=args.size, num_source_views=5))
    views = patchmatch_views(scene)
    v = views[args.view]
    opts = PatchMatchOptions(schedule="acmm").validate()
    h, w = v.image_gray.shape
    # a plausible hypothesis map: random planes (the band of the fine window then covers much of the image, the
    # costs are as expensive as anywhere)
    st = ViewState.zeros(h, w)
    kinv = np.linalg.inv(v.camera.K_idx).ravel()
    random_init_kernel(st.depth, st.normal, kinv, float(v.depth_min), float(v.depth_max), np.uint64(1), False)
    band = fine_window_region(st.depth, st.normal, v.camera, opts)
    imgs = [views[j].image_gray for j in v.source_views]
    cams = [views[j].camera for j in v.source_views]
    pattern = pattern_of(opts)
    params = kernel_params(opts, v.depth_min, v.depth_max, 0, False, False, n_regions(pattern))

    def context(pool: BufferPool | None) -> float:
        t = time.perf_counter()
        ctx = build_context(v.image_gray, v.camera, imgs, cams, opts, None, band, pool)
        seconds = time.perf_counter() - t
        if pool is not None:
            ctx.release(pool)
        return seconds

    ctx = build_context(v.image_gray, v.camera, imgs, cams, opts, None, band)

    def costs(pool: BufferPool | None) -> float:
        t = time.perf_counter()
        init_cost(st, ctx, params, pool=pool)
        seconds = time.perf_counter() - t
        st.drop_caches(pool=pool)
        return seconds

    Z0, N0 = st.depth.copy(), st.normal.copy()

    def half(pool: BufferPool | None) -> float:
        st.depth[:], st.normal[:] = Z0, N0
        t = time.perf_counter()
        init_cost(st, ctx, params, pool=pool)
        half_step(st, ctx, 0, st.cost, pattern, np.uint64(7), params)
        seconds = time.perf_counter() - t
        st.drop_caches(pool=pool)
        return seconds

    pool = BufferPool()
    rows = {}
    for name, fn in (("window terms", context), ("initial cost + caches", costs),
                     ("initial cost + half-step", half)):
        fn(pool)  # compile, fill the pool
        fresh, pooled = [], []
        for _ in range(args.rounds):
            fresh.append(fn(None))
            pooled.append(fn(pool))
        rows[name] = {"fresh_s": min(fresh), "pooled_s": min(pooled), "ratio": min(fresh) / min(pooled)}
    print(f"{scene.name} {w}x{h}, view {args.view}, best of {args.rounds}")
    print(f"{'stage':24s} {'fresh ms':>9s} {'pooled ms':>9s} {'ratio':>6s}")
    for name, r in rows.items():
        print(f"{name:24s} {1e3 * r['fresh_s']:9.1f} {1e3 * r['pooled_s']:9.1f} {r['ratio']:6.2f}")
    if args.json:
        bench.write_result({"scene": scene.name, "size": [w, h], "view": args.view, "rounds": args.rounds,
                            "rows": rows, "how": "alternating fresh / pooled in one process, best of rounds"},
                           args.json)
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
