"""Which estimate ``--pipeline full`` fuses per pixel: PatchMatch's where network 1 trusts it, refined elsewhere.

The refinement (Rossi et al., CVPR 2020, as used by Kuhn et al., 3DV 2020) regularises every pixel. On real
photographs it also moves confident PatchMatch estimates: thin foreground structures are pulled onto the
background behind them, and the two views of a stereo pair no longer agree to a pixel, so fusion loses them
(docs/decisions.md). Keeping the confident estimates and taking the refined ones only where network 1 doubts
the PatchMatch estimate keeps what refinement is for (filling what PatchMatch got wrong).
"""

from __future__ import annotations

import numpy as np


def keep_confident(depth: np.ndarray, normal: np.ndarray, confidence: np.ndarray, refined_depth: np.ndarray,
                   refined_normal: np.ndarray, refined_confidence: np.ndarray,
                   threshold: float | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(depth, normal, confidence) of one view as ``full`` fuses them.

    Args:
        depth, normal: (H, W) PatchMatch depth (0 = none) and (H, W, 3) normals.
        confidence: (H, W) network-1 confidence of the PatchMatch estimates.
        refined_depth, refined_normal: the refined maps, same shapes.
        refined_confidence: (H, W) network-2 confidence of the refined maps.
        threshold: PatchMatch estimates with confidence at least this are kept; None refines every pixel (the
            paper).
    Returns:
        The PatchMatch depth, normal and confidence where kept, the refined ones elsewhere.
    """
    if threshold is None:
        return refined_depth, refined_normal, refined_confidence
    keep = kept_estimates(depth, confidence, threshold)
    return (np.where(keep, depth, refined_depth).astype(np.float32),
            np.where(keep[..., None], normal, refined_normal).astype(np.float32),
            np.where(keep, confidence, refined_confidence).astype(np.float32))


def kept_estimates(depth: np.ndarray, confidence: np.ndarray, threshold: float | None) -> np.ndarray:
    """(H, W) bool: the PatchMatch estimates that :func:`keep_confident` keeps."""
    if threshold is None:
        return np.zeros(depth.shape, bool)
    return (confidence >= threshold) & (depth > 0)
