"""Observed free space: how far in front of the ground-truth surface a GT view sees a point."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable

import numba
import numpy as np

from engine.core.camera import Camera
from engine.core.errors import DeepCError


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


def pack_gt_views(gt_views: Iterable[tuple[Camera, np.ndarray | Callable[[], np.ndarray]]]) -> tuple:
    """The GT views as the kernel reads them (pass to :func:`free_space_margin` to score many chunks of points).

    A view's depth may be given as a function that reads it: each is then read only while it is copied into the
    packed array (4 bytes a pixel in all, whatever the number of views)."""
    gt_views = list(gt_views)
    widths = np.array([cam.width for cam, _ in gt_views], np.int64)
    heights = np.array([cam.height for cam, _ in gt_views], np.int64)
    offsets = np.concatenate([[0], np.cumsum(widths * heights)]).astype(np.int64)
    depths = np.empty(int(offsets[-1]), np.float32)
    for k, (cam, depth) in enumerate(gt_views):
        depth = np.asarray(depth() if callable(depth) else depth, np.float32)
        if depth.shape != (cam.height, cam.width):
            raise DeepCError(f"GT depth shape {depth.shape} does not match its camera ({cam.height}, {cam.width})")
        packed = depths[offsets[k]:offsets[k + 1]]
        packed[:] = depth.ravel()
        packed[~np.isfinite(packed)] = 0
    Es = np.array([np.hstack([cam.R, cam.t[:, None]]) for cam, _ in gt_views])
    Ks = np.array([cam.K_idx for cam, _ in gt_views])
    return Es, Ks, depths, offsets, widths, heights


def free_space_margin(points: np.ndarray, gt_views: list[tuple[Camera, np.ndarray]] | tuple) -> np.ndarray:
    """(N,) float64: how far each point lies in front of the GT surface, the maximum over GT views
    (negative = behind or on it, -inf = no GT view has depth at its projection). ``gt_views``: (camera, GT depth)
    pairs, or what :func:`pack_gt_views` made of them."""
    points = np.asarray(points, np.float64)
    if not len(gt_views) or len(points) == 0:
        return np.full(len(points), -np.inf)
    packed = gt_views if isinstance(gt_views, tuple) else pack_gt_views(gt_views)
    return _free_space_margin_kernel(points, *packed)

