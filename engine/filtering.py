"""Depth-map filters applied before fusion (Kuhn et al. 2020, §4.1).

- Confidence filtering (DeepC-MVS_fast): keep pixel p iff c(p) >= tau.
- Mask-k filtering (COLMAP/ACMM-style baselines "mask1", "mask2"): keep p iff K(p) >= k, with K the
  counter map of consistent source views (Kuhn et al. 2020, §3.2).

Rejected pixels get depth 0 and normal (0, 0, 0). The functions are pure: they return new arrays
and never modify their inputs.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from engine.confidence.options import ConfidenceOptions
from engine.core.options import Options, option


@dataclasses.dataclass
class FilterOptions(Options):
    """Which pixels survive into fusion."""

    tau: float = option(ConfidenceOptions().tau, "keep pixels whose confidence is at least this (0 keeps all; "
                        "default: confidence.tau)", source="ours", low=0, high=1, aliases=("conf_tau",),
                        metavar="TAU")
    mask_k: int | None = option(None, "keep pixels with at least this many consistent source views; unset = no "
                                "counter filter", source="paper", low=0, metavar="K")


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
    FilterOptions(tau=tau).validate()  # the declared range
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
    FilterOptions(mask_k=k).validate()
    # Counter maps read back from .bin files are float32 holding integers; compare with a margin.
    keep = np.asarray(counter, np.float64) >= k - 1e-3
    return _apply(depth, normal, keep)


def apply_filters(depth: np.ndarray, normal: np.ndarray, options: FilterOptions,
                  confidence: np.ndarray | None = None,
                  counter: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Apply the filters ``options`` asks for that have their input map; returns new (depth, normal)."""
    options.validate()
    if confidence is not None and options.tau > 0:
        depth, normal = filter_by_confidence(depth, normal, confidence, options.tau)
    if counter is not None and options.mask_k is not None:
        depth, normal = filter_by_counter(depth, normal, counter, options.mask_k)
    return np.asarray(depth, np.float32).copy(), np.asarray(normal, np.float32).copy()
