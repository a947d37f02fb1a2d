"""Refinement with the structure of the paper's Table 3 (ours; ours refined; ours refined + conf 0.05).

    .venv/bin/python benchmarks/paper/table3_refinement.py RUN_DIR --out OUT_DIR [--proxy-confidence counter]
        [--solver fast|adam] [--reuse] [--views 0,1,2] [--json benchmarks/results/table3_refinement_<scene>.json]
    .venv/bin/python benchmarks/paper/table3_refinement.py VANILLA_RUN_DIR --weights NET1.pt [--refined-weights NET2.pt]

The second form computes what ``--pipeline fast`` and ``full`` compute, from a finished vanilla run:
network-1 confidence, the refinement through ``engine.run.refine.refine_run`` (cached in
RUN_DIR/refined/), the refined maps' counter maps and their confidence from the second network.

RUN_DIR is the output folder of ``deepc run`` (CONTRACT.md §4). Every view is refined (SPEC.md §6) with
the run's confidence maps; a vanilla run has none, and then ``--proxy-confidence counter`` stands in
for the network: c = min(K, 3) / 3 from the counter maps K (said in the output). Refined maps are
written to OUT_DIR/refined/{depth,normal}_maps (``--reuse`` reads back those that exist instead of refining).
``--views`` limits refinement, fusion and metrics to some views (all rows alike) when time is short.
The confidence of the refined maps (the paper's second network) is, with the proxy, the same formula
on counter maps recomputed on the refined maps (SPEC.md §11 item 31).

Rows (F1 / completeness / accuracy at 2 cm and 5 cm, fused with COLMAP-style fusion):
    ours                          vanilla maps, preset deepc (20°)
    ours + conf 0.05 (fast)       vanilla maps filtered at c >= 0.05, preset deepc
    ours refined                  refined maps, preset refined (10°, 2 pixels; fusion.py says why)
    ours refined, 20° fusion      refined maps, preset deepc (separates the map change from the preset)
    ours refined + conf 0.05      refined maps filtered at c_refined >= 0.05, preset refined
    full: ... + sky filter        as above, then SPEC.md §8 (sky mask + far plane)
    full, paper's 5° preset       the same maps, preset refined_paper (5°, 3 pixels: SPEC.md §7.3)
Plus depth metrics (vanilla vs refined, against GT depth) and the mean / median angle between
estimated normals and normals derived from GT depth over planar regions (GT normals within a 7x7
window agree to a mean resultant length >= 0.999, about 2.5°), time and iterations per scale.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from scipy import ndimage

from engine.confidence.weights import DEFAULT_REFINED_WEIGHTS
from engine.consistency import compute_counter_maps
from engine.evaluation.depth import depth_metrics
from engine.filtering import filter_by_confidence
from engine.fusion import FUSION_PRESETS
from engine.io.images import to_gray
from engine.patchmatch import ViewMaps
from engine.refinement import NoDataError, RefinementOptions, refine_depth
from engine.refinement.views import sky_filter_views
from engine.run.folder import file_sha256, read_map, write_map
from engine.run.pipeline import patchmatch_views
from engine.run.refine import refine_run
from support import bench
from support.gt_normals import depth_normals
from support.scoring import fuse_and_score, network_confidence, score_cells
from workbench.viewer.session import ViewerSession

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"scene": str, "size": str, "run": str, "views": list, "confidence": str, "solver": str,
          "refinement_options?": dict, "rows": list, "depth": dict, "normals": dict, "timing": dict,
          "sky_pixels_dropped": int, "refined_counter_seconds?": float, "per_view?": list, "refine_run?": dict}
# The shipped networks this script runs by default: their sha256 is recorded with every result.
WEIGHTS = ("deepc_middle.pt", "deepc_refined.pt")


PLANAR_WINDOW = 7
PLANAR_MIN_RESULTANT = 0.999


def proxy_confidence(counter: np.ndarray) -> np.ndarray:
    """min(K, 3) / 3: 0 without a consistent view, 1 with three or more."""
    return (np.minimum(np.asarray(counter, np.float32), 3.0) / 3.0).astype(np.float32)


def planar_mask(gt_normal: np.ndarray) -> np.ndarray:
    """Pixels whose GT-normal window (7x7) is complete and nearly constant."""
    has = gt_normal.any(-1)
    complete = ndimage.uniform_filter(has.astype(np.float64), PLANAR_WINDOW, mode="constant") > 1 - 1e-6
    mean = np.stack([ndimage.uniform_filter(gt_normal[..., c].astype(np.float64), PLANAR_WINDOW, mode="constant")
                     for c in range(3)], -1)
    return has & complete & (np.linalg.norm(mean, axis=-1) >= PLANAR_MIN_RESULTANT)


def angle_errors(normal: np.ndarray, gt_normal: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Angles (degrees) at pixels of ``mask`` where the estimate has a normal."""
    m = mask & np.asarray(normal).any(-1)
    cos = np.sum(np.asarray(normal, np.float64)[m] * gt_normal[m], -1) / np.linalg.norm(normal[m], axis=-1)
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def score(scene, name: str, depths, normals, preset: str) -> dict:
    return {"method": name, "preset": preset, **fuse_and_score(scene, depths, normals, FUSION_PRESETS[preset])}


