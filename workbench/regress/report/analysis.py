"""What the regression report shows of a run folder besides its metrics: ROC curves, depth errors, thumbnails.

ROC curves need inlier labels. Which pixels count as inliers is a :data:`LabelFunction`: by default the
GT label maps of Kuhn et al. 2020, §3.2 (``engine/confidence/labels.py``); :func:`relative_depth_labels` (depth
within 1 % of GT) is the simpler alternative. Runs are read from their folders (``engine/run/folder.py``,
``engine/run/fused_maps.py``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import numpy as np

from engine.confidence.labels import label_map
from engine.evaluation.depth import roc_curve
from engine.run.folder import run_scene
from engine.run.fused_maps import read_run_views
from engine.scene import Scene
from workbench.maps.images import colorize, view_images
from workbench.regress.report.figures import png_data_uri

# (scene, view index, depth (H, W)) -> (H, W) int8 labels: 1 inlier, 0 outlier, -1 unlabelled
LabelFunction = Callable[[Scene, int, np.ndarray], np.ndarray]
ERROR_MAP_MAX = 5.0  # percent: the error maps' colour scale


def relative_depth_labels(scene: Scene, index: int, depth: np.ndarray, threshold: float = 0.01) -> np.ndarray:
    """Inlier when |z - z*| / z* < ``threshold``; unlabelled without an estimate or without GT."""
    gt = scene.gt_depth(index)
    labels = np.full(depth.shape, -1, np.int8)
    if gt is None:
        return labels
    with np.errstate(invalid="ignore", divide="ignore"):
        both = (depth > 0) & np.isfinite(depth) & (gt > 0) & np.isfinite(gt)
        labels[both] = (np.abs(depth[both] - gt[both]) / gt[both] < threshold).astype(np.int8)
    return labels


def default_label_function() -> tuple[str, LabelFunction]:
    """(description, function) of the DeepC labels (Kuhn et al. 2020, §3.2): reprojection error against GT depth."""

    def reprojection_labels(scene: Scene, index: int, depth: np.ndarray) -> np.ndarray:
        view = scene.views[index]
        gt = scene.gt_depth(index)
        if gt is None:
            return np.full(depth.shape, -1, np.int8)
        return label_map(depth, gt, view.camera, [scene.views[j].camera for j in view.source_views],
                         max_depth=view.depth_range[1])
    return "inlier: reprojection error < 2 px in a source view (Kuhn et al. 2020)", reprojection_labels


@dataclasses.dataclass
class RunAnalysis:
    """What the report shows of one run folder besides its metrics.

    roc: score name -> (fpr, tpr, auc), fractions. errors: depth kind -> relative errors of all pixels
    with estimate and GT. thumbnails: (view name, {map kind: PNG data URI}) for the shown views.
    """

    label_name: str
    roc: dict[str, tuple[np.ndarray, np.ndarray, float]]
    errors: dict[str, np.ndarray]
    thumbnails: list[tuple[str, dict[str, str]]]


def _relative_error(depth: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """(H, W) |z - z*| / z*, NaN where either is missing."""
    with np.errstate(invalid="ignore", divide="ignore"):
        both = (depth > 0) & np.isfinite(depth) & (gt > 0) & np.isfinite(gt)
        return np.where(both, np.abs(depth - gt) / np.where(both, gt, 1.0), np.nan)


def shown_views(count: int, wanted: int) -> list[int]:
    """Up to ``wanted`` view indices spread evenly over ``count`` views."""
    if wanted <= 0 or count == 0:
        return []
    return sorted(set(np.linspace(0, count - 1, min(wanted, count)).round().astype(int).tolist()))


def analyse_run(run_dir: str | Path, max_views: int = 4, labels: tuple[str, LabelFunction] | None = None
                ) -> RunAnalysis:
    """ROC curves, depth-error samples and map thumbnails of a ``deepc run`` output folder."""
    scene = run_scene(run_dir)
    data = read_run_views(run_dir, scene)
    label_name, label_fn = labels or default_label_function()
    scores: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    errors: dict[str, list[np.ndarray]] = {}
    shown = set(shown_views(len(scene.views), max_views))
    thumbnails = []
    for i, view in enumerate(scene.views):
        d = data[i]
        gt = scene.gt_depth(i)
        final = d.refined_depth if d.refined_depth is not None else d.depth
        if gt is not None:
            pm_labels = label_fn(scene, i, d.depth)
            if d.counter is not None:
                scores.setdefault("counter (PatchMatch depth)", []).append((d.counter, pm_labels))
            if d.confidence is not None:
                final_labels = pm_labels if final is d.depth else label_fn(scene, i, final)
                scores.setdefault("confidence", []).append((d.confidence, final_labels))
            errors.setdefault("PatchMatch", []).append(_relative_error(d.depth, gt))
            if d.refined_depth is not None:
                errors.setdefault("refined", []).append(_relative_error(d.refined_depth, gt))
        if i in shown:
            images = view_images(scene, i, d)
            if d.refined_depth is not None:
                lo, hi = view.depth_range
                images["refined depth"] = colorize(d.refined_depth, lo, hi, "turbo", d.refined_depth <= 0)
            if gt is not None:
                error = _relative_error(final, gt) * 100
                rgb = colorize(error, 0.0, ERROR_MAP_MAX, "inferno")
                rgb[~np.isfinite(error)] = 128  # grey: no estimate or no GT (black is zero error)
                images["error"] = rgb
            thumbnails.append((view.name, {kind: png_data_uri(rgb, kind == "image") for kind, rgb in images.items()}))
    roc = {}
    for name, pairs in scores.items():
        roc[name] = roc_curve(np.concatenate([s.ravel() for s, _ in pairs]),
                              np.concatenate([y.ravel() for _, y in pairs]))
    pooled = {kind: np.concatenate([e.ravel() for e in maps]) for kind, maps in errors.items()}
    return RunAnalysis(label_name, roc, {k: v[np.isfinite(v)] for k, v in pooled.items()}, thumbnails)
