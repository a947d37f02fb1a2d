"""Depth-map metrics against ground truth (SPEC.md §9.3, CONTRACT.md §5 ``depth``)."""

from __future__ import annotations

import numpy as np


def depth_metrics(depth: np.ndarray, gt_depth: np.ndarray) -> dict[str, float]:
    """Compare an estimated depth map with GT depth (both (H, W), 0 = none).

    Returns percentages 0-100 except ``abs_rel`` (mean |z - z*| / z*, a fraction):
        abs_rel, within_1pct, within_5pct: over pixels that have both an estimate and GT;
        valid_fraction: fraction of GT pixels that have an estimate;
        num_gt, num_both: pixel counts.
    Empty sets give NaN for the ratios over them.
    """
    depth = np.asarray(depth, np.float64)
    gt = np.asarray(gt_depth, np.float64)
    if depth.shape != gt.shape:
        raise ValueError(f"depth {depth.shape} and GT {gt.shape} differ in shape")
    has_gt = np.isfinite(gt) & (gt > 0)
    both = has_gt & np.isfinite(depth) & (depth > 0)
    n_gt = int(has_gt.sum())
    n_both = int(both.sum())
    out = {"num_gt": n_gt, "num_both": n_both,
           "valid_fraction": 100.0 * n_both / n_gt if n_gt else float("nan")}
    if n_both:
        rel = np.abs(depth[both] - gt[both]) / gt[both]
        out.update(abs_rel=float(rel.mean()), within_1pct=100.0 * float((rel < 0.01).mean()),
                   within_5pct=100.0 * float((rel < 0.05).mean()))
    else:
        out.update(abs_rel=float("nan"), within_1pct=float("nan"), within_5pct=float("nan"))
    return out
