"""The live-tuning browser viewer (viser): ``deepc view OUT_OR_SCENE``.

Camera frustums with their images, the fused cloud coloured by RGB / confidence / supporting views /
error against GT, and a panel to tune the pipeline, the confidence threshold, mask-k and the fusion
thresholds. A change answers at once with a preview (the unfiltered cloud masked by per-point
attributes) and the exact recomputation follows from a worker thread; only stages downstream of the
change are recomputed (``workbench/session.py``). The GUI thread never computes. All browser tabs
share one session. Binds 127.0.0.1 unless told otherwise.
"""

from __future__ import annotations

import dataclasses
import math
import re
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import viser
from viser.transforms import SO3

from engine.fusion import FUSION_PRESETS, FusionOptions
from engine.io.ply import write_ply
from workbench.session import COLOR_MODES, ViewerSession, ViewParams, describe
from workbench.stream import subsample

THUMBNAIL = 160  # longest side of the images sent with the frustums
PREVIEW_MAX_POINTS = 150_000  # previews are approximate anyway; the exact cloud follows
# The exact cloud is scored and exported in full but drawn with at most this many points (an even stride):
# a per-pixel cloud of fountain_p11 at 768 px has 3.4 M points, 50 MB a push to every tab.
DISPLAY_MAX_POINTS = 1_000_000
DELIVERY_WAIT_S = 1.0  # longest a preview waits for the previous cloud to leave for every client
EXACT_QUIET_S = 0.15  # the exact recomputation starts once the controls have been still this long...
EXACT_MAX_DELAY_S = 3.0  # ...or when its request has waited this long (a user who never lets go)
CUSTOM = "custom"  # the fusion preset dropdown's entry for slider values no preset has


def _even_stride(total: int, count: int) -> np.ndarray:
    """(count,) int64 indices spread evenly over range(total): the cloud's shape and density pattern stay."""
    return np.linspace(0, total - 1, count).astype(np.int64)


def _shown_note(total: int) -> str:
    return f" ({DISPLAY_MAX_POINTS:,} drawn)" if total > DISPLAY_MAX_POINTS else ""


# The FusionOptions fields the Fusion panel controls, each with the type its widget's value converts to.
FUSION_CONTROLS = {"max_reproj_error": float, "max_depth_error": float, "max_normal_error": float,
                   "min_num_pixels": int, "point_per_pixel": bool}


def preset_of(fusion: FusionOptions) -> str:
    """Name of the preset whose controlled fields (``FUSION_CONTROLS``) ``fusion`` has, else ``CUSTOM``."""
    for name in sorted(FUSION_PRESETS):
        p = FUSION_PRESETS[name]
        if all(math.isclose(getattr(p, field), getattr(fusion, field), abs_tol=1e-9) for field in FUSION_CONTROLS):
            return name
    return CUSTOM


def safe_file_name(text: str, suffix: str) -> str:
    """A file name made only of [A-Za-z0-9._-], never a path: names from the GUI cannot escape the folder."""
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", Path(text).name).strip("._") or "export"
    return stem[:80] + suffix


class _LatestOnly:
    """Calls ``fn`` for the newest arguments only, one call at a time.

    GUI events arrive faster than a preview can be pushed to every client (50 per second from five tabs):
    running each on viser's thread pool queued them without bound, so latency and memory grew with the
    load. Here a call that arrives while ``fn`` runs only replaces the arguments waiting for the next run.
    """

    def __init__(self, fn):
        self._fn = fn
        self._running = threading.Lock()
        self._swap = threading.Lock()
        self._next: tuple | None = None

    def __call__(self, *args) -> None:
        with self._swap:
            self._next = args
        while True:
            if not self._running.acquire(blocking=False):
                return  # the running call picks our arguments up when it finishes
            try:
                with self._swap:
                    args, self._next = self._next, None
                if args is not None:
                    self._fn(*args)
            finally:
                self._running.release()
            with self._swap:
                if self._next is None:
                    return


