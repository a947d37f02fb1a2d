"""``deepc eval RECON.ply GT.ply|GT.mlp [--tolerances ...] [--json OUT.json]``.

Prints the ETH3D-style table (percent). RECON may be a cloud or a mesh (a PLY with faces, OBJ, OFF, STL): a
mesh is sampled uniformly at half the GT points' spacing (the smallest tolerance's half against an ETH3D project) and
scored as a cloud, so meshes and clouds compare on one scale. GT may be a PLY of surface points or an ETH3D
``scan_alignment.mlp``. When the GT PLY is ``SCENE/ground_truth/points.ply`` of a scene with GT depth
maps, the unobserved-space rule uses those maps (Schöps et al. 2017).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from engine.core.errors import DeepCError
from engine.evaluation import (
    EvaluationOptions,
    EvaluationResult,
    evaluate_eth3d,
    evaluate_file,
    evaluate_points,
    parse_tolerances,
)
from engine.io.atomic import atomic_write_text
from engine.io.ply import ply_element_counts, read_points
from engine.meshing import read_mesh
from engine.meshing.sampling import OVERSAMPLING, point_spacing, sample_surface
from engine.scene import SceneOptions, load_scene


def _gt_views_for(gt_path: Path):
    """(camera, GT depth) pairs when ``gt_path`` is SCENE/ground_truth/points.ply of a loadable scene."""
    if gt_path.name != "points.ply" or gt_path.parent.name != "ground_truth":
        return None
    scene_root = gt_path.parent.parent
    if not (scene_root / "ground_truth" / "depth_maps").is_dir() or not (scene_root / "sparse").is_dir():
        return None
    try:
        scene = load_scene(scene_root, SceneOptions(max_image_size=1024))
    except DeepCError as exc:
        print(f"deepc: warning: ground-truth depth maps not used ({exc})", file=sys.stderr)
        return None
    return scene.gt_views() or None


MESH_SUFFIXES = (".obj", ".off", ".stl")


def is_mesh_file(path: str | Path) -> bool:
    """Whether ``path`` holds triangles: a PLY whose header declares faces, or a mesh-only format."""
    path = Path(path)
    if path.suffix.lower() in MESH_SUFFIXES:
        return True
    return path.suffix.lower() == ".ply" and ply_element_counts(path).get("face", 0) > 0


def run_eval(recon: str | Path, gt: str | Path, options: EvaluationOptions) -> EvaluationResult:
    gt = Path(gt)
    gt_views = None if gt.suffix.lower() == ".mlp" else _gt_views_for(gt)
    if not is_mesh_file(recon):
        return evaluate_file(recon, gt, options, gt_views)
    mesh = read_mesh(recon)
    if gt.suffix.lower() == ".mlp":
        spacing = float(min(options.tolerances)) / 2
        points = sample_surface(mesh, spacing)
        result = evaluate_eth3d(points, gt, options)
    else:
        gt_points = read_points(gt)
        spacing = point_spacing(gt_points) / OVERSAMPLING
        points = sample_surface(mesh, spacing)
        result = evaluate_points(points, gt_points, options, gt_views)
    result.notes.append(f"mesh of {len(mesh):,} triangles sampled as {len(points):,} points, {spacing:.3g} apart")
    return result


def cmd_eval(args: argparse.Namespace) -> int:
    """Handler for ``deepc eval``; args has recon, gt, tolerances (str), json (str | None)."""
    tolerances = getattr(args, "tolerances", None)
    options = EvaluationOptions() if not tolerances else EvaluationOptions(tolerances=parse_tolerances(tolerances))
    options.validate()
    result = run_eval(args.recon, args.gt, options)
    print(f"{args.recon} vs {args.gt}")
    print(result.format_table())
    if getattr(args, "json", None):
        payload = result.to_dict()
        payload.update({"num_reconstruction": result.num_reconstruction,
                        "num_ground_truth": result.num_ground_truth,
                        "unobserved": result.unobserved, "notes": result.notes,
                        "options": options.to_dict()})
        atomic_write_text(args.json, json.dumps(payload, indent=2) + "\n")
    return 0
