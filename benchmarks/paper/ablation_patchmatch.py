"""Table-1-style PatchMatch ablation: ours, ours with the ACMM pattern, ours without plane propagation.

    .venv/bin/python benchmarks/paper/ablation_patchmatch.py [--scene DIR --max-image-size 384]
        [--schedule acmm|paper] [--num-source-views 5] [--json benchmarks/results/ablation_patchmatch_small.json]

Without ``--scene`` the analytic synthetic scene of ``support/pm_synthetic.py`` (4 views, 160x120) is
used. With a scene that has GT depth maps (e.g. /work/shared/data/fountain_p11) the scene is loaded
with ``engine.scene.load_scene``. Depth metrics (``engine.evaluation.depth.depth_metrics``) are averaged over
views: abs_rel, within_1pct, within_5pct, valid_fraction (percentages 0-100), before any filtering.
"""

from __future__ import annotations

import argparse

import numpy as np

from engine.evaluation.depth import depth_metrics
from engine.patchmatch import PatchMatchOptions, PatchMatchView, run_patchmatch
from support import bench

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"scene": str, "schedule": str, "max_image_size": int, "variants": dict}


VARIANTS = {
    "ours": {},
    "ours with ACMM pattern": {"pattern": "acmm"},
    "ours without plane propagation": {"plane_propagation": False},
}


def load(args) -> tuple[list[PatchMatchView], list[np.ndarray]]:
    if args.scene is None:
        from support.pm_synthetic import make_scene

        return make_scene(160, 120)
    from engine.scene import SceneOptions, load_scene

    sc = load_scene(args.scene, SceneOptions(max_image_size=args.max_image_size,
                                             num_source_views=args.num_source_views))
    views = [PatchMatchView(v.name, sc.gray(i), v.camera, v.depth_range[0], v.depth_range[1], v.source_views)
             for i, v in enumerate(sc.views)]
    gts = [sc.gt_depth(i) for i in range(len(views))]
    if any(g is None for g in gts):
        raise SystemExit(f"{args.scene}: needs ground-truth depth maps")
    return views, gts


def debiased(depth: np.ndarray, gt: np.ndarray) -> dict[str, float]:
    """Median signed relative error (%) and within 1 % after subtracting it."""
    both = (gt > 0) & np.isfinite(gt) & (depth > 0)
    if not both.any():
        return {"median_signed_pct": float("nan"), "within_1pct_debiased": float("nan")}
    rel = (depth[both] - gt[both]) / gt[both]
    med = float(np.median(rel))
    return {"median_signed_pct": 100.0 * med, "within_1pct_debiased": 100.0 * float((np.abs(rel - med) < 0.01).mean())}


def summary(result: dict) -> list[dict]:
    """Per variant, averaged over views: abs_rel, within 1 % / 5 %, within 1 % after removing the median bias,
    valid pixels, seconds."""
    return [{"variant": name, "abs_rel": r["abs_rel"], "within 1 %": r["within_1pct"], "within 5 %": r["within_5pct"],
             "within 1 % debiased": r["within_1pct_debiased"], "valid %": r["valid_fraction"], "seconds": r["seconds"]}
            for name, r in result["variants"].items()]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=None)
    ap.add_argument("--max-image-size", type=int, default=384)
    ap.add_argument("--num-source-views", type=int, default=5)
    ap.add_argument("--schedule", default="acmm", choices=("acmm", "paper"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--variants", default=",".join(VARIANTS), help="comma-separated subset of the variants")
    ap.add_argument("--json", default=bench.results_path(__file__))
    args = ap.parse_args()
    views, gts = load(args)
    rows = {}
    for name in args.variants.split(","):
        change = VARIANTS[name]
        opts = PatchMatchOptions(schedule=args.schedule, seed=args.seed, **change)
        with bench.Stopwatch() as watch:
            maps = run_patchmatch(views, opts)
        per_view = [depth_metrics(m.depth, g) | debiased(m.depth, g) for m, g in zip(maps, gts, strict=True)]
        keys = ("abs_rel", "within_1pct", "within_5pct", "valid_fraction", "within_1pct_debiased")
        rows[name] = {k: float(np.nanmean([r[k] for r in per_view])) for k in keys}
        rows[name]["per_view"] = per_view
        rows[name]["seconds"] = watch.wall
        rows[name]["options"] = opts.to_dict()
    print(f"{'variant':34s} {'abs_rel':>8s} {'<1%':>7s} {'<5%':>7s} {'valid':>7s} {'<1%deb':>7s} {'sec':>7s}")
    for name, r in rows.items():
        print(f"{name:34s} {r['abs_rel']:8.4f} {r['within_1pct']:7.2f} {r['within_5pct']:7.2f} "
              f"{r['valid_fraction']:7.2f} {r['within_1pct_debiased']:7.2f} {r['seconds']:7.1f}")
    out = {"scene": args.scene or "synthetic(support/pm_synthetic.py, 160x120)", "schedule": args.schedule,
           "max_image_size": args.max_image_size, "variants": rows}
    bench.write_result(out, args.json)
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
