"""A fused cloud as a binary PLY with its per-point attributes (views, confidence, source view, pixels)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from engine.fusion.cloud import FusedCloud
from engine.io.ply import read_ply, vertex_dtype, vertex_fields, write_ply

_EXTRA = ("num_views", "confidence", "source_view", "num_pixels")
# The properties write_fused_ply writes (its extra attributes' dtypes), and one record of the file's body (43 bytes)
FUSED_FIELDS = vertex_fields("f4", True, True, {"num_views": np.dtype(np.int32), "confidence": np.dtype(np.float32),
                                                "source_view": np.dtype(np.int32), "num_pixels": np.dtype(np.int32)})
FUSED_RECORD = vertex_dtype(FUSED_FIELDS)


def fill_records(table: np.ndarray, xyz: np.ndarray, normal: np.ndarray, rgb: np.ndarray, num_views: np.ndarray,
                 confidence: np.ndarray, source_view: np.ndarray, num_pixels: np.ndarray) -> np.ndarray:
    """``table[:n]`` (``FUSED_RECORD``) filled with n points' attributes as :func:`write_fused_ply` stores them (the
    same casts: float64 positions rounded to float32); returns that part."""
    part = table[:len(xyz)]
    for a, name in enumerate("xyz"):
        part[name] = xyz[:, a]
    for a, name in enumerate(("nx", "ny", "nz")):
        part[name] = normal[:, a]
    for a, name in enumerate(("red", "green", "blue")):
        part[name] = rgb[:, a]
    part["num_views"], part["confidence"] = num_views, confidence
    part["source_view"], part["num_pixels"] = source_view, num_pixels
    return part



def write_fused_ply(path: str | Path, cloud: FusedCloud) -> None:
    """Write ``fused.ply``: binary little-endian, float32 x/y/z, nx/ny/nz, uchar red/green/blue, plus the
    viewer attributes ``num_views`` (int), ``confidence`` (float, NaN = none), ``source_view`` (int)."""
    write_ply(path, np.asarray(cloud.xyz, np.float32), normals=np.asarray(cloud.normal, np.float32),
              rgb=np.asarray(cloud.rgb, np.uint8),
              extra={"num_views": np.asarray(cloud.num_views, np.int32),
                     "confidence": np.asarray(cloud.mean_confidence, np.float32),
                     "source_view": np.asarray(cloud.source_view, np.int32),
                     "num_pixels": np.asarray(cloud.num_pixels, np.int32)})



def read_fused_ply(path: str | Path) -> FusedCloud:
    """Read a fused cloud (ours or COLMAP's ``fused.ply``); missing attributes get neutral values
    (normals 0, colour 0, num_views 0, confidence NaN, source_view -1)."""
    cols = read_ply(path)
    n = len(cols["x"])
    xyz = np.stack([cols["x"], cols["y"], cols["z"]], axis=1)

    def stack(names, dtype, fill):
        if all(k in cols for k in names):
            return np.stack([cols[k] for k in names], axis=1).astype(dtype)
        return np.full((n, len(names)), fill, dtype)

    def column(name, dtype, fill):
        return cols[name].astype(dtype) if name in cols else np.full(n, fill, dtype)

    return FusedCloud(xyz, stack(("nx", "ny", "nz"), np.float32, 0), stack(("red", "green", "blue"), np.uint8, 0),
                      column("num_views", np.int32, 0), column("confidence", np.float32, np.nan),
                      column("source_view", np.int32, -1), column("num_pixels", np.int32, 0))

