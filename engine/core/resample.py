"""Resampling of depth maps between resolutions of the same image (pixel-area aligned).

Depth must never be averaged across a depth edge (that invents surfaces between foreground and
background), so downsampling by an integer factor takes the lower median of the valid depths of
each block, and any other factor samples the nearest source pixel centre.
"""

from __future__ import annotations

import numpy as np


def resample_depth(depth: np.ndarray, size: tuple[int, int], min_valid_fraction: float = 0.5) -> np.ndarray:
    """Resample (H, W) depth (0 = none) to ``size`` = (width, height).

    Integer downsampling factors: each output pixel is the lower median of the valid depths in its
    f_x × f_y block, or 0 when fewer than ``min_valid_fraction`` of the block is valid. Otherwise the
    depth at the nearest source pixel centre. Returns float32.
    """
    depth = np.asarray(depth, np.float32)
    src_h, src_w = depth.shape
    width, height = size
    if (width, height) == (src_w, src_h):
        return depth.copy()
    fx, fy = src_w / width, src_h / height
    if fx >= 1 and fy >= 1 and fx == int(fx) and fy == int(fy):
        fx, fy = int(fx), int(fy)
        blocks = depth.reshape(height, fy, width, fx).transpose(0, 2, 1, 3).reshape(height, width, fx * fy)
        valid = blocks > 0
        count = valid.sum(axis=2)
        ordered = np.sort(np.where(valid, blocks, np.inf), axis=2)
        pick = np.maximum(count - 1, 0) // 2
        out = np.take_along_axis(ordered, pick[:, :, None], axis=2)[:, :, 0]
        out[count < min_valid_fraction * fx * fy] = 0.0
        out[count == 0] = 0.0
        return out.astype(np.float32)
    cols = np.minimum(((np.arange(width) + 0.5) * fx).astype(np.int64), src_w - 1)
    rows = np.minimum(((np.arange(height) + 0.5) * fy).astype(np.int64), src_h - 1)
    return depth[rows[:, None], cols[None, :]].astype(np.float32)
