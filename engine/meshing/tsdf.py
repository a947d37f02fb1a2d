"""TSDF integration (Curless & Levoy, SIGGRAPH 1996) of depth maps into a surface, in open3d's voxel-block grid."""

from __future__ import annotations

import numpy as np

from engine.core.camera import Camera
from engine.core.errors import DeepCError
from engine.meshing.mesh import TriangleMesh
from engine.meshing.options import MeshOptions

BYTES_PER_VOXEL = 20  # a voxel of the grid: float distance, float weight, three float colours
BLOCK_OVERHEAD = 4  # voxel blocks (16³) are allocated whole around the truncation band
BLOCK = 16  # voxels per block edge


def tsdf_voxel_size(cameras: list[Camera], depths: list[np.ndarray], voxel_px: float) -> float:
    """Voxel edge (model units): ``voxel_px`` pixel footprints at the median valid depth, median over the views.

    A pixel at depth z spans z / f (f the focal length in pixels), so the volume resolves what the maps resolve
    whatever the scene's scale; views without depth are skipped."""
    sizes = [float(np.median(d[d > 0])) / float(c.K_idx[0, 0]) * voxel_px
             for c, d in zip(cameras, depths, strict=True) if (d > 0).any()]
    if not sizes:
        raise DeepCError("no depth in any view: nothing to integrate")
    return float(np.median(sizes))


def tsdf_memory_bytes(depths: list[np.ndarray], voxel_px: float, trunc_voxels: float) -> float:
    """Upper estimate of the volume's memory: every valid pixel's footprint (voxel_px² pixels per voxel column)
    touches 2 · trunc_voxels voxels along its ray, views counted as if they did not overlap."""
    pixels = sum(int((d > 0).sum()) for d in depths)
    return pixels / voxel_px**2 * 2 * trunc_voxels * BYTES_PER_VOXEL * BLOCK_OVERHEAD


def tsdf_mesh(cameras: list[Camera], depths: list[np.ndarray], colors: list[np.ndarray],
              options: MeshOptions | None = None) -> tuple[TriangleMesh, float]:
    """Integrate (H, W) depth maps (camera-frame z, 0 = none) with (H, W, 3) uint8 colours seen by ``cameras`` (at
    the maps' size) into a signed-distance volume and extract its zero level set (marching cubes).

    Pass the maps the pipeline fuses: under ``fast`` and ``full`` they are already masked by confidence, so only
    trusted depths are integrated. Returns the mesh and the voxel edge used (model units).
    """
    import open3d as o3d  # lazy: open3d

    options = (options or MeshOptions()).validate()
    voxel = tsdf_voxel_size(cameras, depths, options.tsdf_voxel_px)
    need = tsdf_memory_bytes(depths, options.tsdf_voxel_px, options.tsdf_trunc_voxels)
    if need > options.max_memory_gb * 1e9:
        raise DeepCError(f"a TSDF volume with {voxel:.3g}-unit voxels would need about {need / 1e9:.1f} GB "
                         f"(mesh.max_memory_gb = {options.max_memory_gb:g}): raise mesh.tsdf_voxel_px")
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    o3c = o3d.core
    device = o3c.Device("CPU:0")
    # open3d's voxel-block grid (the legacy ScalableTSDFVolume integrates nothing in open3d 0.20 here)
    volume = o3d.t.geometry.VoxelBlockGrid(
        attr_names=("tsdf", "weight", "color"), attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
        attr_channels=((1), (1), (3)), voxel_size=voxel, block_resolution=BLOCK,
        block_count=max(1000, int(need / (BLOCK**3 * BYTES_PER_VOXEL))), device=device)
    for camera, depth, rgb in zip(cameras, depths, colors, strict=True):
        depth = np.ascontiguousarray(depth, np.float32)
        if not (depth > 0).any():
            continue
        h, w = depth.shape
        if (camera.width, camera.height) != (w, h) or np.asarray(rgb).shape[:2] != (h, w):
            raise ValueError("cameras, depth maps and colours must have one size per view")
        K = o3c.Tensor(camera.K_idx, o3c.float64)  # open3d projects to pixel indices, as K_idx does
        extrinsic = np.eye(4)
        extrinsic[:3, :3], extrinsic[:3, 3] = camera.R, camera.t
        E = o3c.Tensor(extrinsic, o3c.float64)
        depth_image = o3d.t.geometry.Image(o3c.Tensor(depth))
        color_image = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(rgb, np.float32) / 255.0))
        depth_max = float(depth.max()) * 1.01
        blocks = volume.compute_unique_block_coordinates(depth_image, K, E, 1.0, depth_max,
                                                         options.tsdf_trunc_voxels)
        volume.integrate(blocks, depth_image, color_image, K, K, E, 1.0, depth_max, options.tsdf_trunc_voxels)
    # a voxel's weight counts the views that saw it: keep the surface where tsdf_min_views agree
    extracted = volume.extract_triangle_mesh(weight_threshold=options.tsdf_min_views - 0.5)
    mesh = extracted.to_legacy()
    if len(mesh.triangles) == 0:
        raise DeepCError("TSDF integration gave no surface (depth maps empty or inconsistent)")
    mesh.compute_vertex_normals()
    return TriangleMesh.from_open3d(mesh), voxel
