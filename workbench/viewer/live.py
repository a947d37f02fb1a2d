"""The 3-D viewer live while ``deepc run`` runs, then the tuning viewer of the run on the same server.

:class:`LiveViewer` is an engine observer (``engine/core/observer.py``). It starts the viser server when the run
starts and draws the cameras at once (as the tuning viewer draws them, ``workbench.viewer.app.add_cameras``); then,
per view, the current PatchMatch depth back-projected as a thinned point cloud that follows the iterations,
coloured by depth, by GT error (the default when the scene has GT depth) or by confidence (once a
confidence map of the view is known), and a progress panel: stage, level, pass, iteration, views done, the
whole run's ETA (``engine/run/eta.py``) and the share of GT pixels within 1 % so far (scored as the rerun
stream scores it, ``workbench/maps/gt_depth.py``).
After PatchMatch the panel names the stage running (counter maps, confidence, refinement, fusion, meshing,
evaluation) and the fused cloud replaces the per-view clouds. When the run ends, ``deepc run`` calls
``workbench.viewer.app.serve(out, server=live.hand_over(), on_open=live.release)``: the tuning viewer is built on
this server, on the run's own settings (its metrics.json), and once its panel is up the progress panel and
the per-view clouds are removed. Browser tabs stay connected throughout (no reload, no new port).

The engine is never held up by the browser: ``on_iteration`` only copies the view's depth and replaces
that view's waiting snapshot; a :class:`workbench.viewer.scheduler.NewestWorker` scores, back-projects, colours and
pushes the newest snapshot of every view, at most ``PUSH_HZ`` times a second, and the snapshots superseded
meanwhile are never drawn. ``benchmarks/performance/bench_viewer_live.py`` measures what it costs a run.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from typing import Any

import numpy as np

from engine.core.camera import Camera
from engine.core.observer import IterationEvent, NullObserver
from engine.core.words import plural
from engine.run.pipeline import PipelineOptions
from engine.scene import Scene
from workbench.maps.gt_depth import LevelGT, depth_error
from workbench.maps.images import colorize
from workbench.viewer.app import POINT_BUDGET, add_cameras, announce, open_server, set_home_camera
from workbench.viewer.legends import NO_DATA, Scale, note_html, scale_html
from workbench.viewer.scheduler import NewestWorker
from workbench.viewer.session import DEPTH_ERROR_PCT

# Longest side of a view's thinned live cloud: 11 views of fountain_p11 at 128 x 85 are 120 k points in
# all, and one view's push is about 160 kB (float32 points + uint8 colours), light enough for every tab.
LIVE_MAX_SIZE = 128
PUSH_HZ = 10.0  # the worker pushes at most this often (newer snapshots replace waiting ones meanwhile)
# the fused cloud shown until the tuning viewer's exact one: its budget, by an even stride (a streamed cloud maps
# its file; the tuning viewer's voxel thinning would read every point)
FUSED_MAX_POINTS = POINT_BUDGET
STOP_TIMEOUT_S = 10.0
# the colour mode of the relative depth error; the tuning viewer's GT distance (session.GT_DISTANCE) is in cm
DEPTH_ERROR = "depth error (%)"

# What the panel says runs after PatchMatch (the stage names of engine/run/pipeline.py's on_stage calls).
STAGE_NAMES = {"counter": "counter maps (geometric consistency of the PatchMatch maps)",
               "confidence": "confidence (DeepC network)",
               "refinement": "refinement (piece-wise planar), its counter and confidence maps",
               "fusion": "fusion", "mesh": "meshing", "evaluation": "evaluation and metrics"}


@dataclasses.dataclass
class _Snapshot:
    """One view's depth after one iteration (a private copy: the engine's arrays change afterwards)."""

    view: int
    level: int
    depth: np.ndarray  # (H, W) float32 at the level's resolution


@dataclasses.dataclass
class _Progress:
    """Where the run is: what the panel shows (written by the engine thread, read by the worker)."""

    stage: str = "starting"
    level: int | None = None
    pass_kind: str = ""
    pass_index: int = 0
    pass_iterations: int = 0
    iteration: int = 0
    view: int | None = None
    views_done: set = dataclasses.field(default_factory=set)
    shape: tuple[int, int] | None = None
    coarsest: int = 0  # the first (coarsest) level run: PatchMatch runs it down to level 0


def _thinned_rays(camera: Camera, shape: tuple[int, int], step: int) -> np.ndarray:
    """(h, w, 3) camera-frame rays (z = 1) of every ``step``-th pixel centre of ``camera`` at ``shape``."""
    h, w = shape
    cam = camera if (camera.height, camera.width) == (h, w) else camera.rescaled(w, h)
    cols, rows = np.meshgrid(np.arange(0, w, step), np.arange(0, h, step))
    pix = np.stack([cols, rows, np.ones_like(cols)], axis=-1).astype(np.float64)
    return pix @ np.linalg.inv(cam.K_idx).T


def _resampled(values: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Nearest-neighbour ``values`` at ``shape`` (a working-resolution map seen at a coarser level)."""
    if values.shape == shape:
        return values
    rows = np.minimum((np.arange(shape[0]) + 0.5) * values.shape[0] / shape[0], values.shape[0] - 1).astype(int)
    cols = np.minimum((np.arange(shape[1]) + 0.5) * values.shape[1] / shape[1], values.shape[1] - 1).astype(int)
    return values[np.ix_(rows, cols)]


