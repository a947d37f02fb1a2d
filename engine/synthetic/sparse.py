"""An SfM-like sparse model drawn from exact ground truth.

Like a real SfM output (COLMAP): features sit on well-textured pixels (Shi-Tomasi score, one per
grid cell, some dropped at random), each is back-projected with the GT depth, and observed in
every other view where it is visible; points seen in fewer than ``min_views`` views are dropped;
2-D observations and 3-D positions carry small noise. Visibility is decided exactly: the ray of
the other view through the projected point must hit the scene at the point's depth (within
``depth_tolerance``), i.e. the GT depth test at the sub-pixel location, not at the nearest pixel.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

import engine.synthetic.raycast as raycast
from engine.core.camera import Camera
from engine.synthetic.scene import SceneData, SparseModel

_MAX_INCIDENCE_COS = np.cos(np.radians(80.0))  # features are not matched at grazing angles


def feature_score(image: np.ndarray) -> np.ndarray:
    """(H, W) Shi-Tomasi corner score of an (H, W, 3) uint8 image, in grey levels per pixel.

    The score is sqrt of the smaller eigenvalue of the Gaussian-weighted structure tensor.
    """
    grey = image.astype(np.float64).mean(axis=2)
    gx = ndimage.sobel(grey, axis=1, mode="nearest") / 8.0
    gy = ndimage.sobel(grey, axis=0, mode="nearest") / 8.0
    sxx = ndimage.gaussian_filter(gx * gx, 1.0)
    syy = ndimage.gaussian_filter(gy * gy, 1.0)
    sxy = ndimage.gaussian_filter(gx * gy, 1.0)
    half_trace = 0.5 * (sxx + syy)
    lam_min = half_trace - np.sqrt(np.maximum(0.25 * (sxx - syy) ** 2 + sxy * sxy, 0.0))
    return np.sqrt(np.maximum(lam_min, 0.0))


def select_features(score: np.ndarray, depth: np.ndarray, cell: int, border: int, min_score: float,
                    rng: np.random.Generator, keep: float = 0.85) -> np.ndarray:
    """(F, 2) int (col, row) of the best pixel of every ``cell`` x ``cell`` block.

    Only pixels with GT depth, away from the border and with score >= ``min_score`` qualify; a
    random ``1 - keep`` of the picks is dropped (real detectors and matchers miss some).
    """
    h, w = score.shape
    s = np.where(depth > 0, score, -1.0)
    s[:border], s[h - border:], s[:, :border], s[:, w - border:] = -1.0, -1.0, -1.0, -1.0
    ny, nx = -(-h // cell), -(-w // cell)
    padded = np.full((ny * cell, nx * cell), -1.0)
    padded[:h, :w] = s
    blocks = padded.reshape(ny, cell, nx, cell).transpose(0, 2, 1, 3).reshape(ny, nx, cell * cell)
    best = blocks.argmax(axis=2)
    good = np.take_along_axis(blocks, best[..., None], axis=2)[..., 0] >= min_score
    by, bx = np.nonzero(good)
    rows = by * cell + best[by, bx] // cell
    cols = bx * cell + best[by, bx] % cell
    picked = rng.random(len(rows)) < keep
    return np.stack([cols[picked], rows[picked]], axis=1)


def visible_in(data: SceneData, camera: Camera, points: np.ndarray, normals_world: np.ndarray,
               tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """Which (N, 3) world points does ``camera`` see? Returns (N,) bool and (N, 2) index-space uv."""
    uv, z = camera.project(points)
    inside = (z > 0) & (uv[:, 0] >= -0.5) & (uv[:, 0] < camera.width - 0.5) \
        & (uv[:, 1] >= -0.5) & (uv[:, 1] < camera.height - 0.5)
    ok = np.zeros(len(points), bool)
    idx = np.flatnonzero(inside)
    if len(idx):
        rays = np.linalg.solve(camera.K_idx, np.c_[uv[idx], np.ones(len(idx))].T).T  # z = 1
        dirs = rays @ camera.R
        hits = raycast.cast(data.scene.primitives, camera.center, dirs)
        agree = np.abs(hits.s - z[idx]) <= tolerance * z[idx]
        view_dir = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
        facing = -np.einsum("ij,ij->i", view_dir, normals_world[idx]) > _MAX_INCIDENCE_COS
        ok[idx] = agree & facing
    return ok, uv


def make_sparse_model(data: SceneData, rng: np.random.Generator) -> SparseModel:
    """Draw the sparse model of a rendered scene (see the module docstring)."""
    settings = data.scene.sparse
    cams = data.cameras
    xyz_all, rgb_all, obs_point, obs_view, obs_xy = [], [], [], [], []
    next_id = 0
    for v, cam in enumerate(cams):
        depth = data.depths[v]
        feats = select_features(feature_score(data.images[v]), depth, settings.cell_size, settings.border,
                                settings.min_score, rng)
        if len(feats) == 0:
            continue
        cols, rows = feats[:, 0], feats[:, 1]
        z = depth[rows, cols].astype(np.float64)
        rays = np.linalg.solve(cam.K_idx, np.c_[cols, rows, np.ones(len(cols))].T).T
        X = cam.camera_to_world(rays * z[:, None])
        n_world = data.normals[v][rows, cols].astype(np.float64) @ cam.R  # camera -> world
        seen = np.zeros((len(cams), len(X)), bool)
        uvs = np.zeros((len(cams), len(X), 2))
        for u, other in enumerate(cams):
            if u == v:
                seen[u], uvs[u] = True, np.c_[cols, rows]
            elif settings.neighbours and abs(u - v) > settings.neighbours:
                continue  # a long sequence: views far along it cannot see the feature (O(N) casts, not O(N^2))
            else:
                seen[u], uvs[u] = visible_in(data, other, X, n_world, settings.depth_tolerance)
        keep = seen.sum(axis=0) >= settings.min_views
        if not keep.any():
            continue
        X, z, seen, uvs = X[keep], z[keep], seen[:, keep], uvs[:, keep]
        noise3 = np.clip(rng.normal(0.0, 1.0, X.shape), -2.0, 2.0) * (settings.noise_rel_3d * z)[:, None]
        xyz_all.append(X + noise3)
        rgb_all.append(data.images[v][rows[keep], cols[keep]])
        for u in range(len(cams)):
            sel = np.flatnonzero(seen[u])
            noise2 = np.clip(rng.normal(0.0, 1.0, (len(sel), 2)), -2.0, 2.0) * settings.noise_px
            obs_point.append(next_id + sel)
            obs_view.append(np.full(len(sel), u))
            obs_xy.append(uvs[u, sel] + 0.5 + noise2)  # index space -> COLMAP continuous
        next_id += len(X)
    if next_id == 0:
        empty = np.zeros(0, np.int64)
        return SparseModel(np.zeros((0, 3)), np.zeros((0, 3), np.uint8), empty, empty, np.zeros((0, 2)))
    obs_point_arr = np.concatenate(obs_point).astype(np.int64)
    order = np.argsort(obs_point_arr, kind="stable")  # group observations by point
    return SparseModel(
        xyz=np.concatenate(xyz_all),
        rgb=np.concatenate(rgb_all).astype(np.uint8),
        obs_point=obs_point_arr[order],
        obs_view=np.concatenate(obs_view).astype(np.int64)[order],
        obs_xy=np.concatenate(obs_xy)[order],
    )
