"""Filtering before fusion, with the structure of the paper's Table 2 (ours; mask1; mask2; conf τ).

    .venv/bin/python benchmarks/paper/table2_filters.py RUN_DIR [RUN_DIR ...]
        [--out benchmarks/results/table2_filters.json]
        [--weights engine/confidence/weights/deepc_middle.pt] [--preset deepc]

Each RUN_DIR is the output folder of ``deepc run`` (stereo depth/normal/counter maps and metrics.json,
which names the scene). For each variant the maps are filtered, fused with the Table 2 setting (preset
``deepc``: 1 px, 1 %, 20°, 2 supporting views; ``--preset`` picks another, e.g. the default ``dense``) and
scored against the scene's GT points with the unobserved-space rule (GT depth maps). Confidence rows appear
when the run has confidence maps, or when ``--weights`` predicts them for a vanilla run (as ``--pipeline fast`` would).
F1, completeness and accuracy in percent at 2 cm and 5 cm.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from engine.evaluation import EvaluationOptions
from engine.filtering import filter_by_confidence, filter_by_counter
from engine.fusion import FUSION_PRESETS, fuse, views_from_scene
from engine.run.pipeline import evaluate_cloud
from support import bench
from support.scoring import TOLERANCES, score_cells, score_columns
from workbench.viewer.session import ViewerSession

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"runs": list}
# The shipped networks this script runs by default: their sha256 is recorded with every result.
WEIGHTS = ("deepc_middle.pt",)



def variants(session: ViewerSession, confidence: list | None = None) -> list[tuple[str, str, float]]:
    rows = [("ours", "none", 0), ("ours + mask1", "counter", 1), ("ours + mask2", "counter", 2)]
    if session.has_confidence or confidence is not None:
        rows += [(f"ours + conf {tau}", "confidence", tau) for tau in (0.05, 0.1, 0.3, 0.5)]
    return rows


def score_run(run_dir: Path, weights: Path | None = None, preset: str = "deepc") -> dict:
    session = ViewerSession.open(run_dir)
    scene = session.scene
    if not scene.has_gt_points:
        raise SystemExit(f"{run_dir}: scene {scene.name} has no GT points")
    options = FUSION_PRESETS[preset]
    confidence = None
    if weights is not None:  # predict the confidence of a vanilla run with these weights (as --pipeline fast does)
        from engine.confidence.options import ConfidenceOptions
        from engine.run.pipeline import confidence_stage
        confidence = confidence_stage(scene, session.data, [d.counter for d in session.data],
                                      ConfidenceOptions(weights=str(weights)))
    rows = []
    for name, kind, value in variants(session, confidence):
        t = time.perf_counter()
        depths, normals = [], []
        for i, d in enumerate(session.data):
            depth, normal = d.depth, d.normal
            if kind == "counter":
                depth, normal = filter_by_counter(depth, normal, d.counter, int(value))
            elif kind == "confidence":
                conf = d.confidence if confidence is None else confidence[i]
                depth, normal = filter_by_confidence(depth, normal, conf, value)
            depths.append(depth)
            normals.append(normal)
        kept = 100.0 * sum(int((d > 0).sum()) for d in depths) / sum(int((d.depth > 0).sum()) for d in session.data)
        cloud = fuse(views_from_scene(scene, depths, normals, None, options.check_num_images), options)
        result = evaluate_cloud(scene, cloud, EvaluationOptions(tolerances=TOLERANCES))
        rows.append({"method": name, "pixels_kept_pct": kept, "points": len(cloud),
                     "seconds": time.perf_counter() - t, **score_columns(result)})
    size = f"{scene.views[0].camera.width}x{scene.views[0].camera.height}"
    return {"scene": scene.name, "size": size, "run": str(run_dir), "preset": preset, "rows": rows,
            "weights": None if weights is None else str(weights)}


def print_table(table: dict) -> None:
    print(f"\n{table['scene']} ({table['size']}), fusion preset {table.get('preset', 'deepc')}; "
          "percent at 2 cm | 5 cm")
    print(f"{'method':<18} {'F1':>6} {'compl.':>7} {'acc.':>6} | {'F1':>6} {'compl.':>7} {'acc.':>6} "
          f"{'points':>9} {'pixels kept':>12}")
    for r in table["rows"]:
        print(f"{r['method']:<18} {score_cells(r)} {r['points']:>9,} {r['pixels_kept_pct']:>11.1f}%")


def summary(result: dict) -> list[dict]:
    """Per run and filter: F1 / completeness / accuracy at 2 cm, F1 at 5 cm, share of the pixels kept."""
    return [{"scene": f"{t['scene']} {t['size']}", "preset": t.get("preset", "deepc"), "method": r["method"],
             "F1 2 cm": r["f1@0.02"], "compl. 2 cm": r["completeness@0.02"], "acc. 2 cm": r["accuracy@0.02"],
             "F1 5 cm": r["f1@0.05"], "kept %": r["pixels_kept_pct"]} for t in result["runs"] for r in t["rows"]]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path, nargs="+")
    parser.add_argument("--out", type=Path, default=bench.results_path(__file__))
    parser.add_argument("--weights", type=Path, default=None,
                        help="predict confidence maps with these weights (for vanilla runs; default: use the "
                             "run's own confidence maps when it has them)")
    parser.add_argument("--preset", choices=sorted(FUSION_PRESETS), default="deepc",
                        help="fusion preset (default: deepc, the paper's Table 2 setting)")
    args = parser.parse_args()
    tables = [score_run(run, args.weights, args.preset) for run in args.runs]
    for table in tables:
        print_table(table)
    bench.write_result({"runs": tables}, args.out)
    print(f"\nwrote {args.out}")


if __name__ == "__main__":
    np.seterr(invalid="ignore")
    main()
