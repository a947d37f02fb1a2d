"""Engine events -> rerun logs: watch PatchMatch converge, iteration by iteration, view by view.

Entity tree (one per recording; the same code writes to a live viewer or an ``.rrd`` file)::

    world/cameras/<view>            Transform3D (camera -> world) + Pinhole + rgb image
    maps/<view>/depth               DepthImage in model units (colormapped)
    maps/<view>/normal              normals colour-coded as RGB = (n + 1) / 2
    maps/<view>/cost                matching cost, class-coded in 0.01 steps (0 = perfect, 2 = no match)
    maps/<view>/selected_count      number of selected source views per pixel, class-coded
    maps/<view>/selected_views      uint32 bitmask over the view's source list (see selected_views_list)
    maps/<view>/error               |z - z_gt| / z_gt in %, class-coded (hover names it), when GT exists
    maps/<view>/counter             consistent source views after PatchMatch (and every k-th iteration with
                                    StreamOptions.confidence_every, workbench/rerun/confidence.py), class-coded
    maps/<view>/confidence          DeepC confidence (fast/full pipelines; every k-th iteration likewise)
    maps/<view>/label               GT inlier/outlier labels of the depth the confidence scored, when GT exists
    stats/<view>/{mean_cost,changed_pct,within_1pct,seconds,level,pass}   scalars
    stats/<view>/{confidence_kept_pct,confidence_auc,confidence_seconds}  scalars of the k-th iterations' scoring
    legend, legend/<kind>           markdown: colour scale, unit and 'no data' of every map (workbench.rerun.legends)
    world/fused/<pipeline>          fused cloud, when a fusion stage reports one

Timelines: ``view_iteration`` counts one view's red-black iterations over the whole run (scrub it to watch one
view converge: every view's n-th iteration sits at n); ``pass`` numbers the passes over all levels, coarse to
fine (0, 1, 2 at the coarsest level, then 3, ...); ``iteration`` is the engine's global step, all views
interleaved (view 0 at steps 0-2, 24-26, ... with 8 views). Logging can be thinned (every k-th iteration, one
view, reduced resolution); GT error is logged with the maps at every logged iteration of every level.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import rerun as rr

from engine.confidence.labels import label_map
from engine.core.camera import Camera
from engine.core.observer import IterationEvent, NullObserver
from workbench.maps.gt_depth import LevelGT, depth_error
from workbench.maps.images import normal_to_rgb, subsample
from workbench.rerun.legends import (
    CONTEXTS,
    LEGENDS,
    confidence_classes,
    cost_classes,
    count_classes,
    counter_classes,
    error_classes,
    label_classes,
    legend_markdown,
    selected_count_context,
)
from workbench.rerun.options import StreamOptions


def entity_name(index: int, name: str) -> str:
    """Entity-path-safe name of a view: index plus the image name (which may hold '/' or '.')."""
    return rr.escape_entity_path_part(f"{index:03d}_{name}")


def selected_views_list(mask: int, source_views: list[int]) -> list[int]:
    """Decode a selected-views bitmask into view indices (bit k = ``source_views[k]``)."""
    return [view for bit, view in enumerate(source_views) if mask >> bit & 1]


TIMELINES = ("view_iteration", "pass", "iteration")  # the first is the one layouts show


def _popcount(mask: np.ndarray) -> np.ndarray:
    """(H, W) uint32 bitmask -> (H, W) uint8 number of set bits."""
    count = np.zeros(mask.shape, np.uint8)
    for bit in range(32):
        count += ((mask >> np.uint32(bit)) & np.uint32(1)).astype(np.uint8)
    return count


class RerunStream(NullObserver):
    """An engine observer that logs every PatchMatch iteration to a rerun recording stream.

    Args:
        rec: the recording stream (``rr.RecordingStream``), already connected to a sink.
        views: per view (name, camera at the working resolution, rgb image float32, source_views).
        gt_depths: optional per-view GT depth at the working resolution (None entries allowed).
        options: thinning.
        pass_iterations: iterations of a pass given its index (``PatchMatchOptions.pass_iterations``), so
            that the last iteration of every pass is logged whatever the thinning.
    """

    def __init__(self, rec: rr.RecordingStream, views: list[tuple[str, Camera, np.ndarray, list[int]]],
                 gt_depths: list[np.ndarray | None] | None = None, options: StreamOptions | None = None,
                 pass_iterations: Callable[[int], int] | None = None):
        self.rec = rec
        self.pass_iterations = pass_iterations
        self.views = views
        self.gt_depths = gt_depths or [None] * len(views)
        self._level_gt = LevelGT(self.gt_depths)
        self.options = (options or StreamOptions()).validate()
        self._previous_depth: dict[int, np.ndarray] = {}
        self._view_iterations: dict[int, int] = {}  # per view: iterations seen so far
        self._passes: list[tuple[int, int]] = []  # (level, pass_index) in the order they ran
        self._last_time: dict[int, tuple[int, int, int]] = {}  # per view: (view_iteration, pass, step) last logged
        self.event_time = (0, 0, 0)  # (view_iteration, pass, step) of the event being handled, logged or not
        # observers that get every event after this stream handled it and log through it (workbench.rerun.confidence)
        self.companions: list[Any] = []
        self._contexts: set[str] = set()  # class-coded entities whose AnnotationContext is logged
        self._depth_range = [(0.0, 1.0)] * len(views)
        self._point_radius = 0.01  # model units; set_depth_ranges derives one from the scene
        self.logged_steps = 0
        self._log_cameras()

    # ---- static scene --------------------------------------------------------------------------
    def _log_cameras(self) -> None:
        rec = self.rec
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Y_DOWN, static=True)
        for index, (name, camera, rgb, _sources) in enumerate(self.views):
            path = f"world/cameras/{entity_name(index, name)}"
            rec.log(path, rr.Transform3D(translation=camera.center, mat3x3=camera.R.T), static=True)
            rec.log(path, rr.Pinhole(image_from_camera=camera.K, width=camera.width, height=camera.height,
                                     camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.3), static=True)
            rec.log(f"{path}/rgb", rr.Image((np.clip(rgb, 0, 1) * 255 + 0.5).astype(np.uint8)), static=True)
        rec.log("legend", rr.TextDocument(legend_markdown(), media_type=rr.MediaType.MARKDOWN), static=True)
        for kind, text in LEGENDS.items():
            rec.log(f"legend/{kind}", rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN), static=True)

    def set_depth_ranges(self, ranges: list[tuple[float, float]]) -> None:
        """Fix the colormap range of each view's depth (e.g. its PatchMatch depth range)."""
        self._depth_range = list(ranges)
        typical = float(np.median([np.sqrt(lo * hi) for lo, hi in ranges]))
        focal = float(np.median([c.fx for _n, c, _r, _s in self.views]))
        self._point_radius = 0.5 * typical / focal

    # ---- per iteration --------------------------------------------------------------------------
    def _last_of_pass(self, event: IterationEvent) -> bool:
        return self.pass_iterations is not None and event.iteration == self.pass_iterations(event.pass_index) - 1

    def _wanted(self, event: IterationEvent) -> bool:
        if self.options.view is not None and event.view != self.options.view:
            return False
        return self._last_of_pass(event) or event.iteration % self.options.every == 0

    def _gt_at(self, view: int, shape: tuple[int, int]) -> np.ndarray | None:
        """The view's GT depth at ``shape`` (coarser pyramid levels get a resampled copy, cached)."""
        return self._level_gt.at(view, shape)

    def _log_classes(self, path: str, kind: str, ids: np.ndarray, context: Callable[[], Any] | None = None) -> None:
        """Log a class-coded map, with its AnnotationContext (static, once per entity) naming each class."""
        if path not in self._contexts:
            self.rec.log(path, (context or CONTEXTS[kind])(), static=True)
            self._contexts.add(path)
        self.rec.log(path, rr.SegmentationImage(ids, opacity=1.0))

    def _set_time(self, view_iteration: int, pass_number: int, step: int) -> None:
        self.rec.set_time("view_iteration", sequence=view_iteration)
        self.rec.set_time("pass", sequence=pass_number)
        self.rec.set_time("iteration", sequence=step)

    def depth_range(self, view: int) -> tuple[float, float]:
        """The (min, max) depth of ``view`` (its colormap range; the PatchMatch range after set_depth_ranges)."""
        return self._depth_range[view]

    def set_event_time(self) -> None:
        """Set the timelines to the event being handled (for companions logging at its iteration)."""
        self._set_time(*self.event_time)

    def log_view_classes(self, view: int, kind: str, ids: np.ndarray) -> None:
        """Log the class-coded map ``maps/<view>/<kind>`` (a kind of ``legends.CONTEXTS``) at the current
        time."""
        self._log_classes(f"maps/{entity_name(view, self.views[view][0])}/{kind}", kind, ids)

    def on_iteration(self, event: IterationEvent) -> None:
        self._log_iteration(event)
        for companion in self.companions:
            companion.on_iteration(event)

    def _log_iteration(self, event: IterationEvent) -> None:
        view = event.view
        view_iteration = self._view_iterations.get(view, 0)
        self._view_iterations[view] = view_iteration + 1
        if (event.level, event.pass_index) not in self._passes:
            self._passes.append((event.level, event.pass_index))
        pass_number = self._passes.index((event.level, event.pass_index))
        self.event_time = (view_iteration, pass_number, event.step)
        depth = event.depth
        valid = depth > 0
        previous = self._previous_depth.get(view)
        changed = float("nan")
        if previous is not None and previous.shape == depth.shape:
            changed = 100.0 * float(np.count_nonzero(previous != depth)) / depth.size
        self._previous_depth[view] = depth.copy()
        if not self._wanted(event):
            return
        rec = self.rec
        self._set_time(view_iteration, pass_number, event.step)
        self._last_time[view] = (view_iteration, pass_number, event.step)
        name, _camera, _rgb, sources = self.views[view]
        base = entity_name(view, name)
        small = self.options.max_size
        dmin, dmax = self._depth_range[view]
        # Compact: depth as a float16 depth image (hovering shows the depth), the other scalar maps as uint8 class
        # ids whose AnnotationContext names value and unit on hover; ~0.6 MB per view and iteration at 320x240.
        rec.log(f"maps/{base}/depth", rr.DepthImage(subsample(depth, small).astype(np.float16), meter=1.0,
                                                    colormap="turbo", depth_range=[dmin, dmax]))
        rec.log(f"maps/{base}/normal", rr.Image(normal_to_rgb(subsample(event.normal, small))))
        self._log_classes(f"maps/{base}/cost", "cost", cost_classes(subsample(event.cost, small),
                                                                     subsample(~valid, small)))
        mask = subsample(event.selected_views, small)
        self._log_classes(f"maps/{base}/selected_count", "selected_count", count_classes(_popcount(mask)),
                          lambda: selected_count_context(len(sources)))
        if self.options.selected_views_mask and self._last_of_pass(event):
            rec.log(f"maps/{base}/selected_views", rr.Image(np.ascontiguousarray(mask), color_model="L"))
        stats = f"stats/{base}"
        mean_cost = float(event.cost[valid].mean()) if valid.any() else float("nan")
        rec.log(f"{stats}/mean_cost", rr.Scalars(mean_cost))
        rec.log(f"{stats}/changed_pct", rr.Scalars(changed))
        rec.log(f"{stats}/seconds", rr.Scalars(event.seconds))
        if event.pixels_skipped:  # the active set (PatchMatchOptions.active_share)
            rec.log(f"{stats}/skipped_pct", rr.Scalars(100.0 * event.pixels_skipped / max(
                event.pixels_skipped + event.pixel_updates, 1)))
        rec.log(f"{stats}/level", rr.Scalars(event.level))
        rec.log(f"{stats}/pass", rr.Scalars(event.pass_index))
        gt = self._gt_at(view, depth.shape)
        if gt is not None:
            error = depth_error(depth, gt)
            rec.log(f"{stats}/within_1pct", rr.Scalars(error.within_pct))
            self._log_classes(f"maps/{base}/error", "error", error_classes(subsample(error.rel, small) * 100))
        self.logged_steps += 1

    # ---- later stages ---------------------------------------------------------------------------
    def log_view_map(self, view: int, kind: str, image: np.ndarray, step: int | None = None) -> None:
        """Log a per-view map of a later stage (counter, confidence, label, refined depth, ...)."""
        if step is not None:
            self.rec.set_time("iteration", sequence=step)
        name = self.views[view][0]
        self.rec.log(f"maps/{entity_name(view, name)}/{kind}", rr.Image(image))

    def log_cloud(self, pipeline: str, xyz: np.ndarray, rgb: np.ndarray, radius: float = 0.01) -> None:
        """Log a fused cloud under ``world/fused/<pipeline>``."""
        self.rec.log(f"world/fused/{pipeline}", rr.Points3D(xyz, colors=rgb, radii=radius), static=True)

    def log_mesh(self, pipeline: str, mesh: Any) -> None:
        """Log a :class:`engine.meshing.TriangleMesh` under ``world/mesh/<pipeline>`` (shown beside the cloud)."""
        self.rec.log(f"world/mesh/{pipeline}", rr.Mesh3D(
            vertex_positions=np.asarray(mesh.vertices, np.float32), triangle_indices=mesh.triangles,
            vertex_normals=mesh.vertex_normals, vertex_colors=mesh.vertex_colors), static=True)

    def _log_stage_map(self, view: int, kind: str, ids: np.ndarray) -> None:
        """Log a map of a later stage at the view's last logged iteration (so scrubbing a view to its end
        shows it next to the final depth)."""
        if self.options.view is not None and view != self.options.view:
            return
        self._set_time(*self._last_time.get(view, (0, 0, 0)))
        self._log_classes(f"maps/{entity_name(view, self.views[view][0])}/{kind}", kind, ids)

    def labels(self, view: int, depth: np.ndarray) -> np.ndarray | None:
        """GT label map of ``depth`` (Kuhn et al. 2020, §3.2); None without GT depth."""
        gt = self._gt_at(view, depth.shape)
        if gt is None:
            return None
        _name, camera, _rgb, sources = self.views[view]
        h, w = depth.shape
        cam = camera if (camera.width, camera.height) == (w, h) else camera.rescaled(w, h)
        return label_map(depth, gt, cam, [self.views[j][1] for j in sources if j < len(self.views)],
                         max_depth=self._depth_range[view][1])

    def on_stage(self, name: str, **info: Any) -> None:
        """Log what a finished stage produced: counter maps after PatchMatch, confidence maps (and GT labels of
        the depth they score) after the confidence stage, the fused cloud after fusion, the mesh after meshing."""
        if name == "patchmatch_view_converged":
            self.rec.log("log", rr.TextLog(
                f"{info['view_name']}: level {info['level']} pass {info['pass_index']} converged after "
                f"{info['iterations']} of {info['planned']} iterations", level=rr.TextLogLevel.INFO))
            return
        self.rec.log("log", rr.TextLog(f"stage {name} done", level=rr.TextLogLevel.INFO))
        small = self.options.max_size
        maps = info.get("maps") or []
        for view, counter in enumerate(info.get("counter") or []):
            invalid = maps[view].depth <= 0 if view < len(maps) else counter <= 0
            self._log_stage_map(view, "counter", counter_classes(subsample(counter, small), subsample(invalid, small)))
        depths = info.get("depth") or []
        for view, conf in enumerate(info.get("confidence") or []):
            depth = depths[view] if view < len(depths) else None
            invalid = None if depth is None else subsample(depth <= 0, small)
            self._log_stage_map(view, "confidence", confidence_classes(subsample(conf, small), invalid))
            labels = None if depth is None else self.labels(view, depth)
            if labels is not None:
                self._log_stage_map(view, "label", label_classes(subsample(labels, small)))
        cloud = info.get("cloud")
        if cloud is not None:
            self.log_cloud(str(info.get("pipeline", "vanilla")), np.asarray(cloud.xyz, np.float32), cloud.rgb,
                           radius=self._point_radius)
        mesh = info.get("mesh")
        if mesh is not None:
            self.log_mesh(str(info.get("pipeline", "vanilla")), mesh)
        for companion in self.companions:
            companion.on_stage(name, **info)
