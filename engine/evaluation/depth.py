"""Depth-map metrics against ground truth: the ``depth`` block of metrics.json."""

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


def roc_curve(scores: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """ROC curve of ``scores`` (e.g. confidence) separating inliers (label 1) from outliers (label 0).

    Other labels (e.g. -1 = unlabelled) and non-finite scores are ignored. Returns (fpr, tpr, auc):
    false/true positive rates at every distinct threshold, from (0, 0) to (1, 1), and the area under the
    curve, which equals P(s+ > s-) + ½ P(s+ = s-) (tied scores form one diagonal segment). Rates and
    area are fractions; the area is NaN when a class is empty.
    """
    scores = np.asarray(scores, np.float64).ravel()
    labels = np.asarray(labels).ravel()
    keep = ((labels == 0) | (labels == 1)) & np.isfinite(scores)
    scores, positive = scores[keep], labels[keep] == 1
    n_pos, n_neg = int(positive.sum()), int((~positive).sum())
    if n_pos == 0 or n_neg == 0:
        return np.array([0.0, 1.0]), np.array([0.0, 1.0]), float("nan")
    order = np.argsort(-scores, kind="stable")
    scores, positive = scores[order], positive[order]
    group_ends = np.append(np.flatnonzero(np.diff(scores)), scores.size - 1)  # last index of each tie group
    tpr = np.concatenate([[0.0], np.cumsum(positive)[group_ends] / n_pos])
    fpr = np.concatenate([[0.0], np.cumsum(~positive)[group_ends] / n_neg])
    return fpr, tpr, float(np.trapezoid(tpr, fpr))
