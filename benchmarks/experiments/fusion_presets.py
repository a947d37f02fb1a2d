"""Which fusion preset each pipeline should use by default: every preset on every pipeline's maps.

    .venv/bin/python benchmarks/experiments/fusion_presets.py RUN_DIR [RUN_DIR ...] [--presets deepc,refined,dense]
        [--json benchmarks/results/fusion_presets.json]

RUN_DIR is a finished run (vanilla maps; refined maps too when it is to score ``full``). For each run the
maps of the three pipelines are built as ``deepc run`` builds them - vanilla: PatchMatch maps; fast: network 1
at τ 0.05; full: refined maps, network 2 at τ 0.05, sky filter - and fused with each preset of
``engine.fusion.FUSION_PRESETS``. Scores: F1 / accuracy / completeness at 1, 2 and 5 cm, against the scene's
points.ply with the unobserved-space rule (what ``deepc eval`` reports), and for fountain_p11 also under the
OpenMVS peer's rule (every valid GT depth pixel a GT point).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from engine.evaluation import EvaluationOptions, evaluate_points
from engine.fusion import FUSION_PRESETS, fuse, views_from_scene
from engine.run.folder import read_metrics
from engine.run.pipeline import evaluate_cloud
from engine.scene import SceneOptions, load_scene
from support import bench
from support.scoring import TAU, pipeline_maps

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"tau": float, "tolerances": list, "runs": list}
# The shipped networks this script runs by default: their sha256 is recorded with every result.
WEIGHTS = ("deepc_middle.pt", "deepc_refined.pt")


TOLERANCES = (0.01, 0.02, 0.05)


def score(scene, run_dir: Path, presets: list[str]) -> dict:
    metrics = read_metrics(run_dir)
    options = EvaluationOptions(tolerances=TOLERANCES)
    peer = None
    if scene.name == "fountain_p11" and scene.has_gt_depth:
        gt_views = scene.gt_views()
        peer = (np.concatenate([cam.backproject(d)[d > 0] for cam, d in gt_views]), gt_views)
    rows = []
    for pipeline, (depth, normal) in pipeline_maps(scene, run_dir).items():
        for preset in presets:
            fusion = FUSION_PRESETS[preset]
            cloud = fuse(views_from_scene(scene, depth, normal, None, fusion.check_num_images), fusion)
            row = {"pipeline": pipeline, "preset": preset, "points": len(cloud),
                   "deepc_eval": evaluate_cloud(scene, cloud, options).to_dict()}
            if peer is not None:
                row["peer_rule"] = evaluate_points(np.asarray(cloud.xyz, np.float64), peer[0], options,
                                                   peer[1]).to_dict()
            rows.append(row)
            r = row["deepc_eval"]
            print(f"  {scene.name:<14} {pipeline:<8} {preset:<8} {len(cloud):>9,} F1 "
                  + " / ".join(f"{f:6.2f}" for f in r["f1"])
                  + (f"   peer rule F1 2 cm {row['peer_rule']['f1'][1]:.2f}" if peer is not None else ""),
                  flush=True)
    return {"scene": scene.name, "run": str(run_dir), "size": metrics["image_size"], "rows": rows}


def summary(result: dict) -> list[dict]:
    """Per scene, pipeline and preset: F1 at 1 / 2 / 5 cm (deepc eval rule) and the point count."""
    return [{"scene": res["scene"], "pipeline": r["pipeline"], "preset": r["preset"],
             "F1 1 / 2 / 5 cm": r["deepc_eval"]["f1"], "points": r["points"]}
            for res in result["runs"] for r in res["rows"]]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path, nargs="+")
    parser.add_argument("--presets", default="deepc,refined,dense")
    parser.add_argument("--json", type=Path, default=bench.results_path(__file__))
    args = parser.parse_args()
    presets = [p for p in args.presets.split(",") if p]
    unknown = [p for p in presets if p not in FUSION_PRESETS]
    if unknown:
        raise SystemExit(f"--presets: unknown {unknown} (one of {', '.join(sorted(FUSION_PRESETS))})")
    results = []
    for run_dir in args.runs:
        m = read_metrics(run_dir)
        scene = load_scene(m["scene_path"], SceneOptions.from_dict(m["options"]["scene"]))
        results.append(score(scene, run_dir, presets))
    print(f"\nF1 at 1 / 2 / 5 cm (deepc eval rule)\n{'scene':<14} {'pipeline':<8} " +
          " ".join(f"{p:>20}" for p in presets))
    for res in results:
        for pipeline in dict.fromkeys(r["pipeline"] for r in res["rows"]):
            cells = []
            for p in presets:
                r = next(x for x in res["rows"] if x["pipeline"] == pipeline and x["preset"] == p)
                cells.append(" / ".join(f"{f:.1f}" for f in r["deepc_eval"]["f1"]))
            print(f"{res['scene']:<14} {pipeline:<8} " + " ".join(f"{c:>20}" for c in cells))
    bench.write_result({"tau": TAU, "tolerances": list(TOLERANCES), "runs": results}, args.json)
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
