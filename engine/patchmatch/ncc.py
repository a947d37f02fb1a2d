"""Bilaterally weighted NCC (Schönberger et al. 2016 COLMAP; Xu & Tao 2019 ACMM).

The weights depend only on the reference image. The window mean μ_a and variance v_a and the choice of
window are computed once per reference view and level (:func:`window_terms`); the normalised weights w and the
products w·a of a pixel are computed again each time a kernel visits the pixel (:func:`load_window`, by the same
function, so they are the same values): storing them took 2·S floats a pixel (113 MB at 768x512) for about 2 %
of a pixel update's time. A cost evaluation then only samples the source image:
μ_b = Σ w b, v_b = Σ w b² - μ_b², cov = Σ (w a) b - μ_a μ_b, cost = clamp(1 - cov/√(v_a v_b), 0, 2),
and 2 when either variance is below ``min_var`` or the warped centre is behind or outside the source.

Source images are stored padded by one replicated row and column, (N, Hmax+1, Wmax+1), so that
bilinear sampling at a coordinate clamped to [0, W-1] never reads out of bounds (border mode).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numba import njit, prange

from engine.core.blocks import RowPacer

WEIGHTING_CODES = {"colmap": 0, "acmm": 1}
PACER = RowPacer()  # the row blocks of this process's window-term builds (only their time depends on it)
# where a pixel may use the fine window (context.fine_window_region): not at all; where its texture test
# passes (occlusion band); where also its own variance keeps min_ratio_fine of the standard window's (crease band)
FINE_OFF, FINE_EDGE, FINE_CREASE = 0, 1, 2


def window_offsets_2d(offsets_1d: list[int]) -> np.ndarray:
    """(S, 2) int32 (dx, dy) offsets of the window, row-major over dy then dx."""
    return np.array([(dx, dy) for dy in offsets_1d for dx in offsets_1d], dtype=np.int32)


@njit(cache=True, fastmath=True, _nrt=False)
def _pixel_moments(img, x, y, offs, n_off, mode, sigma_s, sigma_c, wrow, warow):
    """Bilateral weights of the first ``n_off`` offsets at (x, y), normalised, into ``wrow``, w·a into
    ``warow``; returns the weighted mean and variance. Window pixels outside the image are clamped."""
    h, w = img.shape
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
        wrow[k] = ww
        s += ww
    inv = 1.0 / s
    m = 0.0
    m2 = 0.0
    for k in range(n_off):
        xx = min(max(x + offs[k, 0], 0), w - 1)
        yy = min(max(y + offs[k, 1], 0), h - 1)
        a = img[yy, xx]
        ww = wrow[k] * inv
        wrow[k] = ww
        warow[k] = ww * a
        m += ww * a
        m2 += ww * a * a
    return m, max(m2 - m * m, 0.0)


@njit(cache=True, parallel=True, fastmath=True)
def _window_terms_kernel(img, offs, offs_f, mode, sigma_s, sigma_c, sigma_s_f, sigma_c_f, min_var_f, min_ratio_f,
                         allowed, mu_a, var_a, wset, y_start, y_stop, x_start, x_stop):
    """Per pixel: the fine window where ``allowed`` (code > FINE_OFF) and its variance test (fine offsets,
    sigma_s_f, the standard sigma_c) reaches ``min_var_f`` and, at FINE_CREASE with ``min_ratio_f`` > 0, its
    variance under its own weights reaches ``min_ratio_f`` times the standard window's; else the standard
    window. Writes the chosen window's weighted mean and variance and the choice (1 = fine) of the pixels
    [x_start, x_stop) x [y_start, y_stop) (every pixel is independent of the others)."""
    h, w = img.shape
    n_std = offs.shape[0]
    n_fine = offs_f.shape[0]
    s_max = max(n_std, n_fine)
    for y in prange(max(y_start, 0), min(y_stop, h)):
        wrow = np.empty(s_max, np.float32)  # the weights and w·a: scratch here, recomputed by load_window
        warow = np.empty(s_max, np.float32)
        for x in range(max(x_start, 0), min(x_stop, w)):
            fine = False
            done = False  # the chosen window's moments are already in m, v
            m = v = 0.0
            if n_fine > 0 and allowed[y, x] != FINE_OFF:
                v_test = _pixel_moments(img, x, y, offs_f, n_fine, mode, sigma_s_f, sigma_c, wrow, warow)[1]
                fine = np.float32(v_test) >= min_var_f
                if fine and allowed[y, x] == FINE_CREASE and min_ratio_f > 0:
                    v_std = _pixel_moments(img, x, y, offs, n_std, mode, sigma_s, sigma_c, wrow, warow)[1]
                    m, v = _pixel_moments(img, x, y, offs_f, n_fine, mode, sigma_s_f, sigma_c_f, wrow, warow)
                    fine = np.float32(v) >= min_ratio_f * np.float32(v_std)
                    done = fine
            if fine:
                if not done:
                    m, v = _pixel_moments(img, x, y, offs_f, n_fine, mode, sigma_s_f, sigma_c_f, wrow, warow)
            else:
                m, v = _pixel_moments(img, x, y, offs, n_std, mode, sigma_s, sigma_c, wrow, warow)
            mu_a[y, x] = m
            var_a[y, x] = v
            wset[y, x] = 1 if fine else 0


@njit(cache=True, parallel=True, fastmath=True)
def _weights_kernel(img, offs, n_samples, mode, sigmas, wset, wgt, wa):
    """Every pixel's weights and w·a as :func:`load_window` computes them, into (H, W, S) arrays (zero past the
    pixel's window)."""
    h, w = img.shape
    for y in prange(h):
        for x in range(w):
            s = wset[y, x]
            n = n_samples[s]
            _pixel_moments(img, x, y, offs[s], n, mode, sigmas[s, 0], sigmas[s, 1], wgt[y, x], wa[y, x])
            for k in range(n, wgt.shape[2]):
                wgt[y, x, k] = 0.0
                wa[y, x, k] = 0.0


