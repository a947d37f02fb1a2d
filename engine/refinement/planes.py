"""Local planes in inverse depth, the pyramid and the initial values (Rossi et al. 2020).

A pixel's plane is (d, u): inverse depth d = 1/z and the image-plane gradient u = (u_x, u_y) of the
inverse depth, so that d_j ≈ d_i + u_i · (x_j - x_i) with x = (col, row) in pixels. Intrinsics are
index-space (pixel (col, row) has its centre at (col, row), Schönberger et al. 2016).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage


def _pixel_grid(shape: tuple[int, int], K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """((H, W), (H, W)) normalised coordinates (x - cx) / fx and (y - cy) / fy."""
    h, w = shape
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    return (np.arange(w)[None, :] - cx) / fx + np.zeros((h, 1)), (np.arange(h)[:, None] - cy) / fy + np.zeros((1, w))


def normal_to_u(normal: np.ndarray, depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(H, W, 3) camera-frame normals and (H, W) depth -> (H, W, 2) inverse-depth gradient u.

    ρ = n · X = z (n_x (x - cx)/fx + n_y (y - cy)/fy + n_z); u = (n_x / (ρ fx), n_y / (ρ fy)).
    Pixels with ρ = 0, no depth or a zero normal get u = 0.
    """
    n = np.asarray(normal, np.float64)
    z = np.asarray(depth, np.float64)
    gx, gy = _pixel_grid(z.shape, K)
    rho = z * (n[..., 0] * gx + n[..., 1] * gy + n[..., 2])
    ok = (np.abs(rho) > 1e-12) & (z > 0)
    safe = np.where(ok, rho, 1.0)
    u = np.stack([n[..., 0] / (safe * K[0, 0]), n[..., 1] / (safe * K[1, 1])], axis=-1)
    return np.where(ok[..., None], u, 0.0)


def u_to_normal(u: np.ndarray, inv_depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(H, W, 2) u and (H, W) inverse depth d -> (H, W, 3) unit normals facing the camera.

    v = (u_x fx, u_y fy, d - u_x (x - cx) - u_y (y - cy)); n = -v / |v| (so n · X = -1/|v| < 0).
    """
    u = np.asarray(u, np.float64)
    d = np.asarray(inv_depth, np.float64)
    h, w = d.shape
    xs = np.arange(w)[None, :] - K[0, 2]
    ys = np.arange(h)[:, None] - K[1, 2]
    v = np.stack([u[..., 0] * K[0, 0], u[..., 1] * K[1, 1], d - u[..., 0] * xs - u[..., 1] * ys], axis=-1)
    return -v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-30)


def pyramid_shapes(shape: tuple[int, int], scales: int) -> list[tuple[int, int]]:
    """Sizes fine -> coarse; each is (round(H/2), round(W/2)) of the previous (at least 1)."""
    out = [tuple(shape)]
    for _ in range(scales - 1):
        h, w = out[-1]
        out.append((max(1, math.floor(h / 2 + 0.5)), max(1, math.floor(w / 2 + 0.5))))
    return out


def scale_intrinsics(K: np.ndarray, src_shape: tuple[int, int], dst_shape: tuple[int, int]) -> np.ndarray:
    """Index-space K of a pixel-area-aligned resampling from (H, W) ``src_shape`` to ``dst_shape``."""
    sy, sx = dst_shape[0] / src_shape[0], dst_shape[1] / src_shape[1]
    K = np.array(K, np.float64)
    out = K.copy()
    out[0, 0], out[1, 1] = K[0, 0] * sx, K[1, 1] * sy
    out[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
    out[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
    return out


def _source_index(n_dst: int, n_src: int) -> np.ndarray:
    """Nearest source index of each destination pixel centre on the area-aligned grid."""
    return np.minimum(np.floor((np.arange(n_dst) + 0.5) * (n_src / n_dst)).astype(np.int64), n_src - 1)


def resize_nearest(a: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Nearest-neighbour resampling of an (H, W, ...) map to ``shape`` (area-aligned pixel centres)."""
    rows = _source_index(shape[0], a.shape[0])
    cols = _source_index(shape[1], a.shape[1])
    return a[rows[:, None], cols[None, :]]


def resize_linear(image: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Bilinear resampling of an (H, W) image to ``shape``; centres at -0.5 + Δ/2 + kΔ (clamped)."""
    src = np.asarray(image, np.float64)

    def coords(n_dst, n_src):
        c = np.clip(-0.5 + (np.arange(n_dst) + 0.5) * (n_src / n_dst), 0, n_src - 1)
        lo = np.minimum(np.floor(c).astype(np.int64), max(n_src - 2, 0))
        return lo, np.minimum(lo + 1, n_src - 1), c - lo

    r0, r1, fr = coords(shape[0], src.shape[0])
    c0, c1, fc = coords(shape[1], src.shape[1])
    top = src[r0][:, c0] * (1 - fc) + src[r0][:, c1] * fc
    bottom = src[r1][:, c0] * (1 - fc) + src[r1][:, c1] * fc
    return top * (1 - fr[:, None]) + bottom * fr[:, None]


def nearest_fill(values: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Copy into every invalid pixel the value of the nearest valid pixel (Euclidean); (H, W, ...)."""
    if valid.all() or not valid.any():
        return values.copy()
    _, (rows, cols) = ndimage.distance_transform_edt(~valid, return_indices=True)
    return values[rows, cols]


def gradient_init(inv_depth: np.ndarray) -> np.ndarray:
    """(H, W, 2) u from Gaussian-derivative filtering of d (5x5, σ = 5, normalised by Σ|kernel|), the
    official initialisation when no normals are given (only approximately a derivative)."""
    t = np.arange(-2, 3, dtype=np.float64)
    g = np.exp(-t ** 2 / (2 * 25.0))
    dg = -t * g
    kx = np.outer(g, dg)
    kx /= np.abs(kx).sum()
    d = np.asarray(inv_depth, np.float64)
    # Correlation with -kernel gives d(x+1) - d(x-1) orientation (a positive slope gives positive u).
    ux = ndimage.correlate(d, -kx, mode="nearest")
    uy = ndimage.correlate(d, -kx.T, mode="nearest")
    return np.stack([ux, uy], axis=-1)
