"""``deepc mesh RUN_DIR [--method poisson|tsdf] [--set mesh.NAME=VALUE]``: a surface for a finished run.

Poisson meshes the run's ``fused.ply``; TSDF integrates the depth maps its pipeline fused, under the run's own
options (``engine.run.fused_maps``: vanilla: PatchMatch's; fast: those the confidence threshold kept; full: the
refined maps with PatchMatch's where network 1 trusts it, filtered by network 2, then the sky filter). Writes
``RUN_DIR/mesh.ply`` and a ``mesh`` block in its metrics.json, both atomically; scores the mesh when the scene has
GT points.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from engine.core.errors import DeepCError
from engine.evaluation import EvaluationOptions
from engine.fusion import FusedCloud, read_fused_ply
from engine.meshing import evaluate_mesh, mesh_run, write_mesh_ply
from engine.run.folder import read_metrics, read_run_metrics, run_scene, write_metrics
from engine.run.fused_maps import FusionRule, fused_view, read_run_view
from engine.scene import Scene
from workbench.cli.run import print_mesh_summary
from workbench.flags.assignments import check_stages
from workbench.flags.run_options import mesh_options


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
        depths = tsdf_depths(run_dir, scene, FusionRule.from_saved(metrics.options, metrics.pipeline))
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


def tsdf_depths(run_dir: Path, scene: Scene, rule: FusionRule) -> list[np.ndarray]:
    """(H, W) depth per view that TSDF integrates: those ``rule`` fuses, read one view at a time."""
    return [fused_view(scene, v.index, rule, read_run_view(run_dir, v.name, rule.kinds())).depth
            for v in scene.views]
