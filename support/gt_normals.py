"""Normals of ground-truth depth maps, for tests and benchmarks that need oriented GT."""

from __future__ import annotations

import numpy as np

from engine.core.camera import Camera


def depth_normals(camera: Camera, depth: np.ndarray, max_relative_jump: float = 0.02) -> np.ndarray:
    """(H, W, 3) float32 camera-frame normals estimated from a depth map (e.g. ground truth).

    Central differences of the back-projected points (index-space K), oriented towards the camera.
    Pixels without depth, at the border, or next to a depth jump larger than ``max_relative_jump``
    (relative to the centre depth) get the zero vector: callers usually drop them.
    """
    depth = np.asarray(depth, np.float64)
    if depth.shape != (camera.height, camera.width):
        raise ValueError(f"depth shape {depth.shape} does not match camera ({camera.height}, {camera.width})")
    X = camera.pixel_rays() * depth[..., None]
    out = np.zeros(depth.shape + (3,), np.float32)
    if min(depth.shape) < 3:
        return out
    c = depth[1:-1, 1:-1]
    nbrs = (depth[1:-1, 2:], depth[1:-1, :-2], depth[2:, 1:-1], depth[:-2, 1:-1])
    ok = c > 0
    for nb in nbrs:
        ok &= (nb > 0) & (np.abs(nb - c) <= max_relative_jump * c)
    dx = X[1:-1, 2:] - X[1:-1, :-2]
    dy = X[2:, 1:-1] - X[:-2, 1:-1]
    n = np.cross(dx, dy)
    norm = np.linalg.norm(n, axis=-1)
    ok &= norm > 0
    n = n / np.where(norm > 0, norm, 1.0)[..., None]
    flip = np.einsum("ijk,ijk->ij", n, X[1:-1, 1:-1]) > 0
    n[flip] *= -1
    out[1:-1, 1:-1] = np.where(ok[..., None], n, 0.0)
    return out

