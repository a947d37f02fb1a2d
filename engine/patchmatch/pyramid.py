"""Image pyramid and joint bilateral upsampling (the multi-scale scheme of Xu & Tao 2019 ACMM).

Level sizes are round(W·0.5^ℓ) × round(H·0.5^ℓ) of the working size; images are area-averaged
(exact pixel-overlap weights, like cv2.INTER_AREA) and cameras rescaled with ``Camera.rescaled``.
Pixel-centre alignment between levels: index-space coordinate x at size W maps to
(x + 0.5)·W'/W - 0.5 at size W'.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange


def level_size(width: int, height: int, level: int) -> tuple[int, int]:
    """(W, H) of pyramid level ``level`` (0 = the given size)."""
    s = 0.5**level
    return max(1, int(round(width * s))), max(1, int(round(height * s)))


def _area_matrix(n_in: int, n_out: int) -> np.ndarray:
    """(n_out, n_in) row-stochastic matrix of pixel-overlap weights."""
    m = np.zeros((n_out, n_in))
    scale = n_in / n_out
    for o in range(n_out):
        lo, hi = o * scale, (o + 1) * scale
        for i in range(int(math.floor(lo)), min(int(math.ceil(hi)), n_in)):
            m[o, i] = min(hi, i + 1) - max(lo, i)
    return m / m.sum(axis=1, keepdims=True)


def area_resize(img: np.ndarray, width: int, height: int) -> np.ndarray:
    """Area-averaged resize of an (H, W) image to (height, width), float32."""
    h, w = img.shape
    if (w, h) == (width, height):
        return np.ascontiguousarray(img, dtype=np.float32)
    out = _area_matrix(h, height) @ img.astype(np.float64) @ _area_matrix(w, width).T
    return out.astype(np.float32)


@njit(cache=True, parallel=True, fastmath=True)
def jbu_kernel(depth_lo, normal_lo, guide_hi, radius, sigma_s, sigma_r, depth_hi, normal_hi):
    """Joint bilateral upsampling of depth and normals guided by the high-res image.

    depth_lo (h, w) f32 (0 = invalid, excluded), normal_lo (h, w, 3), guide_hi (H, W) in [0, 1];
    sigma_s in low-res pixels, sigma_r on [0, 1] intensities. Writes depth_hi (H, W) (0 where no
    valid low-res sample) and normal_hi (H, W, 3) (renormalised weighted mean)."""
    hl, wl = depth_lo.shape
    hh, wh = guide_hi.shape
    fx = wl / wh
    fy = hl / hh
    for y in prange(hh):
        for x in range(wh):
            px = (x + 0.5) * fx - 0.5
            py = (y + 0.5) * fy - 0.5
            cx = int(math.floor(px + 0.5))
            cy = int(math.floor(py + 0.5))
            g = guide_hi[y, x]
            sw = 0.0
            sd = 0.0
            s0 = 0.0
            s1 = 0.0
            s2 = 0.0
            for j in range(-radius, radius + 1):
                qy = min(max(cy + j, 0), hl - 1)
                for i in range(-radius, radius + 1):
                    qx = min(max(cx + i, 0), wl - 1)
                    d = depth_lo[qy, qx]
                    if d <= 0.0:
                        continue
                    ux = min(max(int(math.floor((qx + 0.5) / fx - 0.5 + 0.5)), 0), wh - 1)
                    uy = min(max(int(math.floor((qy + 0.5) / fy - 0.5 + 0.5)), 0), hh - 1)
                    dx = px - qx
                    dy = py - qy
                    dr = g - guide_hi[uy, ux]
                    wgt = math.exp(-(dx * dx + dy * dy) / (2.0 * sigma_s * sigma_s)
                                   - dr * dr / (2.0 * sigma_r * sigma_r))
                    sw += wgt
                    sd += wgt * d
                    s0 += wgt * normal_lo[qy, qx, 0]
                    s1 += wgt * normal_lo[qy, qx, 1]
                    s2 += wgt * normal_lo[qy, qx, 2]
            nn = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
            if sw <= 1e-30 or nn <= 1e-12:
                depth_hi[y, x] = 0.0
                normal_hi[y, x, 0] = 0.0
                normal_hi[y, x, 1] = 0.0
                normal_hi[y, x, 2] = 0.0
            else:
                depth_hi[y, x] = sd / sw
                normal_hi[y, x, 0] = s0 / nn
                normal_hi[y, x, 1] = s1 / nn
                normal_hi[y, x, 2] = s2 / nn


def jbu_upsample(depth_lo: np.ndarray, normal_lo: np.ndarray, guide_hi: np.ndarray, radius: int,
                 sigma_s: float, sigma_r: float) -> tuple[np.ndarray, np.ndarray]:
    """Upsample (depth, normal) to the guide's size; see :func:`jbu_kernel`."""
    hh, wh = guide_hi.shape
    depth_hi = np.empty((hh, wh), np.float32)
    normal_hi = np.empty((hh, wh, 3), np.float32)
    jbu_kernel(np.ascontiguousarray(depth_lo, np.float32), np.ascontiguousarray(normal_lo, np.float32),
               np.ascontiguousarray(guide_hi, np.float32), int(radius), float(sigma_s), float(sigma_r),
               depth_hi, normal_hi)
    return depth_hi, normal_hi
