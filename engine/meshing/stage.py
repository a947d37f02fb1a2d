"""The meshing stage of a run: the chosen method on the run's cloud or maps, and the mesh scored like a cloud."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from engine.evaluation import EvaluationOptions, EvaluationResult, evaluate_points
from engine.fusion.cloud import FusedCloud
from engine.io.images import resize_area
from engine.io.ply import read_points
from engine.meshing.mesh import TriangleMesh
from engine.meshing.options import MeshOptions
from engine.meshing.poisson import poisson_mesh
from engine.meshing.sampling import OVERSAMPLING, point_spacing, sample_surface
from engine.meshing.tsdf import tsdf_mesh
from engine.scene import Scene


def mesh_run(scene: Scene, cloud: FusedCloud, depths: list[np.ndarray], options: MeshOptions
             ) -> tuple[TriangleMesh, dict[str, Any]]:
    """Mesh a run: Poisson on ``cloud``, or TSDF of ``depths`` ((H, W) per view of ``scene``, the maps fusion used).

    Returns the mesh and its ``metrics.json`` block (method, size, seconds, voxel edge for TSDF, notes, options).
    """
    options = options.validate()
    start = time.perf_counter()
    info: dict[str, Any] = {"method": options.method}
    if options.method == "poisson":
        mesh, notes = poisson_mesh(cloud, options)
    elif options.method == "tsdf":
        cameras, colors = [], []
        for view, depth in zip(scene.views, depths, strict=True):
            h, w = depth.shape
            camera = view.camera if (view.camera.width, view.camera.height) == (w, h) else view.camera.rescaled(w, h)
            rgb = scene.image(view.index)
            if rgb.shape[:2] != (h, w):
                rgb = resize_area(rgb, (w, h))
            cameras.append(camera)
            colors.append(np.clip(np.rint(rgb * 255), 0, 255).astype(np.uint8))
        mesh, info["voxel"] = tsdf_mesh(cameras, depths, colors, options)
        notes = []
    else:
        raise ValueError(f"no mesh method {options.method!r} to run")
    info.update(vertices=len(mesh.vertices), triangles=len(mesh.triangles), seconds=time.perf_counter() - start,
                notes=notes, options=options.to_dict())
    return mesh, info


def evaluate_mesh(scene: Scene, mesh: TriangleMesh, options: EvaluationOptions) -> EvaluationResult:
    """ETH3D-style scores of a mesh against the scene's GT points: its surface sampled uniformly at half the GT
    points' spacing (median nearest-neighbour distance; :data:`OVERSAMPLING`), then scored exactly as a cloud is."""
    gt = read_points(scene.gt_points_path)
    points = sample_surface(mesh, point_spacing(gt) / OVERSAMPLING)
    return evaluate_points(points, gt, options, scene.gt_views() or None)