class ViewerApp:
    """The viser server, its GUI and the worker that recomputes exact results."""

    def __init__(self, session: ViewerSession, host: str = "127.0.0.1", port: int = 8080, verbose: bool = False):
        self.session = session
        self.server = viser.ViserServer(host=host, port=port, verbose=verbose)
        self.port = self.server.get_port()
        self.host = host
        self._pending: ViewParams | None = None
        self._generation = 0  # bumped by every request
        self._last_request = 0.0  # time.monotonic() of the last request
        self._done_generation = 0  # last generation whose exact cloud and scores are shown
        self._cond = threading.Condition()
        self._stopping = False
        self._state_lock = threading.Lock()
        self.cloud = None
        self.cloud_params: ViewParams | None = None
        self._cloud_message_id = -1  # broadcast-buffer id of the last cloud push (see _wait_for_delivery)
        self._base_colors_cache: tuple | None = None  # (base cloud, colour mode, colours)
        self._selected_view = 0
        self._recolor_latest = _LatestOnly(self._recolor)
        # Previews run on their own thread, newest request wins: in viser's callback thread a preview that
        # waits for the previous cloud to leave would hold up the next events themselves.
        self._preview_cond = threading.Condition()
        self._preview_args: tuple | None = None
        self._previewing = False
        self._exact_generation = 0  # newest generation whose exact cloud is shown: older previews must not cover it
        self._build_scene()
        self._build_gui()
        self._worker = threading.Thread(target=self._work, name="deepc-viewer-worker", daemon=True)
        self._worker.start()
        self._previewer = threading.Thread(target=self._preview_loop, name="deepc-viewer-preview", daemon=True)
        self._previewer.start()
        if session.has_maps:
            self.request(self.params())

    # ---- scene ----------------------------------------------------------------------------------
    def _build_scene(self) -> None:
        scene = self.session.scene
        depths = [np.mean(v.depth_range) for v in scene.views]
        centers = np.stack([v.camera.center for v in scene.views])
        spread = float(np.median(np.linalg.norm(centers - centers.mean(axis=0), axis=1))) or 1.0
        self.frustum_scale = 0.07 * spread
        # about one pixel footprint at a typical depth
        self.default_point_size = float(np.median(depths) * 0.5 / np.median([v.camera.fx for v in scene.views]))
        self.server.scene.set_up_direction("-y")
        first = scene.views[0].camera
        home_position = first.center - first.R[2] * 0.2 * float(np.median(depths))
        home_target = first.center + first.R[2] * float(np.median(depths))

        @self.server.on_client_connect
        def _(client: viser.ClientHandle) -> None:
            # Start behind the first camera, looking where it looks, its image "up" on screen.
            client.camera.position = home_position
            client.camera.look_at = home_target
            client.camera.up_direction = -first.R[1]
        self.frustums = []
        for v in scene.views:
            cam = v.camera
            fov = 2 * np.arctan2(cam.height / 2, cam.fy)
            image = (np.asarray(scene.image(v.index)) * 255 + 0.5).astype(np.uint8)
            frustum = self.server.scene.add_camera_frustum(
                f"/cameras/{v.index:03d}", fov=float(fov), aspect=cam.width / cam.height, scale=self.frustum_scale,
                image=subsample(image, THUMBNAIL), format="jpeg", wxyz=SO3.from_matrix(cam.R.T).wxyz,
                position=cam.center, color=(60, 60, 200))
            frustum.on_click(lambda event, i=v.index: self.select_view(i))
            self.frustums.append(frustum)
        if not self.session.has_maps and len(scene.model.points):
            self.server.scene.add_point_cloud("/sparse", scene.model.points.astype(np.float32),
                                              colors=(200, 120, 30), point_size=self.default_point_size * 3,
                                              precision="float32")
        self.cloud_handle = None

    # ---- GUI --------------------------------------------------------------------------------------
    def _build_gui(self) -> None:
        gui = self.server.gui
        s = self.session
        defaults = ViewParams()
        gui.add_markdown(f"**DeepC Workbench** · {s.scene.name} · {len(s.scene.views)} views")
        with gui.add_folder("Pipeline"):
            self.pipeline = gui.add_dropdown("Pipeline", options=tuple(s.pipelines or ["vanilla"]),
                                             initial_value=(s.pipelines or ["vanilla"])[0],
                                             disabled=len(s.pipelines) <= 1)
            self.conf_tau = gui.add_slider("Confidence τ", min=0.0, max=1.0, step=0.01,
                                           initial_value=defaults.conf_tau, disabled=not s.has_confidence,
                                           hint="keep pixels with confidence ≥ τ (fast and full pipelines)")
            self.mask_k = gui.add_slider("Mask k", min=0, max=10, step=1, initial_value=0,
                                         disabled=not s.has_counter,
                                         hint="keep pixels with ≥ k consistent source views (0 = off)")
        with gui.add_folder("Fusion"):
            f = defaults.fusion
            self.preset = gui.add_dropdown("Preset", options=(*sorted(FUSION_PRESETS), CUSTOM),
                                           initial_value=preset_of(f),
                                           hint="named thresholds (pixels = what deepc run fuses with; dense = "
                                                "one median point per cluster, lighter to tune; deepc = the "
                                                "paper's); moving a control makes it custom")
            self.reproj = gui.add_slider("Reprojection error (px)", min=0.25, max=4.0, step=0.25,
                                         initial_value=f.max_reproj_error)
            self.depth_err = gui.add_slider("Depth error (rel.)", min=0.001, max=0.05, step=0.001,
                                            initial_value=f.max_depth_error)
            self.normal_err = gui.add_slider("Normal angle (°)", min=1.0, max=90.0, step=1.0,
                                             initial_value=f.max_normal_error)
            self.min_views = gui.add_slider("Min views", min=1, max=10, step=1, initial_value=f.min_num_pixels,
                                            hint="fewest fused pixels per point, the seed included")
            self.per_pixel = gui.add_checkbox("Point per pixel", initial_value=f.point_per_pixel,
                                              hint="every pixel of a kept cluster is a point (else the cluster's "
                                                   "median is one point)")
            self._fusion_handles = dict(zip(FUSION_CONTROLS, (self.reproj, self.depth_err, self.normal_err,
                                                              self.min_views, self.per_pixel), strict=True))
        with gui.add_folder("Display"):
            self.point_size = gui.add_slider("Point size", min=self.default_point_size / 10,
                                             max=self.default_point_size * 10, step=self.default_point_size / 10,
                                             initial_value=self.default_point_size)
            self.color_mode = gui.add_dropdown("Colour", options=COLOR_MODES, initial_value="rgb")
        with gui.add_folder("Metrics"):
            self.metrics = gui.add_markdown("computing…" if s.has_maps else
                                            "no maps: run `deepc run` and open its output folder")
        with gui.add_folder("Export"):
            self.export_name = gui.add_text("File name", initial_value="cloud")
            self.export_button = gui.add_button("Export cloud (PLY)", disabled=not s.has_maps)
            self.rrd_button = gui.add_button("Save state (.rrd)", disabled=not s.has_maps)
            self.export_status = gui.add_markdown("")
        with gui.add_folder("View"):
            self.view_title = gui.add_markdown("")
            self.view_images: dict[str, Any] = {}
            for kind, image in s.view_images(0).items():
                self.view_images[kind] = gui.add_image(subsample(image, 320), label=kind, format="jpeg")
        self.select_view(0)

        self._applying_preset = False
        for handle in (self.pipeline, self.conf_tau, self.mask_k):
            handle.on_update(lambda _event: self.request(self.params()))
        for handle in self._fusion_handles.values():
            handle.on_update(lambda _event: self._fusion_slider_moved())
        self.preset.on_update(lambda _event: self._apply_preset())
        self.color_mode.on_update(lambda _event: self._recolor_latest())
        self.point_size.on_update(lambda _event: self._set_point_size())
        self.export_button.on_click(lambda _event: self.export_ply())
        self.rrd_button.on_click(lambda _event: self.save_rrd())

    def _apply_preset(self) -> None:
        """Set the fusion controls to the chosen preset; one recomputation, not five."""
        if self._applying_preset or self.preset.value == CUSTOM:
            return
        f = FUSION_PRESETS[str(self.preset.value)]
        self._applying_preset = True
        try:
            for field, handle in self._fusion_handles.items():
                handle.value = getattr(f, field)
        finally:
            self._applying_preset = False
        self.request(self.params())

    def _fusion_slider_moved(self) -> None:
        if self._applying_preset:
            return
        name = preset_of(self.params().fusion)
        if self.preset.value != name:
            self._applying_preset = True  # the dropdown only names the sliders' state here
            try:
                self.preset.value = name
            finally:
                self._applying_preset = False
        self.request(self.params())

    def params(self) -> ViewParams:
        fusion = ViewParams().fusion.replace(**{field: FUSION_CONTROLS[field](handle.value)
                                                for field, handle in self._fusion_handles.items()})
        return ViewParams(pipeline=str(self.pipeline.value), conf_tau=float(self.conf_tau.value),
                          mask_k=int(self.mask_k.value), fusion=fusion)

    # ---- updates ----------------------------------------------------------------------------------
    def request(self, params: ViewParams) -> None:
        """Show a preview now (when the base cloud is ready) and queue the exact recomputation."""
        if not self.session.has_maps:
            return
        with self._cond:
            self._generation += 1
            generation = self._generation
            self._last_request = time.monotonic()
        with self._preview_cond:
            self._preview_args = (params, generation)
            self._preview_cond.notify()
        with self._cond:
            if generation == self._generation:  # else a newer request is queued instead
                self._pending = params
                self._cond.notify()

    def _preview_loop(self) -> None:
        while True:
            with self._preview_cond:
                while self._preview_args is None and not self._stopping:
                    self._preview_cond.wait()
                if self._stopping:
                    return
                args, self._preview_args = self._preview_args, None
                self._previewing = True
            try:
                self._preview(*args)
            except Exception as exc:  # the viewer must survive any one bad preview
                self.metrics.content = f"**error:** {' '.join(str(exc).split())}"
            finally:
                with self._preview_cond:
                    self._previewing = False

    def _preview(self, params: ViewParams, generation: int) -> None:
        self._wait_for_delivery()
        if generation != self._generation:
            return  # a newer request came in: its own preview follows
        exact = self.session.cached_cloud(params)
        if exact is not None:  # computed before: show the exact result now rather than after the worker
            self._show(exact, params, preview=False, scores=self.session.cached_scores(params), generation=generation)
            return
        base, own = self.session.nearest_base_cloud(params)
        if base is None:  # nothing to mask yet: say what is coming
            self.metrics.content = "**fusing…**  \nexact result follows"
            return
        keep = np.flatnonzero(ViewerSession.preview_mask(base, params))
        total = len(keep)
        if total > PREVIEW_MAX_POINTS:
            keep = keep[_even_stride(total, PREVIEW_MAX_POINTS)]
        colors = self._base_colors(base)[keep]
        self._show(base.subset(keep), params, preview=True, count=total, colors=colors, stale_fusion=not own,
                   generation=generation)

    def _base_colors(self, base) -> np.ndarray:
        """Colours of the whole base cloud, cached: previews only index them (the error colours need a
        nearest-GT query that takes longer than a preview may)."""
        mode = str(self.color_mode.value)
        cached = self._base_colors_cache
        if cached is None or cached[0] is not base or cached[1] != mode:
            cached = self._base_colors_cache = (base, mode, self.session.colors(base, mode))
        return cached[2]

    def _wait_for_delivery(self) -> None:
        """Block until every connected client has taken the last cloud push off the broadcast buffer.

        viser drops a queued update when a newer one of the same property arrives, but not the one a
        client is already sending: under 50 events per second from five tabs the clouds in flight, not
        the computation, set the latency. Waiting here (newer events meanwhile replace this preview's
        arguments) keeps at most one cloud in flight per client."""
        buffer = self.server._websock_server.get_message_buffer()  # viser 1.1 internals, checked in a test
        deadline = time.monotonic() + DELIVERY_WAIT_S
        while time.monotonic() < deadline and self._cloud_message_id >= 0:
            cursors = list(buffer.generator_cursors.values())
            if all(cursor >= self._cloud_message_id for cursor in cursors):
                return
            time.sleep(0.005)

    def _work(self) -> None:
        while True:
            with self._cond:
                while self._pending is None and not self._stopping:
                    self._cond.wait()
                # While a slider is being dragged the previews answer; an exact result for a value already
                # left behind would only take the CPU from them.
                overdue = time.monotonic() + EXACT_MAX_DELAY_S
                while not self._stopping:
                    wait = min(self._last_request + EXACT_QUIET_S, overdue) - time.monotonic()
                    if wait <= 0:
                        break
                    self._cond.wait(wait)
                if self._stopping:
                    return
                params, generation = self._pending, self._generation
                self._pending = None
            try:
                self.session.base_cloud(params)  # makes later previews possible
                cloud = self.session.cloud(params)
                if generation != self._generation:
                    continue  # a newer request is queued: skip the stale push
                if self.cloud is not cloud:  # (the preview may have shown this cached cloud already)
                    self._show(cloud, params, preview=False, generation=generation)
                scores = self.session.evaluate(params, cloud)
                if generation == self._generation:
                    self.metrics.content = self._metrics_text(cloud, scores)
            except Exception as exc:  # the viewer must survive any one bad computation
                self.metrics.content = f"**error:** {' '.join(str(exc).split())}"
            self._done_generation = generation

    def _metrics_text(self, cloud, scores, preview: bool = False, count: int | None = None,
                      stale_fusion: bool = False) -> str:
        if preview:
            total = len(cloud) if count is None else count
            shown = "" if total == len(cloud) else f", {len(cloud):,} shown"
            fusion = ", previous fusion thresholds" if stale_fusion else ""
            return f"**{total:,} points** (preview{shown}{fusion})  \nexact result follows…"
        return f"**{len(cloud):,} points**{_shown_note(len(cloud))}  \n{describe(scores)}"

    def _show(self, cloud, params: ViewParams, preview: bool, count: int | None = None,
              colors: np.ndarray | None = None, scores: dict | None = None, stale_fusion: bool = False,
              generation: int | None = None) -> None:
        drawn = cloud
        if not preview and len(cloud) > DISPLAY_MAX_POINTS:
            keep = _even_stride(len(cloud), DISPLAY_MAX_POINTS)
            drawn = cloud.subset(keep)
            colors = None if colors is None else colors[keep]
        if colors is None:  # outside the lock: the error colours take a nearest-GT query that previews must not wait on
            colors = self.session.colors(drawn, str(self.color_mode.value))
        points = np.asarray(drawn.xyz, np.float32)
        with self._state_lock:
            if generation is not None:
                if preview and generation <= self._exact_generation:
                    return  # the exact result of this or a newer request is already shown
                if not preview:
                    self._exact_generation = max(self._exact_generation, generation)
            with self.server.atomic():
                if self.cloud_handle is None:
                    self.cloud_handle = self.server.scene.add_point_cloud(
                        "/fused", points, colors=colors, point_size=float(self.point_size.value),
                        precision="float32")
                else:
                    self.cloud_handle.points = points
                    self.cloud_handle.colors = colors
                if preview:
                    self.metrics.content = self._metrics_text(cloud, None, preview=True, count=count,
                                                              stale_fusion=stale_fusion)
                elif scores is not None or not self.session.has_gt:
                    self.metrics.content = self._metrics_text(cloud, scores)
                else:
                    self.metrics.content = f"**{len(cloud):,} points**{_shown_note(len(cloud))}  \nscoring…"
                self._cloud_message_id = self.server._websock_server.get_message_buffer().message_counter - 1
            self.cloud, self.cloud_params = cloud, params

    def _recolor(self) -> None:
        if self.cloud is not None:
            self._show(self.cloud, self.cloud_params, preview=False)
            scores = self.session.evaluate(self.cloud_params, self.cloud) if self.cloud_params else None
            self.metrics.content = self._metrics_text(self.cloud, scores)

    def _set_point_size(self) -> None:
        if self.cloud_handle is not None:
            self.cloud_handle.point_size = float(self.point_size.value)

    def select_view(self, index: int) -> None:
        """Show view ``index``'s image and maps in the side panel (also on a frustum click)."""
        self._selected_view = index
        view = self.session.scene.views[index]
        self.view_title.content = f"**view {index}: {view.name}**  \nsources: {view.source_views}"
        for kind, image in self.session.view_images(index).items():
            if kind in self.view_images:
                self.view_images[kind].image = subsample(image, 320)
        for i, frustum in enumerate(self.frustums):
            frustum.color = (230, 60, 40) if i == index else (60, 60, 200)

    # ---- exports ----------------------------------------------------------------------------------
    def _export_dir(self) -> Path:
        base = self.session.out_dir or Path.cwd()
        return base / "exports"

    def export_ply(self, name: str | None = None) -> Path | None:
        """Write the current cloud to OUT/exports/<sanitised name>.ply."""
        if self.cloud is None:
            return None
        path = self._export_dir() / safe_file_name(name or str(self.export_name.value), ".ply")
        c = self.cloud
        write_ply(path, np.asarray(c.xyz), c.normal, c.rgb, extra={"num_views": c.num_views.astype(np.int32)})
        self.export_status.content = f"wrote `{path}` ({len(c):,} points)"
        return path

    def save_rrd(self, name: str | None = None) -> Path | None:
        """Save cameras, the selected view's maps and the current cloud as OUT/exports/<name>.rrd."""
        if self.cloud is None:
            return None
        import rerun as rr

        from workbench.recording import Recording
        from workbench.stream import RerunStream

        path = self._export_dir() / safe_file_name(name or str(self.export_name.value), ".rrd")
        recording = Recording(path)
        try:
            scene = self.session.scene
            views = [(v.name, v.camera, scene.image(v.index), v.source_views) for v in scene.views]
            stream = RerunStream(recording.rec, views)
            stream.log_cloud(str(self.cloud_params.pipeline), np.asarray(self.cloud.xyz, np.float32), self.cloud.rgb,
                             radius=float(self.point_size.value) / 2)
            for kind, image in self.session.view_images(self._selected_view).items():
                stream.log_view_map(self._selected_view, kind, image)
            recording.rec.log("params", rr.TextDocument(str(dataclasses.asdict(self.cloud_params))), static=True)
        except BaseException:
            recording.abandon()
            raise
        recording.finish()
        self.export_status.content = f"wrote `{path}`"
        return path

    # ---- lifecycle ----------------------------------------------------------------------------------
    def wait_idle(self, timeout: float = 60.0) -> bool:
        """Block until no recomputation is pending or running (for tests and benchmarks)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self._cond, self._preview_cond:
                if (self._pending is None and self._done_generation == self._generation
                        and self._preview_args is None and not self._previewing):
                    return True
            time.sleep(0.02)
        return False

    def stop(self) -> None:
        with self._cond:
            self._stopping = True
            self._cond.notify_all()
        with self._preview_cond:
            self._preview_cond.notify_all()
        self._worker.join(timeout=10)
        self._previewer.join(timeout=10)
        self.server.stop()


def serve(path: str, host: str = "127.0.0.1", port: int = 8080) -> None:
    """Open a session and serve until interrupted (``deepc view``)."""
    session = ViewerSession.open(path)
    app = ViewerApp(session, host=host, port=port, verbose=False)
    print(f"viewer: http://{host}:{app.port}  (Ctrl+C to stop)", flush=True)
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        app.stop()
