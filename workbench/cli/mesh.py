"""``deepc mesh RUN_DIR [--method poisson|tsdf] [--set mesh.NAME=VALUE]``: a surface for a finished run.

Poisson meshes the run's ``fused.ply``; TSDF integrates the maps its pipeline fused (vanilla: PatchMatch's;
fast: those the confidence threshold kept; full: the refined maps with PatchMatch's where network 1 trusts it,
filtered by network 2 — the sky filter is not repeated). Writes ``RUN_DIR/mesh.ply`` and a ``mesh`` block in its
metrics.json, both atomically; scores the mesh when the scene has GT points.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from engine.core.errors import DeepCError
from engine.evaluation import EvaluationOptions
from engine.filtering import filter_by_confidence
from engine.fusion import FusedCloud, read_fused_ply
from engine.meshing import evaluate_mesh, mesh_run, write_mesh_ply
from engine.run.folder import read_metrics, read_run_metrics, run_scene, write_metrics
from workbench.cli.run import print_mesh_summary
from workbench.flags.assignments import check_stages
from workbench.flags.run_options import mesh_options
from workbench.maps.run_maps import read_view_data


def cmd_mesh(args: argparse.Namespace) -> int:
    """Handler of ``deepc mesh``; args has run_dir, method and set (``mesh.NAME=VALUE`` items)."""
    run_dir = Path(args.run_dir)
    if not run_dir.is_dir():
        raise DeepCError("run folder does not exist", run_dir)
    metrics = read_run_metrics(run_dir)
    check_stages(args.set, ("mesh",))
    options = mesh_options(args.method, args.set)
    scene = run_scene(run_dir)
    cloud, depths = FusedCloud.empty(), []
    if options.method == "poisson":
        if not (run_dir / "fused.ply").is_file():
            raise DeepCError("the run has no fused.ply to mesh (an interrupted run?)", run_dir)
        cloud = read_fused_ply(run_dir / "fused.ply")
    else:
        pipeline = metrics.pipeline
        tau = {"fast": metrics.options.get("confidence", {}).get("tau"),
               "full": metrics.options.get("refinement", {}).get("refined_conf_tau")}.get(pipeline)
        for view in read_view_data(run_dir, scene):
            depth, normal, confidence, _ = view.maps(pipeline)
            if tau is not None and confidence is not None:
                depth, normal = filter_by_confidence(depth, normal, confidence, tau)
            depths.append(depth)
    mesh, info = mesh_run(scene, cloud, depths, options)
    write_mesh_ply(run_dir / "mesh.ply", mesh)
    if scene.has_gt_points:
        evaluation = EvaluationOptions.from_dict(metrics.options.get("evaluation") or {})
        info["eval"] = evaluate_mesh(scene, mesh, evaluation).to_dict()
    data = read_metrics(run_dir)
    data["mesh"] = info
    write_metrics(run_dir, data)
    print_mesh_summary(info)
    print(f"mesh: {run_dir / 'mesh.ply'}")
    return 0
