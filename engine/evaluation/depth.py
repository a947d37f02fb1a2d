"""Depth-map metrics against ground truth: the ``depth`` block of metrics.json."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from engine.evaluation.pooled import pairwise_sum


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


#: the pooled ``depth`` block of metrics.json
DEPTH_KEYS = ("abs_rel", "within_1pct", "within_5pct", "valid_fraction")


def relative_errors(depth: np.ndarray, gt_depth: np.ndarray) -> tuple[int, np.ndarray]:
    """(pixels with GT, |z - z*| / z* in float64 where both exist), exactly as :func:`depth_metrics` forms them."""
    has_gt, rel = relative_error_map(depth, gt_depth)
    return int(has_gt.sum()), rel[~np.isnan(rel)]


def relative_error_map(depth: np.ndarray, gt_depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel, as :func:`relative_errors` forms them: ((H, W) bool "has GT", (H, W) float64 |z - z*| / z*,
    NaN where the estimate or the GT is missing). A pixel is within 1 % when its value is below 0.01."""
    depth = np.asarray(depth, np.float64)
    gt = np.asarray(gt_depth, np.float64)
    if depth.shape != gt.shape:
        raise ValueError(f"depth {depth.shape} and GT {gt.shape} differ in shape")
    has_gt = np.isfinite(gt) & (gt > 0)
    both = has_gt & np.isfinite(depth) & (depth > 0)
    rel = np.full(depth.shape, np.nan)
    rel[both] = np.abs(depth[both] - gt[both]) / gt[both]
    return has_gt, rel


def pooled_depth_metrics(names: Sequence[str], depth_of: Callable[[int], np.ndarray],
                         gt_of: Callable[[int], np.ndarray]) -> tuple[dict[str, float], list[dict[str, Any]]]:
    """:func:`depth_metrics` pooled over every pixel of the views ``names`` (the ``DEPTH_KEYS``), and per view
    (``{"view": name, **depth_metrics}``), without holding every view's pixels at once.

    ``depth_of(i)`` and ``gt_of(i)`` give view ``i``'s (H, W) depth and GT depth (0 = none); each is called twice
    per view: once for the counts, once for the sum of the errors. The pooled numbers equal ``depth_metrics`` of the
    concatenated maps to the last bit: counts are exact, and the errors are summed as numpy sums the concatenation
    (:func:`engine.evaluation.pooled.pairwise_sum`).
    """
    per_view, n_gt, n_both, within1, within5 = [], 0, 0, 0, 0
    for i, name in enumerate(names):
        depth, gt = depth_of(i), gt_of(i)
        per_view.append({"view": name, **depth_metrics(depth, gt)})
        has_gt, rel = relative_errors(depth, gt)
        n_gt, n_both = n_gt + has_gt, n_both + rel.size
        within1, within5 = within1 + int((rel < 0.01).sum()), within5 + int((rel < 0.05).sum())
    pooled = {"valid_fraction": 100.0 * n_both / n_gt if n_gt else float("nan")}
    if n_both:
        total = pairwise_sum((relative_errors(depth_of(i), gt_of(i))[1] for i in range(len(names))), n_both)
        pooled.update(abs_rel=float(total / n_both), within_1pct=100.0 * float(within1 / n_both),
                      within_5pct=100.0 * float(within5 / n_both))
    else:
        pooled.update(abs_rel=float("nan"), within_1pct=float("nan"), within_5pct=float("nan"))
    return {k: pooled[k] for k in DEPTH_KEYS}, per_view
