"""The stages of a ``--executor dask`` run after its per-view tasks, streamed from the run folder the tasks wrote,
so that the driver holds no list of per-view maps: fusion reads the views through a bounded cache
(:mod:`engine.fusion.cached`, COLMAP's workspace cache) and filters each one as it is loaded (as the pipeline fuses it,
:mod:`engine.run.fused_maps`), writing its points into ``fused.ply`` as they come
(:mod:`engine.fusion.stream`: the cloud stays on disk); the metrics are accumulated view by view
(:mod:`engine.run.scores`). Cloud and metrics equal those of the in-process pipeline on the same maps.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from engine.core.errors import DeepCError
from engine.fusion import FusedCloud, FusionOptions, FusionView
from engine.fusion.cached import CacheStats, fuse_cached
from engine.fusion.stream import write_fused_stream
from engine.fusion.views import scene_view
from engine.run.folder import read_map
from engine.run.fused_maps import FusionRule, fused_view, read_run_view
from engine.run.scores import confidence_auc, depth_block, views_with_gt_depth
from engine.scene import Scene


def read_view_map(out_dir: str | Path, kind: str, name: str) -> np.ndarray:
    """A map the tasks wrote (a missing one is an error naming it)."""
    array = read_map(out_dir, kind, name)
    if array is None:
        raise DeepCError(f"{kind} map of {name} missing", Path(out_dir))
    return array


def fused_view_loader(scene: Scene, out_dir: str | Path, rule: FusionRule) -> Callable[[int], FusionView]:
    """View index -> its :class:`FusionView` read from ``out_dir`` as ``rule``'s pipeline fuses it
    (:func:`engine.run.fused_maps.fused_view`; no overlap list)."""
    def load(i: int) -> FusionView:
        maps = fused_view(scene, i, rule, read_run_view(out_dir, scene.views[i].name, rule.kinds()))
        return scene_view(scene, i, maps.depth, maps.normal, maps.confidence, [])
    return load


def fuse_run_folder(scene: Scene, out_dir: str | Path, options: FusionOptions, rule: FusionRule,
                    cache_views: int | None = None, stats: CacheStats | None = None,
                    ply: str | Path | None = None) -> FusedCloud:
    """The fused cloud of the maps in ``out_dir`` as ``rule`` fuses them, with at most ``cache_views`` views in
    memory (None: 1 + the longest overlap list, ``engine.fusion.cached``); equal to
    ``fuse(views_from_scene(...))`` of the same maps (the tasks write them at each view's working resolution).
    With ``ply``, the points are written into that file as fusion makes them (``write_fused_ply``'s bytes) and
    the cloud returned lives there (a :class:`engine.fusion.cloud.DiskCloud`): the memory does not grow with the
    points."""
    overlaps = [scene.overlapping_views(i, options.check_num_images) for i in range(len(scene.views))]
    cameras = [v.camera for v in scene.views]
    load = fused_view_loader(scene, out_dir, rule)
    confidence = rule.pipeline != "vanilla"  # vanilla reads no confidence maps
    if ply is None:
        return fuse_cached(cameras, overlaps, load, options, cache_views, confidence=confidence, stats=stats)
    return write_fused_stream(ply, lambda sink: fuse_cached(cameras, overlaps, load, options, cache_views,
                                                            confidence=confidence, stats=stats, sink=sink),
                              max_points=sum(c.width * c.height for c in cameras))  # a point consumes a pixel


def streamed_metrics(scene: Scene, out_dir: str | Path, rule: FusionRule) -> dict[str, Any]:
    """The metrics.json entries an in-process run of ``rule``'s pipeline (vanilla or fast: ``full`` reads its maps
    back) computes from its maps, read view by view from ``out_dir``, in its order: ``depth`` and
    ``depth_per_view`` (with GT depth), ``confidence_auc`` and ``confidence_auc_per_view`` (with GT depth, under
    fast), ``confidence_kept_pct`` (under fast). Scored by the pipeline's own functions (``engine.run.scores``)."""
    if rule.pipeline == "full":
        raise DeepCError("a full run's metrics come from its maps in memory, not streamed")
    filtered = rule.pipeline != "vanilla"
    out: dict[str, Any] = {}
    if views_with_gt_depth(scene):
        def depth_of(i: int) -> np.ndarray:
            return read_view_map(out_dir, "depth", scene.views[i].name)

        out["depth"], out["depth_per_view"] = depth_block(scene, depth_of)
        if filtered:
            auc = confidence_auc(scene, depth_of, lambda i: read_view_map(out_dir, "confidence", scene.views[i].name))
            out["confidence_auc"], out["confidence_auc_per_view"] = auc["pooled"], auc["per_view"]
    if filtered:
        kept = before = 0
        for i, view in enumerate(scene.views):
            maps = read_run_view(out_dir, view.name, rule.kinds())
            kept += int((fused_view(scene, i, rule, maps).depth > 0).sum())
            before += int((maps.depth > 0).sum())
        out["confidence_kept_pct"] = 100.0 * kept / max(1, before)
    return out

