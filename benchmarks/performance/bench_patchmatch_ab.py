"""A/B timing of two PatchMatch engine trees on the same input, with a bit-identity check.

    .venv/bin/python benchmarks/performance/bench_patchmatch_ab.py --baseline ../main_checkout
        [--scene sample_scenes/small] [--size 0] [--rounds 3] [--threads 1]
        [--json benchmarks/results/bench_patchmatch_ab.json]

The machine is shared, so absolute times drift: each case runs the baseline tree and this tree
alternately (A B A B ...) in fresh processes (PYTHONPATH = the tree) and reports the best process CPU
time of each and their ratio. Every run prints an md5 of the final depth, normal, cost and
selected-view maps; the table says whether both trees produced the same bytes.

Cases, all on view 0 of the scene at one level (``--size`` = longest side, 0 = the scene's size):
- ``random``: init cost + 3 red-black iterations from the random initialisation (first photometric pass);
- ``converged``: 3 untimed iterations first, then a new pass (init cost + 2 iterations) from that state, as
  in geometric passes and finer levels (neighbours mostly unchanged between iterations);
- ``converged_geom``: the same with the geometric term; the source depth maps are the scene's ground
  truth where it has one (as in a real geometric pass: most depths agree), else a constant mid-range depth.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

from support import bench

ROOT = bench.REPO_ROOT
# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"baseline": str, "scene": str, "rounds": int, "cases": list}

CASES = {"random": (3, 0, False), "converged": (2, 3, False), "converged_geom": (2, 3, True)}

# runs inside the tree under test; prints one JSON line
WORKER = r'''
import hashlib, json, sys, time
import numpy as np, numba
from engine.scene import load_scene, SceneOptions
from engine.run.pipeline import patchmatch_views
from engine.patchmatch import PatchMatchOptions
from engine.patchmatch import kernels as K
from engine.patchmatch.context import build_context
from engine.patchmatch.rng import stream_key
from engine.patchmatch import ViewState, kernel_params
from engine.patchmatch.view_pass import half_step, init_cost, n_regions, pattern_of
def new_state(h, w):
    return ViewState.zeros(h, w)
def maps(st):
    return st.maps()
def init(st, ctx, t):
    init_cost(st, ctx, params(t))
def step(st, ctx, colour, key, t):
    half_step(st, ctx, colour, st.cost, pattern, key, params(t))
scene, size, threads, reps, T, pre, geom = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), \
    int(sys.argv[5]), int(sys.argv[6]), sys.argv[7] == "1"
sc = load_scene(scene, SceneOptions(max_image_size=size, num_source_views=5))
views = patchmatch_views(sc)
v = views[0]
opts = PatchMatchOptions(schedule="acmm", seed=0)
src = v.source_views
def source_depth(j):
    gt = sc.gt_depth(j)
    return gt if gt is not None else np.full(views[j].image_gray.shape, 0.5 * (v.depth_min + v.depth_max), np.float32)
depths = [source_depth(j) for j in src] if geom else None
ctx = build_context(v.image_gray, v.camera, [views[j].image_gray for j in src], [views[j].camera for j in src], opts,
                    depths)
pattern = pattern_of(opts)
h, w = v.image_gray.shape
numba.set_num_threads(threads)
kinv = np.linalg.inv(v.camera.K_idx).ravel()

def params(t):
    return kernel_params(opts, v.depth_min, v.depth_max, t, geom, False, n_regions(pattern), 2.0 ** -t)

def iterate(st, T, pass_id):
    for t in range(T):
        for colour in (0, 1):
            step(st, ctx, colour, np.uint64(stream_key(0, 0, 0, pass_id, t, colour)), t)

best = None
digest = None
for r in range(reps + 1):  # the first is a warm-up (compilation, page faults)
    st = new_state(h, w)
    K.random_init_kernel(st.depth, st.normal, kinv, v.depth_min, v.depth_max,
                         np.uint64(stream_key(0, 0, 0, 0, 99, 0)), False)
    if pre:
        init(st, ctx, 0)
        iterate(st, pre, 1)
    t0, c0 = time.perf_counter(), time.process_time()
    init(st, ctx, 0)
    iterate(st, T, 0)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    d = hashlib.md5(b"".join(a.tobytes() for a in maps(st))).hexdigest()
    assert digest in (None, d), "run-to-run difference"
    digest = d
    if r > 0 and (best is None or cpu < best[1]):
        best = (wall, cpu)
print(json.dumps({"size": f"{w}x{h}", "wall": best[0], "cpu": best[1], "md5": digest}))
'''


def run_tree(tree: Path, scene: str, size: int, threads: int, reps: int, case: str) -> dict:
    T, pre, geom = CASES[case]
    env = dict(os.environ, PYTHONPATH=str(tree), NUMBA_THREADING_LAYER="workqueue")
    out = subprocess.run([sys.executable, "-c", WORKER, scene, str(size), str(threads), str(reps), str(T), str(pre),
                          "1" if geom else "0"], cwd=tree, env=env, check=True, capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def summary(result: dict) -> list[dict]:
    """Per case: best process CPU seconds of the baseline tree and of this one, speed-up, bit-identical maps."""
    return [{"baseline": result["baseline"], "case": c["case"], "size": c["size"],
             "baseline CPU s": c["baseline_cpu_s"], "this CPU s": c["this_cpu_s"], "speed-up": c["speedup"],
             "identical": c["identical"]} for c in result["cases"]]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", required=True, help="engine tree to compare against (e.g. a checkout of main)")
    ap.add_argument("--scene", default=str(ROOT / "sample_scenes" / "small"))
    ap.add_argument("--size", type=int, default=0, help="longest image side (0 = the scene's size)")
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--rounds", type=int, default=3, help="A/B alternations per case")
    ap.add_argument("--reps", type=int, default=2, help="timed repetitions per process (best is kept)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--json", default=bench.results_path(__file__))
    args = ap.parse_args()
    trees = {"baseline": Path(args.baseline).resolve(), "this": ROOT}
    rows = []
    print(f"{'case':<16} {'size':>9} {'baseline cpu s':>15} {'this cpu s':>11} {'ratio':>6} {'speed-up':>8}  identical")
    for case in args.cases.split(","):
        runs: dict[str, list[dict]] = {"baseline": [], "this": []}
        for _ in range(args.rounds):
            for name, tree in trees.items():
                runs[name].append(run_tree(tree, args.scene, args.size, args.threads, args.reps, case))
        best = {name: min(r["cpu"] for r in rs) for name, rs in runs.items()}
        same = len({r["md5"] for rs in runs.values() for r in rs}) == 1
        row = {"case": case, "size": runs["this"][0]["size"], "threads": args.threads,
               "baseline_cpu_s": best["baseline"], "this_cpu_s": best["this"], "ratio": best["this"] / best["baseline"],
               "speedup": best["baseline"] / best["this"], "identical": same,
               "baseline_runs": runs["baseline"], "this_runs": runs["this"]}
        rows.append(row)
        print(f"{case:<16} {row['size']:>9} {row['baseline_cpu_s']:15.3f} {row['this_cpu_s']:11.3f} "
              f"{row['ratio']:6.3f} {row['speedup']:7.2f}x  {'yes' if same else 'NO'}", flush=True)
    bench.write_result({"baseline": str(trees["baseline"]), "scene": args.scene, "rounds": args.rounds,
                        "cases": rows}, args.json)
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
