"""Engine events -> rerun logs: watch PatchMatch converge, iteration by iteration, view by view.

Entity tree (one per recording; the same code writes to a live viewer or an ``.rrd`` file)::

    world/cameras/<view>            Transform3D (camera -> world) + Pinhole + rgb image
    maps/<view>/depth               depth in model units: a PNG depth image in steps of 1/4095 of the view's far
                                    depth (hover reads the depth), colormapped
    maps/<view>/normal              normals colour-coded as RGB = (n + 1) / 2, a JPEG
    maps/<view>/cost                matching cost, class-coded in 0.01 steps (0 = perfect, 2 = no match)
    maps/<view>/selected_count      number of selected source views per pixel, class-coded
    maps/<view>/selected_views      bitmask over the view's source list (see selected_views_list), a lossless PNG
                                    of 8 or 16 bits (32 as raw pixels for more than 16 sources)
    maps/<view>/error               |z - z_gt| / z_gt in %, class-coded (hover names it), when GT exists
    maps/<view>/counter             consistent source views after PatchMatch (and every k-th iteration with
                                    StreamOptions.confidence_every, workbench/rerun/confidence.py), class-coded
    maps/<view>/confidence          DeepC confidence (fast/full pipelines; every k-th iteration likewise)
    maps/<view>/label               GT inlier/outlier labels of the depth the confidence scored, when GT exists
    stats/<view>/{mean_cost,changed_pct,within_1pct,seconds,level,pass}   scalars
    stats/<view>/pixel_scale        full-resolution pixels per pixel of the logged maps (hover positions × it)
    stats/<view>/{confidence_kept_pct,confidence_auc,confidence_seconds}  scalars of the k-th iterations' scoring
    legend, legend/<kind>           markdown: colour scale, unit and 'no data' of every map (workbench.rerun.legends)
    world/fused/<pipeline>          fused cloud, when a fusion stage reports one (thinned to at most
                                    StreamOptions.max_points: the full cloud is fused.ply)

Timelines: ``view_iteration`` counts one view's red-black iterations over the whole run (scrub it to watch one
view converge: every view's n-th iteration sits at n); ``pass`` numbers the passes over all levels, coarse to
fine (0, 1, 2 at the coarsest level, then 3, ...); ``iteration`` is the engine's global step, all views
interleaved (view 0 at steps 0-2, 24-26, ... with 8 views). Logging can be thinned (every k-th iteration, one
view, reduced resolution; a run's recording chooses within its budget, ``workbench/rerun/budget.py``); GT error is
logged with the maps at every logged iteration of every level.
"""

from __future__ import annotations

import io
import math
from collections.abc import Callable
from typing import Any

import numpy as np
import rerun as rr
from PIL import Image

from engine.confidence.labels import label_map
from engine.core.camera import Camera
from engine.core.observer import IterationEvent, NullObserver
from engine.core.words import plural
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

#: JPEG quality of the logged normal maps (colour-coded directions: 85 keeps them visually exact) and photographs
NORMAL_JPEG_QUALITY, PHOTO_JPEG_QUALITY = 85, 90


def entity_name(index: int, name: str) -> str:
    """Entity-path-safe name of a view: index plus the image name (which may hold '/' or '.')."""
    return rr.escape_entity_path_part(f"{index:03d}_{name}")


def selected_views_list(mask: int, source_views: list[int]) -> list[int]:
    """Decode a selected-views bitmask into view indices (bit k = ``source_views[k]``)."""
    return [view for bit, view in enumerate(source_views) if mask >> bit & 1]


TIMELINES = ("view_iteration", "pass", "iteration")  # the first is the one layouts show


#: integer steps of a logged depth map from 0 to its far end (a 16-bit PNG): at most 0.06 % of the far depth, 16
#: times finer than the 1 % that counts as right, and a third of the bytes of whole 16-bit steps (bench_recording.py)
DEPTH_STEPS = 4095
DEPTH_PNG_LEVEL = 3


def depth_meter(far: float) -> float:
    """Steps per model unit of a map reaching ``far``: the largest 1, 2 or 5 × 10^k that keeps ``far`` within
    ``DEPTH_STEPS``. Rerun's hover prints steps / meter with every digit and no unit ("Depth 7.031 013 431 013 43"
    for 4095 steps over 8.33 m); a round meter prints the depth as a short decimal ("Depth 7.031")."""
    if far <= 0:
        return 1.0
    limit = DEPTH_STEPS / far
    decade = 10.0 ** math.floor(math.log10(limit))
    return max(m * decade for m in (1, 2, 5) if m * decade <= limit)


def depth_image(depth: np.ndarray, depth_range: tuple[float, float]) -> rr.EncodedDepthImage | rr.DepthImage:
    """(H, W) depth in model units (0 = none) as a PNG depth image in steps of 1 / :func:`depth_meter` of the
    farther of the range's far end and the map's largest depth (``meter`` = steps per model unit, so the viewer's
    hover reads model units), a valid depth never rounded to 0; colormapped over ``depth_range``."""
    dmin, dmax = depth_range
    scale = depth_meter(max(dmax, float(depth.max()) if depth.size else 0.0))
    steps = np.clip(np.rint(np.asarray(depth, np.float64) * scale), 0, DEPTH_STEPS).astype(np.uint16)
    steps[(depth > 0) & (steps == 0)] = 1
    # zlib level 3: about 2 % more bytes than level 9 at a quarter of its time (this runs in the engine's thread)
    return rr.DepthImage(steps, meter=scale, colormap="turbo", depth_range=[dmin * scale, dmax * scale]).compress(
        compress_level=DEPTH_PNG_LEVEL)


