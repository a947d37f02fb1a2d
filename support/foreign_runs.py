"""Runs of other MVS systems written by tests: a COLMAP dense workspace and an OpenMVS densify folder whose depth
maps are given arrays, each written from its documented layout (``engine.io.dense``; ``engine.compare.dmap``)."""

from __future__ import annotations

import shutil
import struct
from collections.abc import Callable
from pathlib import Path

import numpy as np

from engine.io.dense import write_dense_map

#: DensifyPointCloud's header: "DR", flags (1 depth, 2 normal, 4 confidence, 8 views), padding, image width and
#: height, depth-map width and height, depth min and max (written here from the format, not from our reader)
DMAP_HEADER = struct.Struct("<2sBB4I2f")


def encode_dmap(image_name: str, depth: np.ndarray, *, image_size: tuple[int, int] | None = None,
                normal: np.ndarray | None = None, confidence: np.ndarray | None = None,
                views: np.ndarray | None = None, view_ids: tuple[int, ...] = (0, 1),
                depth_range: tuple[float, float] = (0.1, 100.0)) -> bytes:
    """The bytes of a float32 ``.dmap`` (DensifyPointCloud's layout) of (H, W) ``depth`` with the optional (H, W, 3)
    normals, (H, W) confidence and (H, W, 4) views maps; a plain K at the map's size, R = I, C = 0."""
    height, width = depth.shape
    flags = 1 + sum(bit for bit, array in ((2, normal), (4, confidence), (8, views)) if array is not None)
    image_w, image_h = image_size or (width, height)
    name = image_name.encode("utf-8")
    K = np.array([[width, 0, width / 2], [0, width, height / 2], [0, 0, 1]], "<f8")
    parts = [DMAP_HEADER.pack(b"DR", flags, 0, image_w, image_h, width, height, *depth_range),
             struct.pack("<H", len(name)), name, struct.pack("<I", len(view_ids)),
             np.asarray(view_ids, "<u4").tobytes(), K.tobytes(), np.eye(3, dtype="<f8").tobytes(),
             np.zeros(3, "<f8").tobytes(), np.asarray(depth, "<f4").tobytes()]
    for array, dtype in ((normal, "<f4"), (confidence, "<f4"), (views, "u1")):
        if array is not None:
            parts.append(np.asarray(array, dtype).tobytes())
    return b"".join(parts)


def write_openmvs_run(scene_dir: Path, out: Path, depth_of: Callable[[str], np.ndarray],
                      names: list[str], image_prefix: str = "../images/") -> Path:
    """An OpenMVS densify folder at ``out``: ``depth0000.dmap`` ... for ``names`` (image names stored as
    ``image_prefix + name``, as OpenMVS stores them relative to its folder) with ``depth_of(name)`` as depth, plus
    normal and confidence maps."""
    out.mkdir(parents=True, exist_ok=True)
    for i, name in enumerate(names):
        depth = np.asarray(depth_of(name), np.float32)
        normal = np.zeros((*depth.shape, 3), np.float32)
        normal[..., 2] = -(depth > 0).astype(np.float32)
        (out / f"depth{i:04d}.dmap").write_bytes(encode_dmap(image_prefix + name, depth, normal=normal,
                                                             confidence=(depth > 0).astype(np.float32)))
    return out


def write_colmap_run(scene_dir: Path, out: Path, depth_of: Callable[[str], np.ndarray], names: list[str],
                     kind: str = "geometric", normal_of: Callable[[str], np.ndarray] | None = None) -> Path:
    """A COLMAP dense workspace at ``out``: the scene's ``sparse/`` and ``images/`` and
    ``stereo/depth_maps/<name>.<kind>.bin`` holding ``depth_of(name)`` for ``names`` (and
    ``stereo/normal_maps/<name>.<kind>.bin`` holding ``normal_of(name)`` when given)."""
    shutil.copytree(scene_dir / "sparse", out / "sparse")
    shutil.copytree(scene_dir / "images", out / "images")
    for name in names:
        write_dense_map(out / "stereo" / "depth_maps" / f"{name}.{kind}.bin", np.asarray(depth_of(name), np.float32))
        if normal_of is not None:
            write_dense_map(out / "stereo" / "normal_maps" / f"{name}.{kind}.bin", normal_of(name))
    return out
