"""The stages of a ``--executor dask`` run after its per-view tasks, streamed from the run folder the tasks wrote,
so that the driver holds no list of per-view maps: fusion reads the views through a bounded cache
(:mod:`engine.fusion.cached`, COLMAP's workspace cache) and filters each one as it is loaded (DeepC-MVS_fast's
confidence filter, Kuhn et al. 2020, §4.1), writing its points into ``fused.ply`` as they come
(:mod:`engine.fusion.stream`: the cloud stays on disk); the metrics are accumulated view by view
(:mod:`engine.run.scores`). Cloud and metrics equal those of the in-process pipeline on the same maps.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from engine.core.errors import DeepCError
from engine.filtering import filter_by_confidence
from engine.fusion import FusedCloud, FusionOptions, FusionView
from engine.fusion.cached import CacheStats, fuse_cached
from engine.fusion.stream import write_fused_stream
from engine.fusion.views import scene_view
from engine.run.folder import read_map
from engine.run.scores import confidence_auc, depth_block, views_with_gt_depth
from engine.scene import Scene


def read_view_map(out_dir: str | Path, kind: str, name: str) -> np.ndarray:
    """A map the tasks wrote (a missing one is an error naming it)."""
    array = read_map(out_dir, kind, name)
    if array is None:
        raise DeepCError(f"{kind} map of {name} missing", Path(out_dir))
    return array


def filtered_maps(out_dir: str | Path, name: str, tau: float | None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(depth, normal, confidence) of one view as the pipeline fuses them: the PatchMatch maps, filtered by their
    confidence (kept where c >= ``tau``) unless ``tau`` is None (vanilla: no confidence)."""
    depth, normal = read_view_map(out_dir, "depth", name), read_view_map(out_dir, "normal", name)
    if tau is None:
        return depth, normal, None
    confidence = read_view_map(out_dir, "confidence", name)
    depth, normal = filter_by_confidence(depth, normal, confidence, tau)
    return depth, normal, confidence


def fused_view_loader(scene: Scene, out_dir: str | Path, tau: float | None) -> Callable[[int], FusionView]:
    """View index -> its :class:`FusionView` read from ``out_dir`` (see :func:`filtered_maps`; no overlap list)."""
    def load(i: int) -> FusionView:
        return scene_view(scene, i, *filtered_maps(out_dir, scene.views[i].name, tau), [])
    return load


def fuse_run_folder(scene: Scene, out_dir: str | Path, options: FusionOptions, tau: float | None,
                    cache_views: int | None = None, stats: CacheStats | None = None,
                    ply: str | Path | None = None) -> FusedCloud:
    """The fused cloud of the maps in ``out_dir``, with at most ``cache_views`` views in memory (None: 1 + the
    longest overlap list, ``engine.fusion.cached``); equal to
    ``fuse(views_from_scene(...))`` of the same maps (the tasks write them at each view's working resolution).
    With ``ply``, the points are written into that file as fusion makes them (``write_fused_ply``'s bytes) and
    the cloud returned lives there (a :class:`engine.fusion.cloud.DiskCloud`): the memory does not grow with the
    points."""
    overlaps = [scene.overlapping_views(i, options.check_num_images) for i in range(len(scene.views))]
    cameras = [v.camera for v in scene.views]
    load = fused_view_loader(scene, out_dir, tau)
    if ply is None:
        return fuse_cached(cameras, overlaps, load, options, cache_views, confidence=tau is not None, stats=stats)
    return write_fused_stream(ply, lambda sink: fuse_cached(cameras, overlaps, load, options, cache_views,
                                                            confidence=tau is not None, stats=stats, sink=sink),
                              max_points=sum(c.width * c.height for c in cameras))  # a point consumes a pixel


def streamed_metrics(scene: Scene, out_dir: str | Path, tau: float | None) -> dict[str, Any]:
    """The metrics.json entries an in-process run computes from its maps, read view by view from ``out_dir``, in its
    order: ``depth`` and ``depth_per_view`` (with GT depth), ``confidence_auc`` and ``confidence_auc_per_view`` (with
    GT depth and a confidence filter ``tau``), ``confidence_kept_pct`` (with ``tau``). Scored by the pipeline's own
    functions (``engine.run.scores``)."""
    out: dict[str, Any] = {}
    if views_with_gt_depth(scene):
        def depth_of(i: int) -> np.ndarray:
            return read_view_map(out_dir, "depth", scene.views[i].name)

        out["depth"], out["depth_per_view"] = depth_block(scene, depth_of)
        if tau is not None:
            auc = confidence_auc(scene, depth_of, lambda i: read_view_map(out_dir, "confidence", scene.views[i].name))
            out["confidence_auc"], out["confidence_auc_per_view"] = auc["pooled"], auc["per_view"]
    if tau is not None:
        kept = before = 0
        for view in scene.views:
            depth = read_view_map(out_dir, "depth", view.name)
            with np.errstate(invalid="ignore"):
                keep = read_view_map(out_dir, "confidence", view.name) >= tau
            kept += int((np.where(keep, depth, np.float32(0.0)) > 0).sum())  # filter_by_confidence's depth > 0
            before += int((depth > 0).sum())
        out["confidence_kept_pct"] = 100.0 * kept / max(1, before)
    return out