def png_image(values: np.ndarray) -> rr.EncodedImage:
    """A lossless single-channel PNG of 8- or 16-bit (H, W) integers."""
    buffer = io.BytesIO()
    array = np.ascontiguousarray(values)
    Image.fromarray(array if array.dtype == np.uint8 else array.astype(np.uint16)).save(buffer, format="PNG")
    return rr.EncodedImage(contents=buffer.getvalue(), media_type="image/png")


def mask_image(mask: np.ndarray, n_sources: int) -> rr.EncodedImage | rr.Image:
    """The selected-views bitmask (H, W) uint32 over ``n_sources`` views in the fewest bits that hold it: a PNG of
    8 or 16 bits, raw 32-bit pixels beyond 16 sources."""
    if n_sources <= 8:
        return png_image(mask.astype(np.uint8))
    if n_sources <= 16:
        return png_image(mask.astype(np.uint16))
    return rr.Image(np.ascontiguousarray(mask), color_model="L")


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
        # per view: the last iteration thinning left out (its maps are the view's until its next iteration)
        self._skipped: dict[int, tuple[IterationEvent, tuple[int, int, int], float]] = {}
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
            rec.log(f"{path}/rgb", rr.Image((np.clip(rgb, 0, 1) * 255 + 0.5).astype(np.uint8)).compress(
                jpeg_quality=PHOTO_JPEG_QUALITY), static=True)
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
        return self._last_of_pass(event) or event.iteration % (self.options.every or 1) == 0

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
        previous = self._previous_depth.get(view)
        changed = float("nan")
        if previous is not None and previous.shape == depth.shape:
            changed = 100.0 * float(np.count_nonzero(previous != depth)) / depth.size
        self._previous_depth[view] = depth.copy()
        if not self._wanted(event):
            # a pass that converges ends before its planned last iteration: this one is logged if it was the last
            self._skipped[view] = (event, (view_iteration, pass_number, event.step), changed)
            return
        self._log_maps(event, (view_iteration, pass_number, event.step), changed)

    def _log_maps(self, event: IterationEvent, times: tuple[int, int, int], changed: float,
                  pass_end: bool = False) -> None:
        """Log ``event``'s maps and scalars at ``times`` (``pass_end``: the last iteration of a pass that ended
        early)."""
        self._skipped.pop(event.view, None)
        view, depth = event.view, event.depth
        valid = depth > 0
        rec = self.rec
        self._set_time(*times)
        self._last_time[view] = times
        name, camera, _rgb, sources = self.views[view]
        base = entity_name(view, name)
        small = self.options.max_size or 0
        dmin, dmax = self._depth_range[view]
        # Compact: depth as a 16-bit PNG depth image (hovering shows the depth), normals as a JPEG, the other scalar
        # maps as uint8 class ids whose AnnotationContext names value and unit on hover (benchmarks/performance/
        # bench_recording.py measures the sizes)
        rec.log(f"maps/{base}/depth", depth_image(subsample(depth, small), (dmin, dmax)))
        rec.log(f"maps/{base}/normal", rr.Image(normal_to_rgb(subsample(event.normal, small))).compress(
            jpeg_quality=NORMAL_JPEG_QUALITY))
        self._log_classes(f"maps/{base}/cost", "cost", cost_classes(subsample(event.cost, small),
                                                                     subsample(~valid, small)))
        mask = subsample(event.selected_views, small)
        self._log_classes(f"maps/{base}/selected_count", "selected_count", count_classes(_popcount(mask)),
                          lambda: selected_count_context(len(sources)))
        if self.options.selected_views_mask and (pass_end or self._last_of_pass(event)):
            rec.log(f"maps/{base}/selected_views", mask_image(mask, len(sources)))
        stats = f"stats/{base}"
        mean_cost = float(event.cost[valid].mean()) if valid.any() else float("nan")
        rec.log(f"{stats}/mean_cost", rr.Scalars(mean_cost))
        rec.log(f"{stats}/changed_pct", rr.Scalars(changed))
        rec.log(f"{stats}/seconds", rr.Scalars(event.seconds))
        if event.pixels_skipped:  # the active set (PatchMatchOptions.active_share)
            rec.log(f"{stats}/skipped_pct", rr.Scalars(100.0 * event.pixels_skipped / max(
                event.pixels_skipped + event.pixel_updates, 1)))
        rec.log(f"{stats}/level", rr.Scalars(event.level))
        # a hover's Position counts the logged map's pixels: this turns it into the inspector's full-resolution ones
        rec.log(f"{stats}/pixel_scale", rr.Scalars(camera.width / subsample(depth, small).shape[1]))
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
        """Log a fused cloud under ``world/fused/<pipeline>``, every k-th point of it when it has more than
        ``options.max_points`` (fusion emits points view by view, pixel by pixel: a stride keeps every part of the
        scene at a k-th of its density)."""
        stride = max(1, -(-len(xyz) // self.options.max_points)) if self.options.max_points else 1
        self.rec.log(f"world/fused/{pipeline}", rr.Points3D(xyz[::stride], colors=rgb[::stride], radii=radius),
                     static=True)

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
            skipped = self._skipped.get(info.get("view", -1))
            if skipped is not None:  # the pass's last iteration, left out by thinning: its maps are the final ones
                self._log_maps(*skipped, pass_end=True)
            self.rec.log("log", rr.TextLog(
                f"{info['view_name']}: level {info['level']} pass {info['pass_index']} converged after "
                f"{info['iterations']} of {plural(info['planned'], 'iteration')}", level=rr.TextLogLevel.INFO))
            return
        self.rec.log("log", rr.TextLog(f"stage {name} done", level=rr.TextLogLevel.INFO))
        small = self.options.max_size or 0
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