def pooled_depth_metrics(scene, depths, selected) -> dict:
    est, gt = [], []
    for v in (scene.views[i] for i in selected):
        g = scene.gt_depth(v.index)
        if g is not None:
            est.append(np.asarray(depths[v.index]).ravel())
            gt.append(g.ravel())
    m = depth_metrics(np.concatenate(est), np.concatenate(gt))
    return {k: m[k] for k in ("abs_rel", "within_1pct", "within_5pct", "valid_fraction")}


def run(run_dir: Path, out_dir: Path, proxy: str | None, solver: str, reuse: bool,
        views: list[int] | None = None, fast_iters: tuple[int, ...] | None = None,
        weights: Path | None = None, refined_weights: Path | None = None) -> dict:
    session = ViewerSession.open(run_dir)
    scene, data = session.scene, session.data
    if data is None:
        raise SystemExit(f"{run_dir}: no maps")
    if weights is not None:  # the pipeline's own path: network 1, refine_run (cached in RUN/refined), network 2
        return run_networks(run_dir, session, weights, refined_weights)
    if session.has_confidence:
        conf_source = "network (run's confidence maps)"
        confidences = [d.confidence for d in data]
    elif proxy == "counter" and session.has_counter:
        conf_source = "PROXY min(K,3)/3 from counter maps (no confidence network yet)"
        confidences = [proxy_confidence(d.counter) for d in data]
    else:
        raise SystemExit(f"{run_dir}: the run has no confidence maps; pass --proxy-confidence counter")
    print(f"{scene.name}: {len(scene.views)} views; confidence: {conf_source}")
    options = RefinementOptions(solver=solver)
    if fast_iters:
        options = options.replace(fast_iters=fast_iters)
    selected = sorted(set(views)) if views else list(range(len(scene.views)))
    if views:
        print(f"only views {selected} are refined and fused (the others are left out of every row)")
    per_view = []
    shape = [d.depth.shape for d in data]
    refined_d = [np.zeros(s, np.float32) for s in shape]
    refined_n = [np.zeros(s + (3,), np.float32) for s in shape]
    for i in selected:
        v = scene.views[i]
        if reuse and read_map(out_dir, "refined_depth", v.name) is not None:
            refined_d[i] = read_map(out_dir, "refined_depth", v.name)
            refined_n[i] = read_map(out_dir, "refined_normal", v.name)
            print(f"  {v.name}: reusing the refined maps in {out_dir}")
            continue
        cpu = time.process_time()
        try:
            res = refine_depth(to_gray(scene.image(i)), data[i].depth, confidences[i], v.camera.K_idx,
                               v.depth_range, data[i].normal, options)
        except NoDataError as exc:
            print(f"  warning: view {v.name}: {exc}; its refined map is left empty")
            per_view.append({"view": v.name, "empty": True})
        else:
            # process_time(): CPU seconds of all threads, a cost measure that other load does not inflate.
            cpu = time.process_time() - cpu
            refined_d[i], refined_n[i] = res.depth, res.normal
            per_view.append({"view": v.name, "seconds": res.seconds, "cpu_seconds": cpu,
                             "iterations": res.iterations, "seconds_per_scale": res.seconds_per_scale,
                             "energy": res.energy, "shapes": res.shapes})
            print(f"  {v.name}: {res.seconds:.1f} s wall, {cpu:.1f} s CPU, iterations {res.iterations}, "
                  f"s/scale {[round(x, 1) for x in res.seconds_per_scale]}", flush=True)
        write_map(out_dir, "refined_depth", v.name, refined_d[i])
        write_map(out_dir, "refined_normal", v.name, refined_n[i])

    # Confidence of the refined maps: the run's second network when it exists, else the proxy on
    # counter maps recomputed on the refined maps.
    t = time.perf_counter()
    pm_views = patchmatch_views(scene)
    # Views left out keep their vanilla maps as the other side of the consistency checks.
    src_d = [refined_d[i] if i in selected else d.depth for i, d in enumerate(data)]
    src_n = [refined_n[i] if i in selected else d.normal for i, d in enumerate(data)]
    empty = [np.zeros(d.shape, np.float32) for d in src_d]
    refined_counter = compute_counter_maps(
        pm_views, [ViewMaps(d, n, e, e.astype(np.uint32)) for d, n, e in zip(src_d, src_n, empty, strict=True)])
    refined_conf = [proxy_confidence(k) for k in refined_counter]
    counter_seconds = time.perf_counter() - t

    keep = np.isin(np.arange(len(data)), selected)
    result = table_rows(scene, data, selected, keep, confidences, refined_d, refined_n, refined_conf)
    timing = {}
    if per_view and all("seconds" in p for p in per_view):
        timing = {"seconds_per_map_mean": float(np.mean([p["seconds"] for p in per_view])),
                  "cpu_seconds_per_map_mean": float(np.mean([p["cpu_seconds"] for p in per_view])),
                  "iterations_per_scale": per_view[0]["iterations"],
                  "seconds_per_scale_mean": np.mean([p["seconds_per_scale"] for p in per_view], 0).tolist(),
                  "peak_rss_mb": bench.peak_rss_mb()}
    size = f"{scene.views[0].camera.width}x{scene.views[0].camera.height}"
    return {"scene": scene.name, "size": size, "run": str(run_dir), "views": [scene.views[i].name for i in selected],
            "confidence": conf_source, "solver": solver, "refinement_options": options.to_dict(), **result,
            "timing": timing, "refined_counter_seconds": counter_seconds, "per_view": per_view}


