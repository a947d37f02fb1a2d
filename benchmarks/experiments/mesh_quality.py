"""Meshes against clouds: F1 of Poisson and TSDF surfaces beside the fused cloud's, per scene and pipeline.

    .venv/bin/python benchmarks/experiments/mesh_quality.py RUN_DIR [RUN_DIR ...] [--methods poisson tsdf]
        [--pipelines vanilla fast full] [--json benchmarks/results/mesh_quality.json]

Each RUN_DIR is a finished run (a vanilla run, or one with refined maps for ``full``); its maps are handed to
fusion as today's pipelines do (``support.scoring.shipped_pipeline_maps``: shipped weights, default options),
fused with the default preset, and meshed with each method exactly as ``deepc run --mesh`` does
(``engine.meshing.mesh_run``). Cloud and mesh are scored against the scene's GT points at 1, 2 and 5 cm (the
mesh sampled uniformly at half the GT spacing). Per mesh: seconds and the peak resident memory of the meshing
step (the process's peak is reset before it, Linux ``/proc/self/clear_refs``).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from engine.evaluation import EvaluationOptions
from engine.fusion import DEFAULT_PRESET, FUSION_PRESETS, fuse, views_from_scene
from engine.meshing import MeshOptions, evaluate_mesh, mesh_run
from engine.run.folder import run_scene
from engine.run.pipeline import evaluate_cloud
from support import bench
from support.scoring import shipped_pipeline_maps

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"tolerances": list, "preset": str, "rows": list}
# The shipped networks this script runs by default: their sha256 is recorded with every result.
WEIGHTS = ("deepc_middle.pt", "deepc_refined.pt")


TOLERANCES = (0.01, 0.02, 0.05)


def summary(result: dict) -> list[dict]:
    """F1 at 1/2/5 cm of the cloud and of each mesh, the mesh's seconds and peak memory."""
    return [{"scene": r["scene"], "pipeline": r["pipeline"], "surface": r["surface"],
             "F1 1 cm": r["f1"][0], "F1 2 cm": r["f1"][1], "F1 5 cm": r["f1"][2],
             "seconds": r.get("seconds"), "peak MB": r.get("peak_mb")} for r in result["rows"]]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("runs", nargs="+", type=Path, help="run folders")
    ap.add_argument("--methods", nargs="+", default=["poisson", "tsdf"], choices=["poisson", "tsdf"])
    ap.add_argument("--pipelines", nargs="+", default=["vanilla", "fast", "full"])
    ap.add_argument("--json", default=bench.results_path(__file__))
    args = ap.parse_args(argv)
    evaluation = EvaluationOptions(tolerances=TOLERANCES)
    rows = []
    for run in args.runs:
        scene = run_scene(run)
        maps = shipped_pipeline_maps(scene, run)
        for pipeline in args.pipelines:
            if pipeline not in maps:
                print(f"{scene.name}: no {pipeline} maps (the run has no refined maps)")
                continue
            depths, normals, confidence = maps[pipeline]
            preset = FUSION_PRESETS[DEFAULT_PRESET]
            cloud = fuse(views_from_scene(scene, depths, normals, confidence, preset.check_num_images), preset)
            score = evaluate_cloud(scene, cloud, evaluation)
            rows.append({"scene": scene.name, "pipeline": pipeline, "surface": "cloud", "points": len(cloud),
                         "f1": score.f1, "accuracy": score.accuracy, "completeness": score.completeness})
            for method in args.methods:
                bench.reset_peak_rss()
                before = bench.peak_rss_mb_now()
                start = time.perf_counter()
                mesh, info = mesh_run(scene, cloud, depths, MeshOptions(method=method))
                seconds = time.perf_counter() - start
                peak = bench.peak_rss_mb_now()
                score = evaluate_mesh(scene, mesh, evaluation)
                rows.append({"scene": scene.name, "pipeline": pipeline, "surface": method, "seconds": seconds,
                             "peak_mb": peak, "peak_above_start_mb": peak - before, "triangles": len(mesh),
                             "voxel": info.get("voxel"), "f1": score.f1, "accuracy": score.accuracy,
                             "completeness": score.completeness})
            bench.print_table([r for r in summary({"rows": rows}) if r["scene"] == scene.name
                               and r["pipeline"] == pipeline])
    bench.write_result({"tolerances": list(TOLERANCES), "preset": DEFAULT_PRESET, "rows": rows}, args.json)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
