"""The metrics.json blocks scored from a run's per-view maps: depth against GT depth and the confidence's ROC-AUC,
pooled over views one view at a time.

The in-process pipeline (maps in memory) and a streamed ``--executor dask`` run (maps read back from the run folder)
both score through here, so their numbers are one computation: the pooled values equal those of the concatenated
views to the last bit (``engine.evaluation.pooled``) without holding them.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from engine.evaluation.depth import pooled_depth_metrics
from engine.evaluation.pooled import PooledRankSum
from engine.run.per_view import view_auc
from engine.scene import Scene

#: view index -> its (H, W) map
MapOf = Callable[[int], np.ndarray]


def views_with_gt_depth(scene: Scene) -> list[Any]:
    """The views of ``scene`` that have a GT depth map."""
    return [v for v in scene.views if scene.gt_depth_paths[v.index] is not None]


def depth_block(scene: Scene, depth_of: MapOf) -> tuple[dict[str, float], list[dict[str, Any]]]:
    """metrics.json's ``depth`` (pooled over every GT pixel of every view) and ``depth_per_view`` entries of the depth
    maps ``depth_of(view index)`` (the function is called twice per view with GT depth)."""
    views = views_with_gt_depth(scene)
    return pooled_depth_metrics([v.name for v in views], lambda i: depth_of(views[i].index),
                                lambda i: scene.gt_depth(views[i].index))


def confidence_auc(scene: Scene, depth_of: MapOf, confidence_of: MapOf) -> dict[str, Any]:
    """ROC-AUC ×100 of the confidence maps against the label maps of their depth maps (Kuhn et al. 2020, §3.2):
    ``pooled`` over the labelled pixels of every view with GT depth (NaN without one) and ``per_view`` entries."""
    ranks, per_view = PooledRankSum(), []
    for view in views_with_gt_depth(scene):
        auc = view_auc(scene, view, depth_of(view.index), confidence_of(view.index))
        if auc is not None:
            per_view.append(auc[0])
            ranks.add(*auc[1:])
    return {"pooled": 100 * ranks.auc() if ranks.views else float("nan"), "per_view": per_view}
