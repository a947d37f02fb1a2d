"""Bilaterally weighted NCC (SPEC.md §2.3).

The weights depend only on the reference image, so they are computed once per reference view and
level (:func:`bilateral_moments`): normalised weights w (H, W, S), the products w·a, and the window
mean μ_a and variance v_a. A cost evaluation then only samples the source image:
μ_b = Σ w b, v_b = Σ w b² - μ_b², cov = Σ (w a) b - μ_a μ_b, cost = clamp(1 - cov/√(v_a v_b), 0, 2),
and 2 when either variance is below ``min_var`` or the warped centre is behind or outside the source.

Source images are stored padded by one replicated row and column, (N, Hmax+1, Wmax+1), so that
bilinear sampling at a coordinate clamped to [0, W-1] never reads out of bounds (border mode).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

WEIGHTING_CODES = {"colmap": 0, "acmm": 1}


def window_offsets_2d(offsets_1d: list[int]) -> np.ndarray:
    """(S, 2) int32 (dx, dy) offsets of the window, row-major over dy then dx."""
    return np.array([(dx, dy) for dy in offsets_1d for dx in offsets_1d], dtype=np.int32)


@njit(cache=True, parallel=True, fastmath=True)
def _bilateral_moments_kernel(img, offs, mode, sigma_s, sigma_c, wgt, wa, mu_a, var_a):
    h, w = img.shape
    n_off = offs.shape[0]
    for y in prange(h):
        for x in range(w):
            a0 = img[y, x]
            s = 0.0
            for k in range(n_off):
                dx = offs[k, 0]
                dy = offs[k, 1]
                xx = min(max(x + dx, 0), w - 1)
                yy = min(max(y + dy, 0), h - 1)
                a = img[yy, xx]
                if mode == 0:
                    e = -(dx * dx + dy * dy) / (2.0 * sigma_s * sigma_s) - (a - a0) ** 2 / (2.0 * sigma_c * sigma_c)
                else:
                    e = (-math.sqrt(dx * dx + dy * dy) / (2.0 * sigma_s * sigma_s)
                         - abs(a - a0) * 255.0 / (2.0 * sigma_c * sigma_c))
                ww = math.exp(e)
                wgt[y, x, k] = ww
                s += ww
            inv = 1.0 / s
            m = 0.0
            m2 = 0.0
            for k in range(n_off):
                xx = min(max(x + offs[k, 0], 0), w - 1)
                yy = min(max(y + offs[k, 1], 0), h - 1)
                a = img[yy, xx]
                ww = wgt[y, x, k] * inv
                wgt[y, x, k] = ww
                wa[y, x, k] = ww * a
                m += ww * a
                m2 += ww * a * a
            mu_a[y, x] = m
            var_a[y, x] = max(m2 - m * m, 0.0)


def bilateral_moments(img: np.ndarray, offs: np.ndarray, weighting: str, sigma_s: float,
                      sigma_c: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Reference-side NCC terms of one image.

    Args:
        img: (H, W) float32 grey image in [0, 1].
        offs: (S, 2) int32 window offsets (dx, dy).
        weighting: 'colmap' (sigma_c on [0,1]) or 'acmm' (sigma_c on 0-255).
    Returns:
        wgt (H, W, S) float32 normalised weights (sum 1 per pixel), wa = wgt·a (H, W, S) float32,
        mu_a (H, W) float32 weighted mean, var_a (H, W) float32 weighted variance. Reference pixels
        outside the image are clamped to the border.
    """
    img = np.ascontiguousarray(img, dtype=np.float32)
    h, w = img.shape
    s = offs.shape[0]
    wgt = np.empty((h, w, s), np.float32)
    wa = np.empty((h, w, s), np.float32)
    mu_a = np.empty((h, w), np.float32)
    var_a = np.empty((h, w), np.float32)
    _bilateral_moments_kernel(img, offs, WEIGHTING_CODES[weighting], float(sigma_s), float(sigma_c),
                              wgt, wa, mu_a, var_a)
    return wgt, wa, mu_a, var_a


