"""What the row blocks of PatchMatch's kernels cost: one call per view against ``engine.core.blocks.RowPacer``'s blocks.

    .venv/bin/python benchmarks/performance/bench_row_blocks.py [--scene ../shared/data/fountain_p11] [--size 768]
        [--rounds 3] [--json benchmarks/results/bench_row_blocks.json]

In one process (same compiled kernels), alternately (A B A B ...): the initial cost and one red-black iteration of
view 0 from the same random hypotheses, as one kernel call per half-step (``pacer=None``) and as the run's row blocks
(``view_pass.PACER``, ~0.5 s each). Reports the best wall and CPU seconds of each, their ratios, the blocks per
call and whether both gave the same maps (they must: the blocks only split the rows).
"""

from __future__ import annotations

import argparse
import hashlib

import numpy as np

import engine.patchmatch.kernels as K
from engine.core.blocks import BLOCK_SECONDS, RowPacer
from engine.patchmatch import PatchMatchOptions, ViewState, kernel_params
from engine.patchmatch.context import build_context
from engine.patchmatch.rng import stream_key
from engine.patchmatch.view_pass import half_step, init_cost, n_regions, pattern_of
from engine.run.pipeline import patchmatch_views
from engine.scene import SceneOptions, load_scene
from support import bench


class CountingPacer(RowPacer):
    """The run's pacer, counting its blocks."""

    blocks = 0

    def run(self, kind, height, width, call):  # noqa: ANN001, ANN201
        def counted(start: int, stop: int) -> None:
            self.blocks += 1
            call(start, stop)
        super().run(kind, height, width, counted)


# Top-level keys of this script's result JSON and their types (support/schema.py); the harness adds its own.
SCHEMA = {"scene": str, "size": str, "rounds": int, "target_s": float, "blocks_per_iteration": (int, None),
          "one_call_wall_s": float, "blocks_wall_s": float, "one_call_cpu_s": float, "blocks_cpu_s": float,
          "wall_ratio": float, "cpu_ratio": float, "identical": bool, "runs": dict}


def summary(result: dict) -> list[dict]:
    """One row: best wall and CPU seconds of one call per view against row blocks, their ratios, identical maps."""
    return [{"scene": f"{result['scene']} {result['size']}", "blocks": result["blocks_per_iteration"],
             "wall ratio": result["wall_ratio"], "CPU ratio": result["cpu_ratio"], "identical": result["identical"]}]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=str(bench.SHARED_DATA / "fountain_p11"))
    ap.add_argument("--size", type=int, default=768)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--target", type=float, default=BLOCK_SECONDS, help="seconds a block aims at")
    ap.add_argument("--json", default=bench.results_path(__file__))
    args = ap.parse_args()
    scene = load_scene(args.scene, SceneOptions(max_image_size=args.size))
    views = patchmatch_views(scene)
    v = views[0]
    opts = PatchMatchOptions(schedule="acmm", seed=0)
    ctx = build_context(v.image_gray, v.camera, [views[j].image_gray for j in v.source_views],
                        [views[j].camera for j in v.source_views], opts)
    pattern = pattern_of(opts)
    h, w = v.image_gray.shape
    start = ViewState.zeros(h, w)
    K.random_init_kernel(start.depth, start.normal, np.linalg.inv(v.camera.K_idx).ravel(), v.depth_min, v.depth_max,
                         np.uint64(stream_key(0, 0, 0, 0, 99, 0)), False)
    pacer = CountingPacer(args.target)
    times: dict[str, list[tuple[float, float]]] = {"one call": [], "blocks": []}
    digests: dict[str, set[str]] = {"one call": set(), "blocks": set()}
    calls = 0
    for r in range(args.rounds + 1):  # the first round is a warm-up (page faults, the pacer's first rate)
        for name, p in (("one call", None), ("blocks", pacer)):
            st = start.copy_maps()
            pacer.blocks = 0
            with bench.Stopwatch() as watch:
                init_cost(st, ctx, kernel_params(opts, v.depth_min, v.depth_max, 0, False, False, n_regions(pattern)),
                          pacer=p)
                params = kernel_params(opts, v.depth_min, v.depth_max, 0, False, False, n_regions(pattern), 1.0)
                for colour in (0, 1):
                    half_step(st, ctx, colour, st.cost, pattern, np.uint64(stream_key(0, 0, 0, 0, 0, colour)), params,
                              pacer=p)
            digests[name].add(hashlib.md5(b"".join(a.tobytes() for a in st.maps())).hexdigest())
            if r > 0:
                times[name].append((watch.wall, watch.cpu))
            if p is not None:
                calls = pacer.blocks
            print(f"round {r} {name:<8} wall {watch.wall:7.2f} s cpu {watch.cpu:7.2f} s", flush=True)
    best = {name: (min(t[0] for t in ts), min(t[1] for t in ts)) for name, ts in times.items()}
    result = {"scene": args.scene, "size": f"{w}x{h}", "rounds": args.rounds, "target_s": args.target,
              "blocks_per_iteration": calls,
              "one_call_wall_s": best["one call"][0], "blocks_wall_s": best["blocks"][0],
              "one_call_cpu_s": best["one call"][1], "blocks_cpu_s": best["blocks"][1],
              "wall_ratio": best["blocks"][0] / best["one call"][0],
              "cpu_ratio": best["blocks"][1] / best["one call"][1],
              "identical": len(digests["one call"] | digests["blocks"]) == 1, "runs": times}
    print(f"{w}x{h}: {calls} blocks (initial cost + 2 half-steps); best wall blocks/one call "
          f"{result['wall_ratio']:.3f}, CPU {result['cpu_ratio']:.3f}; identical maps: {result['identical']}")
    bench.write_result(result, args.json)


if __name__ == "__main__":
    main()
