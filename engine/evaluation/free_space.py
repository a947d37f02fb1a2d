"""Observed free space: how far in front of the ground-truth surface a GT view sees a point."""

from __future__ import annotations

import math

import numba
import numpy as np

from engine.camera import Camera
from engine.errors import DeepCError


@numba.njit(cache=True, nogil=True, parallel=True)
def _free_space_margin_kernel(points, E, K, depth, offsets, widths, heights):
    """For each point the largest distance (along the viewing ray) by which it lies in front of the
    GT surface in any GT view; -inf if no view has GT depth at its projection.

    E: (V, 3, 4) world-to-camera [R | t]; K: (V, 3, 3) index-space intrinsics. The surface depth at
    the nearest pixel is the minimum of the valid GT depths in its 3x3 neighbourhood (the centre
    must be valid): at depth edges the nearer surface wins, so points on a foreground silhouette
    are not declared to float in free space.
    """
    n = points.shape[0]
    out = np.full(n, -np.inf)
    for i in numba.prange(n):
        x = points[i, 0]
        y = points[i, 1]
        z = points[i, 2]
        best = -np.inf
        for v in range(E.shape[0]):
            cz = E[v, 2, 0] * x + E[v, 2, 1] * y + E[v, 2, 2] * z + E[v, 2, 3]
            if cz <= 0.0:
                continue
            cx = E[v, 0, 0] * x + E[v, 0, 1] * y + E[v, 0, 2] * z + E[v, 0, 3]
            cy = E[v, 1, 0] * x + E[v, 1, 1] * y + E[v, 1, 2] * z + E[v, 1, 3]
            fu = (K[v, 0, 0] * cx + K[v, 0, 1] * cy) / cz + K[v, 0, 2]
            fv = K[v, 1, 1] * cy / cz + K[v, 1, 2]
            W = widths[v]
            H = heights[v]
            if not (fu > -0.5 and fv > -0.5 and fu < W - 0.5 and fv < H - 0.5):
                continue
            c = min(int(math.floor(fu + 0.5)), W - 1)
            r = min(int(math.floor(fv + 0.5)), H - 1)
            base = offsets[v]
            surf = depth[base + r * W + c]
            if surf <= 0.0:
                continue
            for rr in range(max(r - 1, 0), min(r + 2, H)):
                for cc in range(max(c - 1, 0), min(c + 2, W)):
                    dn = depth[base + rr * W + cc]
                    if dn > 0.0 and dn < surf:
                        surf = dn
            # Depth difference -> distance along the ray: times |X_cam| / z.
            margin = (surf - cz) * math.sqrt(cx * cx + cy * cy + cz * cz) / cz
            if margin > best:
                best = margin
        out[i] = best
    return out



def pack_gt_views(gt_views: list[tuple[Camera, np.ndarray]]) -> tuple:
    """The GT views as the kernel reads them (pass to :func:`free_space_margin` to score many chunks of points)."""
    Es, Ks, depths, offsets, widths, heights = [], [], [], [0], [], []
    for cam, depth in gt_views:
        depth = np.asarray(depth, np.float32)
        if depth.shape != (cam.height, cam.width):
            raise DeepCError(f"GT depth shape {depth.shape} does not match its camera ({cam.height}, {cam.width})")
        Es.append(np.hstack([cam.R, cam.t[:, None]]))
        Ks.append(cam.K_idx)
        depths.append(np.where(np.isfinite(depth), depth, 0).ravel())
        offsets.append(offsets[-1] + depth.size)
        widths.append(cam.width)
        heights.append(cam.height)
    return (np.array(Es), np.array(Ks), np.concatenate(depths).astype(np.float32), np.array(offsets, np.int64),
            np.array(widths, np.int64), np.array(heights, np.int64))



def free_space_margin(points: np.ndarray, gt_views: list[tuple[Camera, np.ndarray]] | tuple) -> np.ndarray:
    """(N,) float64: how far each point lies in front of the GT surface, the maximum over GT views
    (negative = behind or on it, -inf = no GT view has depth at its projection). ``gt_views``: (camera, GT depth)
    pairs, or what :func:`pack_gt_views` made of them."""
    points = np.asarray(points, np.float64)
    if not len(gt_views) or len(points) == 0:
        return np.full(len(points), -np.inf)
    packed = gt_views if isinstance(gt_views, tuple) else pack_gt_views(gt_views)
    return _free_space_margin_kernel(points, *packed)

