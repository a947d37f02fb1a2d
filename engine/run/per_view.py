"""The per-view bodies of the stages after PatchMatch (counter map, confidence, a view's confidence AUC): the
in-process pipeline loops over views with them, and ``engine.run.distributed`` runs them one view at a time."""

from __future__ import annotations

from typing import Any

import numpy as np

from engine.confidence.data import view_labels
from engine.confidence.inputs import network_inputs
from engine.confidence.metrics import roc_auc
from engine.confidence.options import ConfidenceOptions
from engine.consistency import CounterOptions, compute_counter_maps
from engine.patchmatch import PatchMatchView, ViewMaps
from engine.scene import Scene, SceneViews


def patchmatch_view(scene: Scene | SceneViews, i: int) -> PatchMatchView:
    """The PatchMatch input of view ``i`` of ``scene`` at its working resolution."""
    v = scene.views[i]
    return PatchMatchView(v.name, scene.gray(i), v.camera, v.depth_range[0], v.depth_range[1], list(v.source_views))


class SceneView:
    """A :class:`PatchMatchView` whose grey image is read from the scene when asked for (the scene's image cache
    bounds the memory): what a driver that never holds every image at once passes to checks and fingerprints."""

    def __init__(self, scene: Scene, i: int):
        v = scene.views[i]
        self.scene, self.index = scene, i
        self.name, self.camera, self.source_views = v.name, v.camera, list(v.source_views)
        self.depth_min, self.depth_max = v.depth_range

    @property
    def image_gray(self) -> np.ndarray:
        return self.scene.gray(self.index)


def view_confidence(image: np.ndarray, maps: ViewMaps, counter: np.ndarray, n_sources: int,
                    options: ConfidenceOptions, model: Any) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) float32 confidence in [0, 1] of one view from the network (Kuhn et al. 2020, §3.2), zero where there
    is no depth, and the same before the back-facing rule (``options.zero_backfacing``; the refinement's weights).

    Args:
        image: (H, W, 3) float32 RGB in [0, 1] at the maps' resolution.
        maps: the view's PatchMatch maps; counter: its (H, W) uint8 counter map; n_sources: its source views.
        model: a loaded :class:`engine.confidence.network.ConfidenceNet` (torch threads are the caller's).
    """
    from engine.confidence.inference import facing_away, predict_confidence  # lazy: torch

    x = network_inputs(image, maps.normal, counter, n_sources)
    c = predict_confidence(model, x, options.tile, options.overlap, options.bf16)
    c = np.where(maps.depth > 0, c, np.float32(0.0)).astype(np.float32)
    raw = c.copy() if options.zero_backfacing else c
    if options.zero_backfacing:
        c[facing_away(x)] = 0.0
    return c, raw


def view_counter(view: PatchMatchView, sources: list[PatchMatchView], maps: ViewMaps, source_depths: list[np.ndarray],
                 options: CounterOptions) -> np.ndarray:
    """(H, W) uint8 counter map of one view (Kuhn et al. 2020, §3.1) from its final maps and its source views' final
    depth maps (``view.source_views`` in order), exactly as :func:`engine.consistency.compute_counter_maps` makes it
    for that view: the view as the only reference of a list holding its sources (they get no map of their own)."""
    ref = PatchMatchView(view.name, view.image_gray, view.camera, view.depth_min, view.depth_max,
                         list(range(1, 1 + len(sources))))
    others = [PatchMatchView(s.name, s.image_gray, s.camera, s.depth_min, s.depth_max, []) for s in sources]
    empty = [ViewMaps(d, np.zeros((*d.shape, 3), np.float32), np.zeros_like(d), np.zeros(d.shape, np.uint32))
             for d in source_depths]
    return compute_counter_maps([ref, *others], [maps, *empty], options)[0]


def view_auc(scene: Scene, view: Any, depth: np.ndarray, confidence: np.ndarray
             ) -> tuple[dict[str, Any], np.ndarray, np.ndarray] | None:
    """One view's entry of metrics.json's ``confidence_auc_per_view`` (ROC-AUC x 100 of ``confidence`` against the
    label map of ``depth``, Kuhn et al. 2020, §3.2) and its labelled scores and labels (what the pooled AUC pools);
    None without GT depth."""
    y = view_labels(scene, view.index, depth)
    if y is None:
        return None
    keep = y >= 0
    entry = {"view": view.name, "auc": 100 * roc_auc(confidence[keep], y[keep]), "labelled": int(keep.sum()),
             "inliers": int((y == 1).sum())}
    return entry, confidence[keep], y[keep]
