"""Plain-numpy references of the evaluation kernels (free space, ETH3D beam model), used by their tests."""

from __future__ import annotations

import math

import numpy as np

from engine.core.camera import Camera


def free_space_margin_reference(points: np.ndarray, gt_views: list[tuple[Camera, np.ndarray]]) -> np.ndarray:
    """Plain numpy version of :func:`free_space_margin` (for tests)."""
    points = np.asarray(points, np.float64)
    best = np.full(len(points), -np.inf)
    for cam, depth in gt_views:
        depth = np.asarray(depth, np.float64)
        H, W = depth.shape
        uv, z = cam.project(points)
        with np.errstate(invalid="ignore"):
            inside = (z > 0) & (uv[:, 0] > -0.5) & (uv[:, 1] > -0.5) & (uv[:, 0] < W - 0.5) & (uv[:, 1] < H - 0.5)
        for i in np.flatnonzero(inside):
            c = min(int(math.floor(uv[i, 0] + 0.5)), W - 1)
            r = min(int(math.floor(uv[i, 1] + 0.5)), H - 1)
            if depth[r, c] <= 0:
                continue
            block = depth[max(r - 1, 0):r + 2, max(c - 1, 0):c + 2]
            surf = block[block > 0].min()
            Xc = cam.world_to_camera(points[i])
            margin = (surf - z[i]) * np.linalg.norm(Xc) / z[i]
            best[i] = max(best[i], margin)
    return best



def classify_beam_reference(recon_scan_frame: np.ndarray, scan_points: np.ndarray, tolerances: np.ndarray,
                            beam_start_radius: float, half_angle_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Brute-force numpy version of :func:`classify_beam` (every scan ray is a candidate; for tests)."""
    g = np.asarray(scan_points, np.float64)
    g = g[np.linalg.norm(g, axis=1) > 0]
    rg = np.linalg.norm(g, axis=1)
    dirs = g / rg[:, None]
    tol_sq = np.asarray(tolerances, np.float64) ** 2
    n_tol = len(tol_sq)
    tan_half = math.tan(math.radians(half_angle_deg))
    first = np.full(len(recon_scan_frame), n_tol, np.int64)
    flag = np.zeros(len(recon_scan_frame), bool)
    for i, p in enumerate(np.asarray(recon_scan_frame, np.float64)):
        r = np.linalg.norm(p)
        if r == 0:
            continue
        beam = beam_start_radius + r * tan_half
        t = dirs @ p
        perp = np.sum((p[None, :] - t[:, None] * dirs) ** 2, axis=1)
        seen = (t >= 0) & (perp <= beam * beam)
        if not seen.any():
            continue
        d2 = np.sum((g[seen] - p) ** 2, axis=1)
        ok = d2[:, None] <= tol_sq[None, :]
        hits = np.flatnonzero(ok.any(axis=0))
        first[i] = hits[0] if len(hits) else n_tol
        flag[i] = bool((t[seen] < rg[seen]).any())
    return first, flag

