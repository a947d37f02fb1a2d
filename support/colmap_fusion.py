"""COLMAP's own fusion (pycolmap) on our maps, as a referee for ``engine.fusion``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from engine.fusion.cloud import FusedCloud, FusionView
from engine.fusion.options import FusionOptions
from engine.fusion.packing import rgb_uint8
from engine.fusion.ply import read_fused_ply


def write_colmap_workspace(scene, views: list[FusionView], workdir: str | Path,
                           sparse_dir: str | Path | None = None) -> Path:
    """Write a minimal COLMAP dense workspace for ``views`` (one per ``scene.views``, same order).

    Images at the depth-map resolution (PNG data, lossless), the scene's sparse model (its tracks
    give COLMAP's overlap graph) with every camera set to the depth-map size and our index-space
    intrinsics (so COLMAP's (col, row) un-projection equals ours), depth and normal maps written
    with our COLMAP-layout writer (pycolmap's NormalMap binding scrambles channels), fusion.cfg.
    """
    import pycolmap
    from PIL import Image

    from engine.io.colmap_model import find_model_dir
    from engine.io.dense import write_dense_map

    workdir = Path(workdir)
    rec = pycolmap.Reconstruction(str(sparse_dir or find_model_dir(scene.root)))
    by_name = {im.name: im for im in rec.images.values()}
    set_cameras: dict[int, tuple] = {}
    for sv, v in zip(scene.views, views, strict=True):
        im = by_name[sv.name]
        K = v.camera.K_idx
        params = (v.camera.width, v.camera.height, K[0, 0], K[1, 1], K[0, 2], K[1, 2])
        if set_cameras.setdefault(im.camera_id, params) != params:
            raise ValueError(f"views sharing COLMAP camera {im.camera_id} have different map sizes or intrinsics")
        cam = rec.cameras[im.camera_id]
        cam.width, cam.height = v.camera.width, v.camera.height
        cam.params = list(params[2:])
    (workdir / "sparse").mkdir(parents=True, exist_ok=True)
    rec.write_binary(str(workdir / "sparse"))
    for sv, v in zip(scene.views, views, strict=True):
        image_path = workdir / "images" / sv.name
        image_path.parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(rgb_uint8(v.rgb)).save(image_path, format="PNG")
        write_dense_map(workdir / "stereo" / "depth_maps" / f"{sv.name}.geometric.bin", v.depth)
        write_dense_map(workdir / "stereo" / "normal_maps" / f"{sv.name}.geometric.bin", v.normal)
    (workdir / "stereo" / "fusion.cfg").write_text("".join(f"{sv.name}\n" for sv in scene.views))
    return workdir



def run_colmap_fusion(workdir: str | Path, options: FusionOptions, num_threads: int = 1) -> FusedCloud:
    """Run ``pycolmap.stereo_fusion`` (CPU) on a workspace from :func:`write_colmap_workspace`.

    ``num_threads=1`` makes COLMAP deterministic. Returns its points; num_views comes from
    ``fused.ply.vis`` (source_view is -1: COLMAP does not record it).
    """
    import pycolmap

    workdir = Path(workdir)
    copts = pycolmap.StereoFusionOptions(
        min_num_pixels=options.min_num_pixels, max_num_pixels=options.max_num_pixels,
        max_traversal_depth=options.max_traversal_depth, max_reproj_error=options.max_reproj_error,
        max_depth_error=options.max_depth_error, max_normal_error=options.max_normal_error,
        check_num_images=options.check_num_images, num_threads=num_threads)
    out = workdir / "fused.ply"
    pycolmap.stereo_fusion(str(out), str(workdir), input_type="geometric", options=copts, output_type="PLY")
    cloud = read_fused_ply(out)
    vis = workdir / "fused.ply.vis"
    if vis.is_file():
        data = np.fromfile(vis, "<u4")
        counts, pos = [], 2  # a uint64 point count comes first
        for _ in range(len(cloud)):
            counts.append(int(data[pos]))
            pos += 1 + int(data[pos])
        cloud.num_views = np.array(counts, np.int32)
    return cloud



def colmap_reference_fusion(scene, views: list[FusionView], options: FusionOptions, workdir: str | Path,
                            num_threads: int = 1, sparse_dir: str | Path | None = None) -> FusedCloud:
    """Fuse the same maps with COLMAP's own fusion as a referee (workspace under ``workdir``)."""
    write_colmap_workspace(scene, views, workdir, sparse_dir)
    return run_colmap_fusion(workdir, options, num_threads)