def run_networks(run_dir: Path, session, weights: Path, refined_weights: Path | None) -> dict:
    """Table 3 as ``--pipeline fast`` and ``full`` compute it, on a finished vanilla run: network-1
    confidence, ``refine_run`` (cached in RUN/refined/ with a stamp), the refined maps' counter maps and
    their confidence from the second network (``refined_weights``; default: the shipped second network)."""
    scene, data = session.scene, session.data
    refined_weights = refined_weights or DEFAULT_REFINED_WEIGHTS
    confidences = network_confidence(scene, [d.depth for d in data], [d.normal for d in data],
                                      [d.counter for d in data], weights)
    done = refine_run(run_dir, weights=weights, log=lambda line: print("  " + line, flush=True))
    names = [v.name for v in scene.views]
    refined_d = [read_map(run_dir, "refined_depth", n) for n in names]
    refined_n = [read_map(run_dir, "refined_normal", n) for n in names]
    refined_k = [read_map(run_dir, "refined_counter", n) for n in names]
    refined_conf = network_confidence(scene, refined_d, refined_n, refined_k, refined_weights)
    selected = list(range(len(scene.views)))
    result = table_rows(scene, data, selected, np.ones(len(data), bool), confidences, refined_d, refined_n,
                        refined_conf)
    size = f"{scene.views[0].camera.width}x{scene.views[0].camera.height}"
    source = (f"network 1 {weights.name} (sha256 {file_sha256(weights)[:12]}); refined maps' confidence: "
              f"{refined_weights.name} (sha256 {file_sha256(refined_weights)[:12]})")
    return {"scene": scene.name, "size": size, "run": str(run_dir), "views": names, "confidence": source,
            "solver": "fast", **result, "timing": {}, "refine_run": {"reused": done.reused,
                                                                      "seconds": done.seconds}}


def table_rows(scene, data, selected, keep, confidences, refined_d, refined_n, refined_conf) -> dict:
    """The Table-3 rows, depth metrics and planar-normal errors of vanilla vs refined maps."""
    vanilla_d = [d.depth if keep[i] else np.zeros_like(d.depth) for i, d in enumerate(data)]
    vanilla_n = [d.normal if keep[i] else np.zeros_like(d.normal) for i, d in enumerate(data)]
    fast = [filter_by_confidence(d, n, c, 0.05) for d, n, c in zip(vanilla_d, vanilla_n, confidences, strict=True)]
    ref_conf = [filter_by_confidence(d, n, c, 0.05) for d, n, c in zip(refined_d, refined_n, refined_conf, strict=True)]
    full_d, full_n, sky = sky_filter_views(scene, [x[0] for x in ref_conf], [x[1] for x in ref_conf], vanilla_d,
                                           confidences)
    rows = [score(scene, "ours", vanilla_d, vanilla_n, "deepc"),
            score(scene, "ours + conf 0.05 (fast)", [x[0] for x in fast], [x[1] for x in fast], "deepc"),
            score(scene, "ours refined", refined_d, refined_n, "refined"),
            score(scene, "ours refined, 20° fusion", refined_d, refined_n, "deepc"),
            score(scene, "ours refined + conf 0.05", [x[0] for x in ref_conf], [x[1] for x in ref_conf], "refined"),
            score(scene, "full (+ sky filter)", full_d, full_n, "refined"),
            score(scene, "full, paper's 5° preset", full_d, full_n, "refined_paper")]

    depth = {"vanilla": pooled_depth_metrics(scene, vanilla_d, selected),
             "refined": pooled_depth_metrics(scene, refined_d, selected),
             "refined + conf 0.05 + sky": pooled_depth_metrics(scene, full_d, selected)}
    err_v, err_r, n_planar = [], [], 0
    for v in (scene.views[i] for i in selected):
        gt = scene.gt_depth(v.index)
        if gt is None:
            continue
        gt_n = depth_normals(v.camera, gt).astype(np.float64)
        planar = planar_mask(gt_n)
        n_planar += int(planar.sum())
        err_v.append(angle_errors(vanilla_n[v.index], gt_n, planar))
        err_r.append(angle_errors(refined_n[v.index], gt_n, planar))
    err_v, err_r = np.concatenate(err_v), np.concatenate(err_r)
    normals = {"planar_pixels": n_planar,
               "patchmatch": {"mean_deg": float(err_v.mean()), "median_deg": float(np.median(err_v))},
               "refined": {"mean_deg": float(err_r.mean()), "median_deg": float(np.median(err_r))}}
    return {"rows": rows, "depth": depth, "normals": normals,
            "sky_pixels_dropped": int(sum(int(m.sum()) for m in sky))}