def bilateral_moments(img: np.ndarray, offs: np.ndarray, weighting: str, sigma_s: float,
                      sigma_c: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Reference-side NCC terms of one image with one window, as whole maps (for tests and inspection; the
    kernels compute a pixel's weights when they visit it).

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
    mu_a, var_a, wset = window_terms(img, offs, np.zeros((0, 2), np.int32), weighting, sigma_s, sigma_c,
                                     sigma_s, sigma_c, 0.0, None)
    wgt, wa = window_weight_maps(img, np.ascontiguousarray(offs, np.int32)[None], np.array([offs.shape[0]]),
                                 np.array([[sigma_s, sigma_c]], np.float64), WEIGHTING_CODES[weighting], wset)
    return wgt, wa, mu_a, var_a


def window_weight_maps(img: np.ndarray, offsets: np.ndarray, n_samples: np.ndarray, sigmas: np.ndarray,
                       weighting: int, wset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every pixel's bilateral weights w and w·a as :func:`load_window` computes them, as (H, W, S) f32 maps
    (zeros past the pixel's window): for tests and inspection, the kernels never hold them. ``offsets``
    (n_sets, S, 2) i32, ``n_samples`` (n_sets,), ``sigmas`` (n_sets, 2) f64, ``weighting`` a WEIGHTING_CODES code,
    ``wset`` (H, W) u8 each pixel's window set."""
    h, w = img.shape
    wgt = np.empty((h, w, offsets.shape[1]), np.float32)
    wa = np.empty_like(wgt)
    _weights_kernel(np.ascontiguousarray(img, np.float32), offsets, np.asarray(n_samples, np.int64), int(weighting),
                    sigmas, wset, wgt, wa)
    return wgt, wa


def window_terms(img: np.ndarray, offs: np.ndarray, offs_fine: np.ndarray, weighting: str, sigma_s: float,
                 sigma_c: float, sigma_s_fine: float, sigma_c_fine: float, min_var_fine: float,
                 allowed: np.ndarray | None, alloc: Callable[..., np.ndarray] = np.empty, min_ratio_fine: float = 0.0,
                 pacer: RowPacer | None = PACER, box: tuple[int, int, int, int] | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Reference-side NCC terms with a per-pixel choice between two windows (see
    ``context.reference_terms``): mu_a, var_a (H, W) f32 the chosen window's weighted mean and variance and
    wset (H, W) u8 (1 = fine). ``offs_fine`` (0, 2) disables the fine window; ``allowed`` (H, W) bool, uint8
    codes (FINE_OFF, FINE_EDGE, FINE_CREASE: subject to ``min_ratio_fine`` too, its variance under its own weights
    must reach that fraction of the standard window's) or None (everywhere, FINE_EDGE). ``alloc(shape, dtype)``
    gives the output arrays (``np.empty`` or a ``buffers.BufferPool``'s take); ``pacer``: the row blocks
    (``engine.core.blocks``; None: one call); ``box`` (x0, y0, x1, y1): only the terms of the pixels
    [x0, x1) x [y0, y1) (the others 0), for kernels that update only those pixels (the probe's partial replay:
    a pixel's NCC reads its own reference terms alone)."""
    img = np.ascontiguousarray(img, dtype=np.float32)
    h, w = img.shape
    mu_a = alloc((h, w), np.float32)
    var_a = alloc((h, w), np.float32)
    wset = np.empty((h, w), np.uint8)
    if allowed is None:
        allowed = np.full((h, w), FINE_EDGE, np.uint8)
    args = (img, offs, np.ascontiguousarray(offs_fine, dtype=np.int32), WEIGHTING_CODES[weighting], float(sigma_s),
            float(sigma_c), float(sigma_s_fine), float(sigma_c_fine), np.float32(min_var_fine),
            np.float32(min_ratio_fine), np.ascontiguousarray(allowed, dtype=np.uint8), mu_a, var_a, wset)
    x0, y0, x1, y1 = (0, 0, w, h) if box is None else (max(0, int(box[0])), max(0, int(box[1])),
                                                        min(w, int(box[2])), min(h, int(box[3])))
    if box is not None:
        for a in (mu_a, var_a, wset):
            a[:] = 0
    if pacer is None:
        _window_terms_kernel(*args, y0, y1, x0, x1)
    else:  # blocks of rows, a stop request honoured between them (one call took seconds at 768x512, loaded)
        pacer.run("window_terms", y1 - y0, x1 - x0,
                  lambda start, stop: _window_terms_kernel(*args, y0 + start, y0 + stop, x0, x1))
    return mu_a, var_a, wset


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


# rows of ncc_cost's working array: the pixel's window (4) and per-sample scratch (3)
WORK_ROWS = 7
# ncc_cost's vectorised loops run over whole vectors of this many float32 lanes (AVX2)
LANES = 8


@njit(cache=True, inline="always")
def work_width(n_samples):
    """Columns of the working arrays for windows of up to ``n_samples`` samples: rounded up to whole
    vectors (:data:`LANES`)."""
    return (n_samples + LANES - 1) // LANES * LANES


@njit(cache=True)
def ncc_work(n_samples):
    """Working arrays of :func:`ncc_cost` for windows of up to ``n_samples`` samples: ``win``
    (WORK_ROWS, work_width(n)) float32 (rows 0-3 the reference pixel's window, see :func:`load_window`;
    rows 4-6 scratch) and ``sidx`` (work_width(n),) int32 scratch. One pair per thread (the kernels
    allocate one per image row)."""
    width = work_width(n_samples)
    return np.zeros((WORK_ROWS, width), np.float32), np.zeros(width, np.int32)


@njit(cache=True, inline="always")
def load_window(win, img, offs, sigmas, mode, ox, oy, wset, ns, x, y):
    """Put reference pixel (x, y)'s window into rows 0-3 of ``win``: its bilateral weights w and weighted
    intensities w·a, computed here from the reference image ``img`` (H, W) f32 by the function that computed its
    moments (:func:`window_terms`), and the offsets of its window set; zeros up to ``work_width(n)`` in rows 0-3
    and 6. Window set s (``wset`` (H, W) u8) has ``ns[s]`` samples at ``offs[s]`` (n_sets, S, 2) i32 (as floats in
    ``ox``, ``oy`` (n_sets, S) f32), spatial and colour sigmas ``sigmas[s]`` (n_sets, 2) f64 and the weighting
    ``mode`` (WEIGHTING_CODES). Returns the number of samples n.

    One copy per pixel, so that the cost functions take one array instead of four views (numba passes
    each array as 7-11 machine words and counts references to views: per NCC window that was 10-20 %
    of the time)."""
    s = wset[y, x]
    n = ns[s]
    _pixel_moments(img, x, y, offs[s], n, mode, sigmas[s, 0], sigmas[s, 1], win[0], win[1])
    for k in range(n):
        win[2, k] = ox[s, k]
        win[3, k] = oy[s, k]
    # zero weights, offsets and blended values up to the next whole vector: ncc_cost's vector loops run
    # over them (its texel loop writes row 6 only below n)
    for k in range(n, work_width(n)):
        win[0, k] = 0.0
        win[1, k] = 0.0
        win[2, k] = 0.0
        win[3, k] = 0.0
        win[6, k] = 0.0
    return n


@njit(cache=True, fastmath=True, _nrt=False)
def ncc_cost(flat: np.ndarray, base: int, stride: int, sw: int, sh: int, win: np.ndarray, n: int,
             mu_a: float, var_a: float, x: int, y: int,
             h00: float, h01: float, h02: float, h10: float, h11: float, h12: float,
             h20: float, h21: float, h22: float, min_var: float, sidx: np.ndarray) -> float:
    """Photometric cost in [0, 2] (a float32 value) of the homography H (row-major h00..h22, float32) at
    ref pixel (x, y).

    ``flat`` is the padded source stack raveled; the source starts at ``base`` with row ``stride``
    and size (sw, sh). ``win`` (WORK_ROWS, >= work_width(n)) float32 holds the reference pixel's window of
    ``n`` samples in rows 0-3 (weights, weighted centred intensities, x and y offsets, zero up to work_width(n)
    as row 6: :func:`load_window`) and is scratch in rows 4-6; ``sidx`` (>= work_width(n),) int32 is
    scratch.

    Three loops instead of one: LLVM does not vectorise a loop with gathers on this CPU (its cost
    model rejects them), so the projection (two divisions per sample) and the weighted sums get loops of
    their own that it vectorises 8 wide (2.1x the samples per second of the single loop,
    benchmarks/performance/bench_patchmatch.py). The scalar loop in between loads the four texels and blends them:
    it is bound by loads and stores, so it stores one blended value per sample instead of four texels,
    and the vector loops run over whole vectors instead of ending in a scalar remainder (with the inlined
    aggregated_cost, 1.05-1.21x per half-step: benchmarks/results/bench_patchmatch_ab_blend.json).
    """
    fx = np.float32(x)
    fy = np.float32(y)
    cz = h20 * fx + h21 * fy + h22
    if cz <= 0.0:
        return 2.0
    bu = h00 * fx + h01 * fy + h02
    bv = h10 * fx + h11 * fy + h12
    cu = bu / cz
    cv = bv / cz
    wmax = np.float32(sw - 1)
    hmax = np.float32(sh - 1)
    if not (cu >= 0.0 and cv >= 0.0 and cu <= wmax and cv <= hmax):
        return 2.0
    tiny = np.float32(1e-6)
    zero = np.float32(0.0)
    istride = np.int32(stride)
    # whole vectors: the zero-weight samples past n (load_window) cost less than a scalar remainder loop
    # with two divisions per sample, and add exact zeros to the sums
    n_vec = work_width(n)
    # 1. projection, clamped to the image (border mode): texel index within the source and fractions
    for k in range(n_vec):
        dx = win[2, k]
        dy = win[3, k]
        hz = max(cz + h20 * dx + h21 * dy, tiny)
        u = min(max((bu + h00 * dx + h01 * dy) / hz, zero), wmax)
        v = min(max((bv + h10 * dx + h11 * dy) / hz, zero), hmax)
        iu = np.int32(u)
        iv = np.int32(v)
        win[4, k] = u - np.float32(iu)
        win[5, k] = v - np.float32(iv)
        sidx[k] = iv * istride + iu
    # 2. the four texels and their bilinear blend (the padded border keeps idx + stride + 1 inside the
    # source); blending here stores one value per sample instead of four for the next loop
    ubase = np.uint64(base)
    ustride = np.uint64(stride)
    u1 = np.uint64(1)
    for k in range(n):
        idx = ubase + np.uint64(sidx[k])
        p00 = flat[idx]
        p01 = flat[idx + u1]
        p10 = flat[idx + ustride]
        p11 = flat[idx + ustride + u1]
        fu = win[4, k]
        top = p00 + fu * (p01 - p00)
        bot = p10 + fu * (p11 - p10)
        win[6, k] = top + win[5, k] * (bot - top)
    # 3. weighted moments
    sb = np.float32(0.0)
    sbb = np.float32(0.0)
    sab = np.float32(0.0)
    for k in range(n_vec):
        bval = win[6, k]
        wb = win[0, k] * bval
        sb += wb
        sbb += wb * bval
        sab += win[1, k] * bval
    var_b = sbb - sb * sb
    if var_a < min_var or var_b < min_var:
        return 2.0
    ncc = np.float32((sab - mu_a * sb) / math.sqrt(var_a * var_b))
    # a float32 value, so that caches may store costs as float32 without changing them
    return min(max(np.float32(1.0) - ncc, zero), np.float32(2.0))
