"""Depth-map filters applied before fusion (Kuhn et al. 2020, §4.1).

- Confidence filtering (DeepC-MVS_fast): keep pixel p iff c(p) >= tau.
- Mask-k filtering (COLMAP/ACMM-style baselines "mask1", "mask2"): keep p iff K(p) >= k, with K the
  counter map of consistent source views (Kuhn et al. 2020, §3.2).

Rejected pixels get depth 0 and normal (0, 0, 0). The functions are pure: they return new arrays
and never modify their inputs.
"""

from __future__ import annotations

import numpy as np

from engine.core.options import check


def _apply(depth: np.ndarray, normal: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    depth = np.asarray(depth, np.float32)
    normal = np.asarray(normal, np.float32)
    if depth.ndim != 2 or normal.shape != depth.shape + (3,):
        raise ValueError(f"depth must be (H, W) and normal (H, W, 3); got {depth.shape} and {normal.shape}")
    if keep.shape != depth.shape:
        raise ValueError(f"filter map has shape {keep.shape}, depth has {depth.shape}")
    out_depth = np.where(keep, depth, np.float32(0.0)).astype(np.float32)
    out_normal = np.where(keep[..., None], normal, np.float32(0.0)).astype(np.float32)
    return out_depth, out_normal


def filter_by_confidence(depth: np.ndarray, normal: np.ndarray, confidence: np.ndarray,
                         tau: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero every pixel whose confidence is below ``tau`` (keep c >= tau).

    Args:
        depth: (H, W) float32 depth, 0 = none.
        normal: (H, W, 3) float32 camera-frame normals.
        confidence: (H, W) confidence in [0, 1]; NaN counts as rejected.
        tau: threshold in [0, 1].
    Returns:
        New (depth, normal) arrays.
    """
    check(0 <= tau <= 1, "tau", tau, "must be in [0, 1]")
    confidence = np.asarray(confidence)
    with np.errstate(invalid="ignore"):
        keep = confidence >= tau
    return _apply(depth, normal, keep)


def filter_by_counter(depth: np.ndarray, normal: np.ndarray, counter: np.ndarray,
                      k: int) -> tuple[np.ndarray, np.ndarray]:
    """Zero every pixel with fewer than ``k`` consistent source views (keep K >= k).

    Args:
        depth: (H, W) float32 depth, 0 = none.
        normal: (H, W, 3) float32 camera-frame normals.
        counter: (H, W) number of consistent views (any numeric dtype; stored as float32 on disk).
        k: minimum count, >= 0.
    Returns:
        New (depth, normal) arrays.
    """
    check(k >= 0, "mask_k", k, "must be at least 0")
    # Counter maps read back from .bin files are float32 holding integers; compare with a margin.
    keep = np.asarray(counter, np.float64) >= k - 1e-3
    return _apply(depth, normal, keep)