class LiveViewer(NullObserver):
    """The live 3-D viewer of one run (see the module docstring).

    Args:
        scene: the scene being run (cameras, depth ranges, GT depth when it has some).
        options: the run's options (pipeline and PatchMatch schedule name the stages and passes to come).
        host, port: where to serve (port 0 = any free one; a busy port takes the next free one).
        mesh: whether the run meshes after fusion (the panel names the stage).
        max_size: longest side of a view's thinned cloud (pixels).
    """

    def __init__(self, scene: Scene, options: PipelineOptions, host: str = "127.0.0.1", port: int = 8080,
                 mesh: bool = False, max_size: int = LIVE_MAX_SIZE):
        self.scene = scene
        self.options = options
        self.mesh = mesh
        self.max_size = max_size
        self.host = host
        self._start = time.monotonic()
        self._lock = threading.Lock()  # guards _pending, _progress and _confidence (engine thread vs worker)
        self._pending: dict[int, _Snapshot] = {}
        self._progress = _Progress()
        self._confidence: dict[int, np.ndarray] = {}
        self._fused: Any = None  # the fused cloud, once fusion reports it
        self._scores: dict[int, tuple[int, int, int]] = {}  # per view: (level, within, GT pixels) of the last drawn
        self._rays: dict[tuple[int, tuple[int, int]], np.ndarray] = {}
        self._clouds: dict[int, Any] = {}  # per view: its cloud handle
        self._footprint: dict[int, float] = {}  # per view: size of one thinned pixel at its level (model units)
        self._drawn: dict[int, _Snapshot] = {}  # per view: the snapshot its cloud shows (to recolour it)
        self._recolor = False
        self._fused_shown = False  # the fused cloud has replaced the per-view clouds
        self._released = self._handed_over = self._stopped = False
        self.pushes = 0  # clouds pushed (benchmarks and tests)
        self.eta: Any = None  # the whole run's ETA (``engine.run.eta.RunEta``: ``text()``), set by ``deepc run``
        self._level_gt = LevelGT([scene.gt_depth(v.index) for v in scene.views])
        self.has_gt = any(g is not None for g in self._level_gt.gt_depths)
        ranges = np.array([v.depth_range for v in scene.views], np.float64)
        self._depth_scale = Scale("depth (PatchMatch, now)", float(ranges[:, 0].min()), float(ranges[:, 1].max()),
                                  "turbo", "m")
        self.server = open_server(host, port)
        self.port = self.server.get_port()
        try:
            set_home_camera(self.server, scene)
            self.frustums, self.frustum_scale, self.point_size = add_cameras(self.server, scene)
            self._build_panel()
        except BaseException:
            self.server.stop()
            raise
        self._worker: NewestWorker[None] = NewestWorker(self._render, self._show_error, name="deepc-live-viewer")
        self._worker.submit(None)

    # ---- panel --------------------------------------------------------------------------------------
    def _build_panel(self) -> None:
        gui = self.server.gui
        s = self.scene
        self._panel = [gui.add_markdown(f"**DeepC Workbench** · {s.name} · {plural(len(s.views), 'view')} · "
                                        f"`{self.options.pipeline}` run, live")]
        self.progress = gui.add_markdown("starting…")
        self.color_mode = gui.add_dropdown("Colour", options=self._modes(), initial_value=self._modes()[-1],
                                           hint=f"depth: each point's depth; {DEPTH_ERROR}: |z - z_gt| / z_gt at the "
                                                "level's resolution (with GT depth); confidence: once known")
        self.legend = gui.add_html(self._legend())
        self.live_point_size = gui.add_slider("Point size (× pixel)", min=0.25, max=4.0, step=0.25, initial_value=1.0,
                                              hint="× the footprint of one thinned pixel at its level (the "
                                                   "clouds are thinned: a point stands for step × step pixels)")
        self._panel += [self.progress, self.color_mode, self.legend, self.live_point_size]
        self.color_mode.on_update(lambda _event: self._color_mode_changed())
        self.live_point_size.on_update(lambda _event: self._set_point_size())

    def _modes(self) -> tuple[str, ...]:
        """Colour modes with their data, the default last: error with GT depth, else depth."""
        modes = ["depth", *(["confidence"] if self._confidence else [])]
        return (*modes, DEPTH_ERROR) if self.has_gt else tuple(modes)

    def _legend(self) -> str:
        mode = str(self.color_mode.value)
        if mode == DEPTH_ERROR:
            return scale_html(Scale("depth error vs GT, % of the GT depth (at the level's resolution)", 0.0,
                                    DEPTH_ERROR_PCT, "RdYlGn_r", "%", no_data="no GT depth", saturates=True, digits=1))
        if mode == "confidence":
            return scale_html(Scale("confidence", 0.0, 1.0, "viridis", no_data="no confidence yet"))
        return scale_html(self._depth_scale) + note_html("one thinned cloud per view: its depth after the newest "
                                                         "iteration")

    def _color_mode_changed(self) -> None:
        self.legend.content = self._legend()
        with self._lock:
            self._recolor = True
        self._worker.submit(None)

    def _set_point_size(self) -> None:
        for view, handle in list(self._clouds.items()):
            handle.point_size = self._footprint.get(view, self.point_size) * float(self.live_point_size.value)

    def _show_error(self, exc: Exception) -> None:
        """The live view survives one bad update (the run goes on): the panel says what went wrong."""
        self.progress.content = f"**live view error:** {' '.join(str(exc).split())}"

    # ---- engine side (never waits on the browser) ------------------------------------------------------
    def on_iteration(self, event: IterationEvent) -> None:
        snapshot = _Snapshot(event.view, event.level, np.array(event.depth, np.float32, copy=True))
        with self._lock:
            p = self._progress
            self._pending[event.view] = snapshot
            p.stage, p.level, p.view, p.shape = "patchmatch", event.level, event.view, event.depth.shape
            p.pass_kind, p.pass_index, p.iteration = event.pass_kind, event.pass_index, event.iteration
            if p.pass_iterations and event.iteration == p.pass_iterations - 1:
                p.views_done.add(event.view)
        self._worker.submit(None)

    def on_stage(self, name: str, **info: Any) -> None:
        """Follow the stages: PatchMatch passes, then what runs after PatchMatch (named in the panel)."""
        confidence = info.get("confidence")
        if isinstance(confidence, np.ndarray) and isinstance(info.get("view"), int):  # one view's map
            self.set_confidence(info["view"], confidence)
            confidence = None
        with self._lock:
            p = self._progress
            if name == "patchmatch_pass":
                # the previous pass's view and (at a new level) its map size are not this pass's
                if p.level != info.get("level"):
                    p.shape = None
                p.stage, p.level, p.pass_kind = "patchmatch", info.get("level"), str(info.get("pass_kind", ""))
                p.pass_index, p.pass_iterations = int(info.get("pass_index", 0)), int(info.get("iterations", 0))
                p.iteration, p.views_done, p.view = 0, set(), None
                p.coarsest = max(p.coarsest, int(info.get("level") or 0))
            elif name == "patchmatch_done":
                p.stage = "counter"
            elif name in ("patchmatch", "confidence", "refinement", "fusion", "mesh"):
                p.stage = self._next_stage(name)
            if isinstance(confidence, list | tuple):
                for view, conf in enumerate(confidence):
                    if conf is not None:
                        self._confidence[view] = np.array(conf, np.float32, copy=True)
                self._recolor = self._recolor or str(self.color_mode.value) == "confidence"
            if name == "fusion" and info.get("cloud") is not None:
                self._fused = info["cloud"]
        if isinstance(confidence, list | tuple):
            self._update_modes()
        self._worker.submit(None)

    def set_confidence(self, view: int, confidence: np.ndarray) -> None:
        """Colour ``view`` by this (H, W) confidence in [0, 1] (any resolution: resampled to the level's) from
        now on, e.g. confidence computed while PatchMatch runs."""
        recolor = str(self.color_mode.value) == "confidence"  # other colours do not change
        with self._lock:
            self._confidence[view] = np.array(confidence, np.float32, copy=True)
            self._recolor = self._recolor or recolor
        self._update_modes()
        self._worker.submit(None)

    def _update_modes(self) -> None:
        modes = self._modes()
        if tuple(self.color_mode.options) != modes:
            self.color_mode.options = modes  # (keeps the chosen mode: every earlier mode is still offered)

    def _next_stage(self, finished: str) -> str:
        """The stage that runs after ``finished`` in this run's pipeline (engine/run/pipeline.py's order)."""
        pipeline = self.options.pipeline
        order = ["patchmatch", *(["confidence"] if pipeline in ("fast", "full") else []),
                 *(["refinement"] if pipeline == "full" else []), "fusion", *(["mesh"] if self.mesh else []),
                 "evaluation"]
        return order[order.index(finished) + 1] if finished in order[:-1] else "evaluation"

    # ---- worker side ---------------------------------------------------------------------------------
    def _render(self, _item: None) -> None:
        """Draw the newest snapshot of every view that has one waiting, then the panel; at most PUSH_HZ a second."""
        started = time.monotonic()
        with self._lock:
            pending, self._pending = self._pending, {}
            recolor, self._recolor = self._recolor, False
            fused, self._fused = self._fused, None
            progress = dataclasses.replace(self._progress, views_done=set(self._progress.views_done))
            confidence = dict(self._confidence)
        if self._released:
            return
        if recolor:  # every drawn view again, in the new colours
            for view, snapshot in list(self._drawn.items()):
                pending.setdefault(view, snapshot)
        for view, snapshot in sorted(pending.items()):
            self._draw(snapshot, confidence.get(view))
        if fused is not None:
            self._draw_fused(fused)
        self.progress.content = self._progress_text(progress)
        rest = 1.0 / PUSH_HZ - (time.monotonic() - started)
        if rest > 0:
            time.sleep(rest)

    def _draw(self, snapshot: _Snapshot, confidence: np.ndarray | None) -> None:
        view, depth = snapshot.view, snapshot.depth
        shape = depth.shape
        gt = self._level_gt.at(view, shape)
        error = depth_error(depth, gt) if gt is not None else None
        if error is not None:
            self._scores[view] = (snapshot.level, error.within, error.gt_pixels)
        step = max(1, int(np.ceil(max(shape) / self.max_size)))
        key = (view, shape)
        if key not in self._rays:
            self._rays[key] = _thinned_rays(self.scene.views[view].camera, shape, step)
        d = depth[::step, ::step]
        valid = d > 0
        camera = self.scene.views[view].camera
        points = camera.camera_to_world(self._rays[key][valid] * d[valid][:, None]).astype(np.float32)
        mode = str(self.color_mode.value)
        if mode == DEPTH_ERROR and error is not None:
            colors = colorize(error.rel[::step, ::step][valid] * 100, 0.0, DEPTH_ERROR_PCT, "RdYlGn_r")
            colors[np.isnan(error.rel[::step, ::step][valid])] = NO_DATA
        elif mode == "confidence" and confidence is not None:
            colors = colorize(_resampled(confidence, shape)[::step, ::step][valid], 0.0, 1.0, "viridis")
        elif mode in (DEPTH_ERROR, "confidence"):
            colors = np.tile(np.array(NO_DATA, np.uint8), (len(points), 1))
        else:
            colors = colorize(d[valid], self._depth_scale.vmin, self._depth_scale.vmax, "turbo")
        colors = colors.reshape(-1, 3)
        # one working-resolution pixel's footprint (add_cameras), times the level's and the thinning's factor
        self._footprint[view] = self.point_size * camera.width / shape[1] * step
        size = self._footprint[view] * float(self.live_point_size.value)
        handle = self._clouds.get(view)
        if handle is None:
            if not len(points):
                return  # nothing to draw yet (a view without estimates)
            self._clouds[view] = self.server.scene.add_point_cloud(
                f"/live/{view:03d}", points, colors=colors, point_size=size, precision="float32",
                visible=not self._fused_shown)
        else:
            with self.server.atomic():
                handle.points = points
                handle.colors = colors
                handle.point_size = size
        self._drawn[view] = snapshot
        self.pushes += 1

    def _draw_fused(self, cloud: Any) -> None:
        """The fused cloud in its colours in place of the per-view clouds, until the tuning viewer's."""
        keep = np.linspace(0, len(cloud) - 1, min(len(cloud), FUSED_MAX_POINTS)).astype(np.int64)
        # the kept points alone are read (a streamed cloud maps its file: no whole copy of it)
        self.server.scene.add_point_cloud("/fused", np.asarray(cloud.xyz[keep], np.float32),
                                          colors=np.asarray(cloud.rgb[keep], np.uint8),
                                          point_size=self.point_size, precision="float32")
        self._fused_shown = True
        for handle in self._clouds.values():
            handle.visible = False

    def within_so_far(self, level: int) -> tuple[float, int] | None:
        """(percent of the GT pixels within 1 %, views) pooled over the views last drawn at ``level``;
        None before any view with GT depth is."""
        scores = [(w, n) for lv, w, n in self._scores.values() if lv == level]
        if not scores:
            return None
        return 100.0 * sum(w for w, _ in scores) / max(1, sum(n for _, n in scores)), len(scores)

    def _progress_text(self, p: _Progress) -> str:
        n = len(self.scene.views)
        elapsed = f"{time.monotonic() - self._start:,.1f} s"
        if p.stage == "starting":
            return f"**starting…** · {elapsed}"
        eta = self.eta.text() if self.eta is not None else ""
        eta = f" · whole run: **{eta}**" if eta else ""
        if p.stage != "patchmatch":
            return f"**PatchMatch done** · now: **{STAGE_NAMES.get(p.stage, p.stage)}** · {elapsed}{eta}"
        passes = 1 + self.options.patchmatch.geom_passes
        size = f" ({p.shape[1]}×{p.shape[0]})" if p.shape else ""
        iterations = f"/{p.pass_iterations}" if p.pass_iterations else ""
        done = f"{len(p.views_done)} of {plural(n, 'view')} done in this pass"
        if p.view is not None and p.view < n:
            step = f"iteration {p.iteration + 1}{iterations}"
            view = f"view {p.view}: {self.scene.views[p.view].name} · {done}"
        else:  # a pass has started and no view has reported an iteration of it yet
            step, view = "starting", f"first view to come · {done}"
        lines = [f"**PatchMatch** · level {p.level}{size} (levels {p.coarsest} → 0, 0 = finest)",
                 f"{p.pass_kind} pass {p.pass_index + 1} of {passes} · {step}", view]
        within = self.within_so_far(p.level) if p.level is not None else None
        if within is not None:
            lines.append(f"within 1 % of GT so far: **{within[0]:.1f} %** of the GT pixels (level {p.level}, "
                         f"{plural(within[1], 'view')})")
        elif self.has_gt:
            lines.append("within 1 % of GT: after the first view")
        lines.append(elapsed + eta)
        return "  \n".join(lines)

    # ---- hand-over and lifecycle -----------------------------------------------------------------------
    def wait_idle(self, timeout: float = 30.0) -> bool:
        """Block until every snapshot handed over so far is drawn (tests and benchmarks); False on timeout."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self._lock:
                waiting = bool(self._pending) or self._recolor or self._fused is not None
            if not waiting and self._worker.idle():
                return True
            time.sleep(0.02)
        return False

    def hand_over(self) -> Any:
        """The run ended: stop drawing, say so, and give the server to the tuning viewer
        (``workbench.viewer.app.serve(..., server=..., on_open=live.release)``, which stops it in the end)."""
        self._worker.stop(STOP_TIMEOUT_S)
        self._handed_over = True
        self.progress.content = "**run finished** · opening the tuning viewer of the run…"
        return self.server

    def release(self, _app: Any = None) -> None:
        """The tuning viewer is up on this server: remove the live clouds and the progress panel."""
        self._released = True
        self._worker.stop(STOP_TIMEOUT_S)
        with self.server.atomic():
            for handle in self._clouds.values():
                handle.remove()
            for handle in self._panel:
                handle.remove()
        self._clouds.clear()

    def stop(self) -> None:
        """Stop the worker and, unless the tuning viewer took it over, the server (idempotent)."""
        if self._stopped:
            return
        self._stopped = True
        self._worker.stop(STOP_TIMEOUT_S)
        if not self._handed_over:
            self.server.stop()


def start_live_viewer(scene: Scene, options: PipelineOptions, host: str = "127.0.0.1", port: int = 8080,
                      mesh: bool = False) -> LiveViewer:
    """A :class:`LiveViewer` serving on host:port, announced in one line (and one more for a busy port)."""
    live = LiveViewer(scene, options, host, port, mesh)
    announce("live 3-D viewer", host, port, live.port, "becomes the tuning viewer when the run ends")
    return live
