"""Refinement benchmark: speed and memory at 768x512, and the fast solver against the Adam reference.

    .venv/bin/python benchmarks/performance/bench_refinement.py [--run runs/fountain768] [--view 0]
        [--crops 64x96,96x128] [--skip-full] [--fast-iters 300,300,250,500]
        [--json benchmarks/results/bench_refinement.json]

Input: one view of a vanilla ``deepc run`` (depth, normal, counter maps); confidence = the run's
confidence maps or, without them, the proxy min(K, 3)/3 of the counter map (as table3_refinement.py).

1. Full map (fast solver, default schedule): wall and CPU seconds (CPU = process time of all threads,
   i.e. ~2x the wall time an idle 2-core machine needs), iterations and seconds per scale, peak RSS.
   The machine is shared, so wall time under other load overstates the cost; both are reported.
2. Crops (top-left at the map centre): both solvers with their default multi-scale schedules on the
   same input; final energy of the finest scale (the same energy and graph for both) and their ratio
   (target: fast <= 1.01 x Adam).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from engine.io.images import to_gray
from engine.refinement import RefinementOptions, refine_depth
from engine.run.folder import read_map
from support import bench
from workbench.viewer.session import ViewerSession

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"scene": str, "view": str, "size": list, "confidence": str, "full": dict, "crops": list}



def view_inputs(run_dir: Path, view: int) -> dict:
    session = ViewerSession.open(run_dir)
    scene, data = session.scene, session.data[view]
    v = scene.views[view]
    conf = data.confidence
    source = "network"
    if conf is None:
        conf = np.minimum(read_map(run_dir, "counter", v.name), 3.0) / 3.0
        source = "proxy min(K,3)/3"
    return {"scene": scene.name, "view": v.name, "gray": to_gray(scene.image(view)), "depth": data.depth,
            "normal": data.normal, "confidence": conf, "K": v.camera.K_idx, "range": v.depth_range,
            "confidence_source": source}


def crop(inp: dict, h: int, w: int) -> dict:
    H, W = inp["depth"].shape
    r0, c0 = (H - h) // 2, (W - w) // 2
    out = dict(inp)
    for key in ("gray", "depth", "normal", "confidence"):
        out[key] = inp[key][r0:r0 + h, c0:c0 + w]
    K = inp["K"].copy()
    K[0, 2] -= c0
    K[1, 2] -= r0
    out["K"] = K
    return out


def run_refine(inp: dict, options: RefinementOptions):
    with bench.Stopwatch() as watch:
        res = refine_depth(inp["gray"], inp["depth"], inp["confidence"], inp["K"], inp["range"], inp["normal"],
                           options)
    return res, watch.cpu


def summary(result: dict) -> list[dict]:
    """The full map's wall and CPU seconds and peak memory; per crop the fast solver's final energy over Adam's."""
    rows = []
    if "full" in result:
        f = result["full"]
        rows.append({"input": f"full {result['size'][0]}x{result['size'][1]}", "wall s": f["seconds"],
                     "CPU s": f["cpu_seconds"], "peak RSS MiB": f["peak_rss_mb"]})
    rows += [{"input": f"crop {c['crop'][0]}x{c['crop'][1]}", "wall s": c["seconds_fast"], "CPU s": c["cpu_fast"],
              "Adam wall s": c["seconds_adam"], "energy fast / Adam": c["ratio"]} for c in result["crops"]]
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, default=Path("runs/fountain768"))
    parser.add_argument("--view", type=int, default=0)
    parser.add_argument("--crops", default="64x96,96x128", help="HxW list, comma-separated ('' = none)")
    parser.add_argument("--skip-full", action="store_true")
    parser.add_argument("--fast-iters", default="", help="primal-dual iterations per scale for the full map")
    parser.add_argument("--json", type=Path, default=bench.results_path(__file__))
    args = parser.parse_args()
    inp = view_inputs(args.run, args.view)
    h, w = inp["depth"].shape
    print(f"{inp['scene']} view {inp['view']} ({w}x{h}), confidence: {inp['confidence_source']}")
    result: dict = {"scene": inp["scene"], "view": inp["view"], "size": [w, h],
                    "confidence": inp["confidence_source"]}
    # Warm the numba caches so compile time is not counted.
    run_refine(crop(inp, 16, 16), RefinementOptions(scales=1, iters=(1,), lr=(1e-3,), lr_slots=(1,), fast_iters=(1,)))
    if not args.skip_full:
        fast_iters = tuple(int(v) for v in args.fast_iters.split(",") if v.strip())
        res, cpu = run_refine(inp, RefinementOptions(fast_iters=fast_iters) if fast_iters else RefinementOptions())
        full = {"solver": "fast", "seconds": res.seconds, "cpu_seconds": cpu, "shapes": res.shapes,
                "iterations_per_scale": res.iterations, "seconds_per_scale": res.seconds_per_scale,
                "energy_per_scale": res.energy,
                "peak_rss_mb": bench.peak_rss_mb()}
        result["full"] = full
        print(f"full map, fast solver: {res.seconds:.1f} s wall, {cpu:.1f} s CPU; iterations per scale "
              f"{res.iterations}; seconds per scale {[round(s, 2) for s in res.seconds_per_scale]}; "
              f"peak RSS {full['peak_rss_mb']:.0f} MB")
    rows = []
    for spec in filter(None, args.crops.split(",")):
        ch, cw = (int(x) for x in spec.split("x"))
        c = crop(inp, ch, cw)
        fast, fast_cpu = run_refine(c, RefinementOptions(solver="fast"))
        adam, adam_cpu = run_refine(c, RefinementOptions(solver="adam"))
        rel = np.abs(fast.depth - adam.depth) / adam.depth
        row = {"crop": [cw, ch], "energy_fast": fast.energy[-1], "energy_adam": adam.energy[-1],
               "ratio": fast.energy[-1] / adam.energy[-1], "seconds_fast": fast.seconds, "seconds_adam": adam.seconds,
               "cpu_fast": fast_cpu, "cpu_adam": adam_cpu, "iterations_fast": fast.iterations,
               "iterations_adam": adam.iterations, "median_rel_depth_diff": float(np.median(rel)),
               "p95_rel_depth_diff": float(np.percentile(rel, 95))}
        rows.append(row)
        print(f"crop {cw}x{ch}: E fast {row['energy_fast']:.6g} / E adam {row['energy_adam']:.6g} = "
              f"{row['ratio']:.4f}; {fast.seconds:.1f} s vs {adam.seconds:.1f} s wall; depth difference median "
              f"{100 * row['median_rel_depth_diff']:.3f} %, p95 {100 * row['p95_rel_depth_diff']:.3f} %", flush=True)
    result["crops"] = rows
    bench.write_result(result, args.json)
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
