"""A tiny analytic multi-view scene for the PatchMatch tests: textured planes seen by pinhole cameras.

The surface is z = min over three planes (world frame, y down): two walls forming a corner that
opens towards the cameras and a floor, so there are creases but no occlusion edges. Texture is smooth
value noise in plane coordinates (features of a few pixels), rendered with 3×3 supersampling. The
cameras sit on an arc looking at the corner. Ground-truth depth is the camera z of the hit at the
pixel centre (index-space convention).
"""

from __future__ import annotations

import numpy as np

from engine.core.camera import Camera
from engine.patchmatch import PatchMatchView

_GRID = np.random.default_rng(1234).random((4, 256, 256))


def _value_noise(u: np.ndarray, v: np.ndarray, layer: int, cell: float) -> np.ndarray:
    g = _GRID[layer]
    x = u / cell
    y = v / cell
    x0 = np.floor(x).astype(np.int64)
    y0 = np.floor(y).astype(np.int64)
    fx = x - x0
    fy = y - y0
    fx = fx * fx * (3 - 2 * fx)
    fy = fy * fy * (3 - 2 * fy)
    x0 %= 256
    y0 %= 256
    x1 = (x0 + 1) % 256
    y1 = (y0 + 1) % 256
    top = g[y0, x0] * (1 - fx) + g[y0, x1] * fx
    bot = g[y1, x0] * (1 - fx) + g[y1, x1] * fx
    return top * (1 - fy) + bot * fy


def _texture(u: np.ndarray, v: np.ndarray, layer: int) -> np.ndarray:
    t = 0.6 * _value_noise(u, v, layer, 0.35) + 0.4 * _value_noise(u, v, layer + 1, 0.14)
    return 0.1 + 0.8 * np.clip(t + 0.1 * np.sin(9 * u) * np.cos(7 * v), 0, 1)


# planes: point, normal (world), in-plane axes, extent box in plane coords (None = unbounded), layer
_PLANES = [
    (np.array([0.0, 0.0, 5.5]), np.array([0.35, 0.0, -1.0]), None, 0),
    (np.array([0.0, 0.0, 5.5]), np.array([-0.35, 0.0, -1.0]), None, 1),
    (np.array([0.0, 1.2, 4.5]), np.array([0.0, -1.0, -0.7]), None, 2),
]


def _render(cam: Camera, ss: int = 3) -> tuple[np.ndarray, np.ndarray]:
    h, w = cam.height, cam.width
    Ki = np.linalg.inv(cam.K_idx)
    offs = (np.arange(ss) + 0.5) / ss - 0.5
    img = np.zeros((h, w))
    depth = np.zeros((h, w))
    C = cam.center
    for sy in offs:
        for sx in offs:
            cols, rows = np.meshgrid(np.arange(w) + sx, np.arange(h) + sy)
            rays_c = np.stack([cols, rows, np.ones_like(cols)], -1) @ Ki.T  # z = 1
            rays_w = rays_c @ cam.R  # R^T r
            best_t = np.full((h, w), np.inf)
            val = np.zeros((h, w))
            for P, n, box, layer in _PLANES:
                n = n / np.linalg.norm(n)
                a = np.cross(n, [0.0, 1.0, 0.0])
                a /= np.linalg.norm(a)
                b = np.cross(n, a)
                den = rays_w @ n
                with np.errstate(divide="ignore", invalid="ignore"):
                    t = ((P - C) @ n) / den
                X = C + t[..., None] * rays_w
                u = (X - P) @ a
                v = (X - P) @ b
                ok = (t > 0) & np.isfinite(t)
                if box is not None:
                    ok &= (u > box[0]) & (u < box[1]) & (v > box[2]) & (v < box[3])
                closer = ok & (t < best_t)
                best_t = np.where(closer, t, best_t)
                val = np.where(closer, _texture(u + 10, v + 10, layer), val)
            img += val
            if sx == offs[ss // 2] and sy == offs[ss // 2]:
                depth = np.where(np.isfinite(best_t), best_t, 0.0)  # camera z since ray z = 1
    return (img / ss**2).astype(np.float32), depth.astype(np.float32)


def make_scene(width: int = 120, height: int = 90, n_views: int = 4, baseline: float = 0.15,
               n_sources: int | None = None) -> tuple[list[PatchMatchView], list[np.ndarray]]:
    """Views (all others as sources unless ``n_sources``) and GT depth maps; ``baseline`` is the
    angle (radians) between neighbouring cameras on the arc."""
    f = 1.2 * width
    views, gts = [], []
    target = np.array([0.0, 0.2, 5.0])
    angles = (np.arange(n_views) - (n_views - 1) / 2) * baseline
    for i, a in enumerate(angles):
        Cw = target + 4.6 * np.array([np.sin(a), 0.08 * ((i % 2) * 2 - 1), -np.cos(a)])
        fwd = target - Cw
        fwd /= np.linalg.norm(fwd)
        right = np.cross([0.0, 1.0, 0.0], fwd)
        right /= np.linalg.norm(right)
        down = np.cross(fwd, right)
        R = np.stack([right, down, fwd])  # rows: camera axes in world
        t = -R @ Cw
        cam = Camera.from_params(width, height, f, f, width / 2, height / 2, R, t)
        img, gt = _render(cam)
        others = [j for j in range(n_views) if j != i]
        if n_sources is not None:
            others = sorted(others, key=lambda j: abs(j - i))[:n_sources]
        views.append(PatchMatchView(f"view{i}", img, cam, 0.0, 0.0, others))
        gts.append(gt)
    # depth range as a sparse model would give it: GT extent stretched by 0.75 / 1.25
    for v, gt in zip(views, gts, strict=True):
        v.depth_min = 0.75 * float(gt[gt > 0].min())
        v.depth_max = 1.25 * float(gt.max())
    return views, gts