def pad_sources(images: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Stack source images into (N, Hmax+1, Wmax+1) float32 with a replicated border row/column.

    Returns the stack and (N, 2) int32 sizes (W, H)."""
    hm = max(im.shape[0] for im in images)
    wm = max(im.shape[1] for im in images)
    out = np.zeros((len(images), hm + 1, wm + 1), np.float32)
    sizes = np.zeros((len(images), 2), np.int32)
    for j, im in enumerate(images):
        h, w = im.shape
        out[j, :h, :w] = im
        out[j, :h, w] = im[:, w - 1]
        out[j, h, :w] = im[h - 1]
        out[j, h, w] = im[h - 1, w - 1]
        sizes[j] = (w, h)
    return out, sizes


@njit(cache=True, fastmath=True, _nrt=False)
def ncc_cost(flat: np.ndarray, base: int, stride: int, sw: int, sh: int, wgt: np.ndarray, wa: np.ndarray,
             mu_a: float, var_a: float, ox: np.ndarray, oy: np.ndarray, x: int, y: int,
             h00: float, h01: float, h02: float, h10: float, h11: float, h12: float,
             h20: float, h21: float, h22: float, min_var: float) -> float:
    """Photometric cost in [0, 2] of the homography H (row-major h00..h22, float32) at ref pixel (x, y).

    ``flat`` is the padded source stack raveled; the source starts at ``base`` with row ``stride``
    and size (sw, sh). ``wgt``/``wa`` are the (S,) rows of the reference pixel, ``ox``/``oy`` the (S,)
    float32 window offsets. Unsigned indices keep numba from adding wrap-around checks, which lets
    LLVM vectorise the sample loop with gathers.
    """
    fx = np.float32(x)
    fy = np.float32(y)
    cz = h20 * fx + h21 * fy + h22
    if cz <= 0.0:
        return 2.0
    cu = (h00 * fx + h01 * fy + h02) / cz
    cv = (h10 * fx + h11 * fy + h12) / cz
    wmax = np.float32(sw - 1)
    hmax = np.float32(sh - 1)
    if not (cu >= 0.0 and cv >= 0.0 and cu <= wmax and cv <= hmax):
        return 2.0
    sb = np.float32(0.0)
    sbb = np.float32(0.0)
    sab = np.float32(0.0)
    tiny = np.float32(1e-6)
    zero = np.float32(0.0)
    ubase = np.uint64(base)
    ustride = np.uint64(stride)
    u1 = np.uint64(1)
    for k in range(ox.shape[0]):
        qx = fx + ox[k]
        qy = fy + oy[k]
        hz = max(h20 * qx + h21 * qy + h22, tiny)
        u = min(max((h00 * qx + h01 * qy + h02) / hz, zero), wmax)
        v = min(max((h10 * qx + h11 * qy + h12) / hz, zero), hmax)
        iu = np.uint32(u)
        iv = np.uint32(v)
        fu = u - np.float32(iu)
        fv = v - np.float32(iv)
        idx = ubase + np.uint64(iv) * ustride + np.uint64(iu)
        p00 = flat[idx]
        p01 = flat[idx + u1]
        p10 = flat[idx + ustride]
        p11 = flat[idx + ustride + u1]
        top = p00 + fu * (p01 - p00)
        bot = p10 + fu * (p11 - p10)
        bval = top + fv * (bot - top)
        wb = wgt[k] * bval
        sb += wb
        sbb += wb * bval
        sab += wa[k] * bval
    var_b = sbb - sb * sb
    if var_a < min_var or var_b < min_var:
        return 2.0
    ncc = (sab - mu_a * sb) / math.sqrt(var_a * var_b)
    return min(max(1.0 - ncc, 0.0), 2.0)
