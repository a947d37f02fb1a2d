"""Screened Poisson surface reconstruction (Kazhdan & Hoppe, ToG 2013) of a fused cloud, with open3d."""

from __future__ import annotations

import numpy as np

from engine.core.errors import DeepCError
from engine.fusion.cloud import FusedCloud
from engine.meshing.mesh import TriangleMesh
from engine.meshing.options import MeshOptions
from engine.meshing.sampling import point_spacing

MIN_POINTS = 100  # fewer points than this carry no surface worth solving for
MAX_AUTO_DEPTH = 11  # depth 12 takes about 8x the memory and 3x the time of 11, for clouds of this tool's sizes


def auto_depth(xyz: np.ndarray) -> int:
    """Octree depth whose finest cells are about one point spacing: floor(log2(extent / spacing)), 6..11."""
    extent = float(np.ptp(xyz, axis=0).max())
    return int(np.clip(np.floor(np.log2(extent / max(point_spacing(xyz), 1e-12))), 6, MAX_AUTO_DEPTH))


def poisson_mesh(cloud: FusedCloud, options: MeshOptions | None = None) -> tuple[TriangleMesh, list[str]]:
    """A watertight Poisson surface of the oriented cloud, trimmed to where the cloud supports it.

    The solve extrapolates across holes and past the cloud's edges; vertices whose Poisson density (the number
    of samples that shaped them) lies in the lowest ``poisson_trim_quantile`` are removed, as is everything
    outside the cloud's bounding box. Colours are interpolated from the points. Fused normals face the cameras,
    so they are oriented already; a cloud without normals (a PLY from elsewhere) gets normals estimated from
    neighbours and oriented consistently, and a note says so.

    Points outside the box of the ``poisson_outlier_pct`` percentiles (plus 5 %) are left out, and the octree
    depth (unless set) is chosen so that the finest cells are about one point spacing (:func:`auto_depth`).

    Returns the mesh and notes (one line each) for the user.
    """
    import open3d as o3d  # lazy: open3d

    options = (options or MeshOptions()).validate()
    xyz = np.asarray(cloud.xyz, np.float64)
    if len(xyz) < MIN_POINTS:
        raise DeepCError(f"the fused cloud has {len(xyz)} points: too few for a Poisson surface "
                         f"(at least {MIN_POINTS})")
    if not np.isfinite(xyz).all() or float(np.ptp(xyz, axis=0).max()) <= 0:
        raise DeepCError("the fused cloud is degenerate (non-finite points, or all points at one place)")
    notes = []
    keep = np.ones(len(xyz), bool)
    if options.poisson_outlier_pct > 0:
        # a few stray points far away would stretch the octree and coarsen every cell
        low, high = np.percentile(xyz, [options.poisson_outlier_pct, 100 - options.poisson_outlier_pct], axis=0)
        margin = 0.05 * (high - low)
        keep = np.all((xyz >= low - margin) & (xyz <= high + margin), axis=1)
        if not keep.all():
            notes.append(f"{int((~keep).sum()):,} stray points outside the cloud's "
                         f"{options.poisson_outlier_pct:g}-{100 - options.poisson_outlier_pct:g} % box left out")
    xyz = xyz[keep]
    depth = options.poisson_depth or auto_depth(xyz)
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))
    pcd.colors = o3d.utility.Vector3dVector(np.asarray(cloud.rgb, np.float64)[keep] / 255.0)
    normal = np.asarray(cloud.normal, np.float64)[keep]
    has_normal = np.linalg.norm(normal, axis=1) > 0.5
    if has_normal.mean() > 0.99:
        pcd.normals = o3d.utility.Vector3dVector(np.where(has_normal[:, None], normal, [0.0, 0.0, 1.0]))
    else:
        spacing = point_spacing(xyz)
        pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=6 * spacing, max_nn=30))
        pcd.orient_normals_consistent_tangent_plane(15)
        notes.append(f"{100 * (1 - has_normal.mean()):.0f} % of the points had no normal: normals estimated from "
                     "their neighbours and oriented consistently (the sign of whole parts may flip)")
    threads = options.threads if options.threads > 0 else -1
    mesh, density = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
        pcd, depth=depth, n_threads=threads)
    density = np.asarray(density)
    if options.poisson_trim_quantile > 0 and len(density):
        mesh.remove_vertices_by_mask(density < np.quantile(density, options.poisson_trim_quantile))
    box = pcd.get_axis_aligned_bounding_box()
    mesh = mesh.crop(box.scale(1.02, box.get_center()))
    mesh.remove_unreferenced_vertices()
    if len(mesh.triangles) == 0:
        raise DeepCError("Poisson reconstruction left no triangles (the cloud may be too sparse or flat)")
    mesh.compute_vertex_normals()
    return TriangleMesh.from_open3d(mesh), notes