def print_table(t: dict) -> None:
    print(f"\n{t['scene']} ({t['size']}), confidence: {t['confidence']}; percent at 2 cm | 5 cm")
    print(f"{'method':<26} {'preset':<13} {'F1':>6} {'compl.':>7} {'acc.':>6} | {'F1':>6} {'compl.':>7} {'acc.':>6} "
          f"{'points':>9}")
    for r in t["rows"]:
        print(f"{r['method']:<26} {r['preset']:<13} {score_cells(r)} {r['points']:>9,}")
    print(f"\n{'depth maps':<26} {'valid %':>8} {'<1 %':>7} {'<5 %':>7} {'abs_rel':>8}")
    for name, m in t["depth"].items():
        print(f"{name:<26} {m['valid_fraction']:>8.2f} {m['within_1pct']:>7.2f} {m['within_5pct']:>7.2f} "
              f"{m['abs_rel']:>8.4f}")
    n = t["normals"]
    print(f"\nnormal angle error vs GT-depth normals on {n['planar_pixels']:,} planar pixels: PatchMatch mean "
          f"{n['patchmatch']['mean_deg']:.2f}° median {n['patchmatch']['median_deg']:.2f}°; refined mean "
          f"{n['refined']['mean_deg']:.2f}° median {n['refined']['median_deg']:.2f}°")
    if t["timing"]:
        tm = t["timing"]
        print(f"refinement ({t['solver']}): {tm['seconds_per_map_mean']:.1f} s wall / "
              f"{tm['cpu_seconds_per_map_mean']:.1f} s CPU per map, iterations per scale "
              f"{tm['iterations_per_scale']}, s per scale "
              f"{[round(s, 1) for s in tm['seconds_per_scale_mean']]}, peak RSS {tm['peak_rss_mb']:.0f} MB")


def summary(result: dict) -> list[dict]:
    """Per row of Table 3: fusion preset, F1 / completeness / accuracy at 2 cm, F1 at 5 cm, points."""
    return [{"method": r["method"], "preset": r["preset"], "F1 2 cm": r["f1@0.02"],
             "compl. 2 cm": r["completeness@0.02"], "acc. 2 cm": r["accuracy@0.02"], "F1 5 cm": r["f1@0.05"],
             "points": r["points"]} for r in result["rows"]]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--out", type=Path, default=None, help="where the refined maps go (not with --weights)")
    parser.add_argument("--weights", type=Path, default=None,
                        help="network-1 weights: confidence and refinement as the pipeline computes them "
                             "(refine_run, cached in RUN_DIR/refined/)")
    parser.add_argument("--refined-weights", type=Path, default=None,
                        help="second network, for the refined maps' confidence (default: the shipped deepc_refined.pt)")
    parser.add_argument("--proxy-confidence", choices=("counter",), default=None)
    parser.add_argument("--solver", choices=("fast", "adam"), default="fast")
    parser.add_argument("--reuse", action="store_true", help="read refined maps from --out instead of refining")
    parser.add_argument("--views", default="", help="comma-separated view indices to refine and fuse (default all)")
    parser.add_argument("--fast-iters", default="", help="primal-dual iterations per scale, coarse to fine")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    views = [int(v) for v in args.views.split(",") if v.strip()]
    fast_iters = tuple(int(v) for v in args.fast_iters.split(",") if v.strip()) or None
    if args.weights is None and args.out is None:
        parser.error("--out is required without --weights")
    table = run(args.run_dir, args.out, args.proxy_confidence, args.solver, args.reuse, views, fast_iters,
                args.weights, args.refined_weights)
    print_table(table)
    path = bench.write_result(table, args.json or bench.results_path(__file__, table["scene"]))
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
