"""The live-tuning browser viewer (viser): ``deepc view OUT_OR_SCENE``.

Camera frustums with their images, the fused cloud coloured by RGB / confidence / supporting views /
error against GT, and a panel to tune the pipeline, the confidence threshold, mask-k and the fusion
thresholds. A change answers at once with a preview (the unfiltered cloud masked by per-point
attributes) and the exact recomputation follows from a worker thread; only stages downstream of the
change are recomputed (``workbench/viewer/session.py``). The GUI thread never computes. All browser tabs
share one session. Binds 127.0.0.1 unless told otherwise.

A run opens on its own pipeline, thresholds and fusion options (from its metrics.json), named at the top
with a button back to them; the metrics compare every tolerance with the run's and with the previous
setting. Controls that cannot act are disabled and say why, previews say they are approximate, every
colour mode and map has a legend with its unit (``workbench/viewer/legends.py``), and the View folder shows
the selected view's maps as the current pipeline and filters use them.

The browser gets at most the point budget (Display folder, ``POINT_BUDGET`` by default): a larger cloud is sent
voxel-thinned (``engine/core/thinning.py``) and a note says so; scores, exports and meshes use every point.

The controls are declared in ``workbench/viewer/panel.py``, the newest-request-wins scheduling of previews
and recomputations is ``workbench/viewer/scheduler.py``, the Export panel's files ``workbench/viewer/export.py`` and
the pixel inspector with its region re-run ``workbench/viewer/inspector.py``.
"""

from __future__ import annotations

import contextlib
import io
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import viser
from viser.transforms import SO3

from engine.core.errors import DeepCError
from engine.core.thinning import VoxelThinning, thin_to_budget, voxel_thinning
from engine.fusion import FusedCloud
from engine.scene import Scene
from workbench.maps.images import subsample
from workbench.viewer.export import safe_file_name, write_cloud_ply, write_state_rrd
from workbench.viewer.inspector import InspectorPanel
from workbench.viewer.legends import metrics_html
from workbench.viewer.mesh import MeshPanel
from workbench.viewer.panel import PANEL_IMAGE, ControlPanel, preset_of, view_label
from workbench.viewer.scheduler import LatestOnly, RecomputeScheduler
from workbench.viewer.session import ViewerSession, ViewParams, describe

# preset_of is imported from here by benchmarks/bench_viewer.py
__all__ = ["POINT_BUDGET", "ViewerApp", "preset_of", "serve"]

THUMBNAIL = 160  # longest side of the images sent with the frustums
# The browser gets at most this many points (the Display folder's "Point budget" changes it): above it the cloud
# is voxel-thinned (engine/core/thinning.py). Scores, exports and meshes use every point. Sample small's 458 k
# points took 7-22 s a change in chromium's software WebGL, tiny's 77 k 0.15 s (issue 47; docs/decisions.md,
# "Viewer: at most 200 000 points and 200 000 triangles to the browser").
POINT_BUDGET = 200_000
MIN_POINT_BUDGET = 1_000  # the control's minimum
THIN_CACHE = 4  # voxel grids of base clouds (which previews mask) kept, and as many exact clouds' sent points
DELIVERY_WAIT_S = 1.0  # longest a preview waits for the previous cloud to leave for every client
EXACT_QUIET_S = 0.15  # the exact recomputation starts once the controls have been still this long...
EXACT_MAX_DELAY_S = 3.0  # ...or when its request has waited this long (a user who never lets go)


def thinned_note(total: int, sent: int, voxel: float, budget: int) -> str:
    """What the browser got of a cloud of ``total`` points: all of them, or ``sent`` thinned to one per voxel of
    edge ``voxel`` (model units, metres: shown in mm) under the point budget."""
    # (the metrics above say "N points": the note does not repeat it, a page has one "N points" text)
    if sent >= total:
        return f"whole cloud sent: all {total:,} (point budget {budget:,})"
    return (f"**cloud thinned** for the browser: {sent:,} sent of {total:,}, one per {voxel * 1000:.3g} mm voxel "
            f"(point budget {budget:,}); scores, export and mesh use every point")


def set_home_camera(server: viser.ViserServer, scene: Scene) -> None:
    """Every client that connects starts behind the first camera, looking where it looks, its image "up" on
    screen, and "Reset View" returns there (viser's initial camera; the connect handler also moves clients
    already connected: register it once per server)."""
    depth = float(np.median([np.mean(v.depth_range) for v in scene.views]))
    first = scene.views[0].camera
    home_position = first.center - first.R[2] * 0.2 * depth
    home_target = first.center + first.R[2] * depth
    # a client that connects later takes its first pose from here, before any handler could move it
    server.initial_camera.position = home_position
    server.initial_camera.look_at = home_target
    server.initial_camera.up = -first.R[1]

    @server.on_client_connect
    def _(client: viser.ClientHandle) -> None:
        client.camera.position = home_position
        client.camera.look_at = home_target
        client.camera.up_direction = -first.R[1]


def add_cameras(server: viser.ViserServer, scene: Scene) -> tuple[list, float, float]:
    """Draw every view as a frustum with its thumbnail under ``/cameras/<index>`` (drawing them again
    replaces them). Returns (frustum handles, frustum scale, default point size): the frustums are 7 % of the
    cameras' median spread from their centroid, the point size about one pixel's footprint at a typical depth
    (model units)."""
    server.scene.set_up_direction("-y")
    depths = [np.mean(v.depth_range) for v in scene.views]
    centers = np.stack([v.camera.center for v in scene.views])
    spread = float(np.median(np.linalg.norm(centers - centers.mean(axis=0), axis=1))) or 1.0
    frustum_scale = 0.07 * spread
    point_size = float(np.median(depths) * 0.5 / np.median([v.camera.fx for v in scene.views]))
    frustums = []
    for v in scene.views:
        cam = v.camera
        fov = 2 * np.arctan2(cam.height / 2, cam.fy)
        image = (np.asarray(scene.image(v.index)) * 255 + 0.5).astype(np.uint8)
        frustums.append(server.scene.add_camera_frustum(
            f"/cameras/{v.index:03d}", fov=float(fov), aspect=cam.width / cam.height, scale=frustum_scale,
            image=subsample(image, THUMBNAIL), format="jpeg", wxyz=SO3.from_matrix(cam.R.T).wxyz,
            position=cam.center, color=(60, 60, 200)))
    return frustums, frustum_scale, point_size


class ViewerApp(ControlPanel):
    """The viser server, its scene and GUI (:class:`ControlPanel`), and the scheduled recomputations.

    Every change of the controls is a request to a :class:`RecomputeScheduler`: a preview thread masks
    the nearest cached base cloud at once, and a worker thread computes the exact cloud once the controls
    have been still for ``EXACT_QUIET_S``; results of superseded requests are dropped.
    """

    def __init__(self, session: ViewerSession, host: str = "127.0.0.1", port: int = 8080, verbose: bool = False,
                 server: viser.ViserServer | None = None):
        """``server``: an already running viser server to take over (the live viewer of ``deepc run``, whose
        clients stay connected and keep their camera); without it the app starts its own on host:port."""
        self.session = session
        self.point_budget_default, self.point_budget_min = POINT_BUDGET, MIN_POINT_BUDGET
        own_server = server is None
        self.server = viser.ViserServer(host=host, port=port, verbose=verbose) if server is None else server
        self.port = self.server.get_port()
        self.host = host
        self._state_lock = threading.Lock()
        self.cloud = None
        self.cloud_params: ViewParams | None = None
        self._cloud_message_id = -1  # broadcast-buffer id of the last cloud push (see _wait_for_delivery)
        self._base_colors_cache: tuple | None = None  # (base cloud, colour mode, colours)
        self.selected_view = 0
        self._recolor_latest = LatestOnly(self._recolor)
        self._exact_generation = 0  # newest generation whose exact cloud is shown: older previews must not cover it
        self._scored: tuple | None = None  # (params, scores) of the newest exact result shown with its scores
        self._previous_scored: tuple | None = None  # ...and of the setting before it (the "previous" column)
        self._refresh_view_latest = LatestOnly(self._refresh_view)
        self._last_preview: tuple | None = None  # (params, point count) of the newest preview shown
        self._thin_lock = threading.Lock()
        self._thinnings: list[tuple[FusedCloud, int, VoxelThinning]] = []  # newest last, THIN_CACHE at most
        self._selections: list[tuple[FusedCloud, int, np.ndarray, float]] = []  # exact clouds' sent points, likewise
        self._sent: tuple | None = None  # (cloud, points sent, voxel) of the cloud drawn now
        # Previews run on their own thread: in viser's callback thread a preview that waits for the previous
        # cloud to leave would hold up the next events themselves.
        self._scheduler: RecomputeScheduler[ViewParams] = RecomputeScheduler(
            self._preview, self._exact, self._show_error, EXACT_QUIET_S, EXACT_MAX_DELAY_S, name="deepc-viewer")
        self._build_scene(home=own_server)
        self._build_gui()
        self.mesh_panel = MeshPanel(self)
        self.inspector = InspectorPanel(self)  # click a point or a pixel: its PatchMatch trace
        if session.has_maps:
            self.request(self.params())
        self.mesh_panel.preload()

    # ---- scene ----------------------------------------------------------------------------------
    def _build_scene(self, home: bool = True) -> None:
        scene = self.session.scene
        if home:
            set_home_camera(self.server, scene)
        self.frustums, self.frustum_scale, self.default_point_size = add_cameras(self.server, scene)
        for view, frustum in zip(scene.views, self.frustums, strict=True):
            frustum.on_click(lambda event, i=view.index: self.select_view(i))
        if not self.session.has_maps and len(scene.model.points):
            self.server.scene.add_point_cloud("/sparse", scene.model.points.astype(np.float32),
                                              colors=(200, 120, 30), point_size=self.default_point_size * 3,
                                              precision="float32")
        self.cloud_handle = None

    # ---- updates ----------------------------------------------------------------------------------
    def request(self, params: ViewParams) -> None:
        """Show a preview now (when the base cloud is ready) and queue the exact recomputation."""
        if self.session.has_maps:
            self._scheduler.request(params)

    def _show_error(self, exc: Exception) -> None:
        """The viewer survives any one bad preview or computation: it says what went wrong instead."""
        self.metrics.content = f"**error:** {' '.join(str(exc).split())}"

    def _preview(self, params: ViewParams, generation: int) -> None:
        self.histograms.content = "".join(self.session.histograms(params))  # the thresholds move at once
        self._wait_for_delivery()
        if not self._scheduler.is_current(generation):
            return  # a newer request came in: its own preview follows
        exact = self.session.cached_cloud(params)
        if exact is not None:  # computed before: show the exact result now rather than after the worker
            self._show(exact, params, preview=False, scores=self.session.cached_scores(params), generation=generation)
            return
        base, own = self.session.nearest_base_cloud(params)
        if base is None:  # nothing to mask yet: say what is coming
            self.metrics.content = "**fusing…**  \nexact result follows"
            self.metrics_table.content = ""
            return
        mask = ViewerSession.preview_mask(base, params)  # on the whole base cloud: its count is the preview's
        total = int(np.count_nonzero(mask))
        budget = self.budget()
        # over the budget: the masked points of the base cloud's voxel grid (built once per base cloud by the
        # exact worker), one per voxel; a linear pass, no search
        thinning = self._thinning(base, budget) if total > budget else None
        keep = np.flatnonzero(mask) if thinning is None else thinning.select(mask)
        colors = self._base_colors(base)[keep]
        self._show(base.subset(keep), params, preview=True, count=total, colors=colors, stale_fusion=not own,
                   generation=generation, voxel=0.0 if thinning is None else thinning.voxel)

    def budget(self) -> int:
        """The point budget control's value: the most points sent to the browser (a value typed below the
        control's minimum counts as the minimum: a digit on its way to a larger number must not thin to one)."""
        return max(MIN_POINT_BUDGET, int(self.point_budget.value))

    def _thinning(self, cloud: FusedCloud, budget: int) -> VoxelThinning:
        """The voxel grid of ``cloud`` (a base cloud, which previews mask) for ``budget`` points, cached for the
        newest THIN_CACHE clouds."""
        with self._thin_lock:
            for entry in self._thinnings:
                if entry[0] is cloud and entry[1] == budget:
                    return entry[2]
        thinning = voxel_thinning(np.asarray(cloud.xyz), budget)  # (outside the lock)
        with self._thin_lock:
            self._thinnings = [*self._thinnings, (cloud, budget, thinning)][-THIN_CACHE:]
        return thinning

    def _exact_selection(self, cloud: FusedCloud, budget: int, params: ViewParams | None) -> tuple[np.ndarray, float]:
        """The points of an exact ``cloud`` sent under ``budget`` and the voxel edge: on its base cloud's grid (the
        previews') when that fits, so the exact picture keeps the previews' resolution; the base cloud itself
        through its cached grid."""
        base = self.session.nearest_base_cloud(params) if params is not None else (None, False)
        base = base[0] if base[1] else None  # (never computes)
        if cloud is base:
            thinning = self._thinning(cloud, budget)
            return thinning.select(), thinning.voxel
        with self._thin_lock:
            for entry in self._selections:
                if entry[0] is cloud and entry[1] == budget:
                    return entry[2], entry[3]
            start = next((t.voxel for c, b, t in self._thinnings if c is base and b == budget and t.voxel > 0),
                         None)
        keep, voxel = thin_to_budget(np.asarray(cloud.xyz), budget, start=start)  # (outside the lock)
        with self._thin_lock:
            self._selections = [*self._selections, (cloud, budget, keep, voxel)][-THIN_CACHE:]
        return keep, voxel

    def _base_colors(self, base: FusedCloud) -> np.ndarray:
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

    def _exact(self, params: ViewParams, generation: int) -> None:
        """The exact cloud and scores of a request. It starts only once the controls are still (the
        scheduler's quiet time): while a slider is being dragged the previews answer, and an exact result for
        a value already left behind would only take the CPU from them."""
        base = self.session.base_cloud(params)  # makes later previews possible
        cloud = self.session.cloud(params)
        if not self._scheduler.is_current(generation):
            return  # a newer request is queued: skip the stale push
        if self.cloud is not cloud:  # (the preview may have shown this cached cloud already)
            self._show(cloud, params, preview=False, generation=generation)
        self._refresh_view_latest()
        if len(base) > self.budget():  # after the exact cloud is shown: it must not wait on this
            self._thinning(base, self.budget())  # previews then thin in a linear pass
        scores = self.session.evaluate(params, cloud)
        if self._scheduler.is_current(generation):
            self._show_scores(cloud, params, scores)

    def _show_scores(self, cloud: FusedCloud, params: ViewParams, scores: dict | None) -> None:
        """The exact result's headline and its table: every tolerance, against the run and the previous setting."""
        with self._state_lock:
            current = {**(scores or {}), "_points": len(cloud)}
            if self._scored is None or self._scored[0] != params:
                self._previous_scored, self._scored = self._scored, (params, current)
            previous = self._previous_scored
        self.metrics.content = self._metrics_text(cloud, scores, params=params)
        run = self.session.run
        self.metrics_table.content = metrics_html(scores, self.session.run_scores(),
                                                  previous[1] if previous else None, len(cloud),
                                                  run.fused_points if run is not None else None)

    def _metrics_text(self, cloud: FusedCloud, scores: dict | None, preview: bool = False, count: int | None = None,
                      stale_fusion: bool = False, params: ViewParams | None = None) -> str:
        if preview:
            total = len(cloud) if count is None else count
            shown = "" if total == len(cloud) else f", {len(cloud):,} shown"
            how = ("masks the cloud of the previous fusion thresholds: this fusion change is not in it yet"
                   if stale_fusion else "the unfiltered cloud masked by per-point confidence and views")
            return (f"**{total:,} points** (preview, approximate{shown})  \n*{how}*  \n"
                    "exact result follows…")
        text = f"**{len(cloud):,} points**{self._sent_note(cloud)} · exact  \n{describe(scores)}"
        last = self._last_preview
        if last is not None and params is not None and last[0] == params and last[1] != len(cloud):
            text += f"  \n*the approximate preview showed {last[1]:,} points ({last[1] - len(cloud):+,})*"
        return text

    def _sent_note(self, cloud: FusedCloud) -> str:
        """The metrics' " (N sent, thinned)" when the browser got ``cloud`` thinned, else ""."""
        sent = self._sent
        return f" ({sent[1]:,} sent, thinned)" if sent is not None and sent[0] is cloud and sent[1] < len(cloud) \
            else ""

    def _show(self, cloud: FusedCloud, params: ViewParams, preview: bool, count: int | None = None,
              colors: np.ndarray | None = None, scores: dict | None = None, stale_fusion: bool = False,
              generation: int | None = None, voxel: float = 0.0) -> None:
        """Draw ``cloud`` (an exact one thinned to the point budget here; a preview arrives thinned, ``voxel`` its
        grid's edge and ``count`` its whole count) with its metrics text."""
        drawn = cloud
        budget = self.budget()
        if not preview and len(cloud) > budget:
            keep, voxel = self._exact_selection(cloud, budget, params)
            drawn = cloud.subset(keep)
            colors = None if colors is None else colors[keep]
        total = len(cloud) if count is None else count
        note = thinned_note(total, len(drawn), voxel, budget)
        if preview:
            note = f"preview: {note}"
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
                        "/fused", points, colors=colors, point_size=self.cloud_point_size(),
                        precision="float32")
                    self.mesh_panel.apply_visibility()  # a new cloud handle starts visible
                else:
                    self.cloud_handle.points = points
                    self.cloud_handle.colors = colors
                self._sent = (cloud, len(drawn), voxel)
                self.budget_note.content = note
                if preview:
                    self.metrics.content = self._metrics_text(cloud, None, preview=True, count=count,
                                                              stale_fusion=stale_fusion)
                    self.metrics_table.content = ""
                    self._last_preview = (params, len(cloud) if count is None else count)
                elif scores is not None or not self.session.has_gt:
                    self.metrics.content = self._metrics_text(cloud, scores, params=params)
                else:
                    self.metrics.content = f"**{len(cloud):,} points**{self._sent_note(cloud)}  \nscoring…"
                self._cloud_message_id = self.server._websock_server.get_message_buffer().message_counter - 1
            self.cloud, self.cloud_params = cloud, params

    def _recolor(self) -> None:
        if self.cloud is not None:
            self._show(self.cloud, self.cloud_params, preview=False)
            scores = self.session.evaluate(self.cloud_params, self.cloud) if self.cloud_params else None
            self._show_scores(self.cloud, self.cloud_params, scores)

    def _set_point_size(self) -> None:
        if self.cloud_handle is not None:
            self.cloud_handle.point_size = self.cloud_point_size()

    def select_view(self, index: int) -> None:
        """Show view ``index``'s image and maps in the side panel (also on a frustum click, the view
        dropdown and the previous / next buttons)."""
        self.selected_view = index
        view = self.session.scene.views[index]
        label = view_label(index, view.name)
        if self.view_dropdown.value != label:
            self.view_dropdown.value = label
        self.view_title.content = f"**view {index}: {view.name}**  \nsources: {view.source_views}"
        self._refresh_view()
        for i, frustum in enumerate(self.frustums):
            frustum.color = (230, 60, 40) if i == index else (60, 60, 200)

    def _refresh_view(self) -> None:
        """The selected view's maps, legends and numbers under the current controls."""
        index = self.selected_view
        params = self.params() if hasattr(self, "_fusion_handles") else self.run_params
        try:
            maps = self.session.view_maps(index, params)
            numbers = self.session.view_metrics(index, params) if self.session.has_maps else ""
        except Exception as exc:  # noqa: BLE001 - the panel says what went wrong, the viewer stays up
            self.view_metrics.content = f"**error:** {' '.join(str(exc).split())}"
            return
        self.view_metrics.content = f"*{params.pipeline}, as the controls filter it:*  \n{numbers}" if numbers else ""
        for kind, handle in self.view_images.items():
            shown = kind in maps
            handle.visible = shown
            self.view_legends[kind].visible = shown
            if shown:
                handle.image = subsample(maps[kind][0], PANEL_IMAGE)
                self.view_legends[kind].content = maps[kind][1]

    # ---- exports ----------------------------------------------------------------------------------
    def _export_dir(self) -> Path:
        base = self.session.out_dir or Path.cwd()
        return base / "exports"

    def whole_cloud(self) -> FusedCloud | None:
        """The whole exact cloud of the setting shown (None before any): what is shown may be a preview, a thinned
        mask of the base cloud, so the exact one is taken from the session (computed there if not yet)."""
        if self.cloud is None or self.cloud_params is None:
            return self.cloud
        return self.session.cloud(self.cloud_params)

    def export_ply(self, name: str | None = None) -> Path | None:
        """Write the current setting's whole cloud to OUT/exports/<sanitised name>.ply."""
        cloud = self.whole_cloud()
        if cloud is None:
            return None
        path = self._export_dir() / safe_file_name(name or str(self.export_name.value), ".ply")
        write_cloud_ply(path, cloud)
        self.export_status.content = f"wrote `{path}` ({len(cloud):,} points)"
        return path

    def save_rrd(self, name: str | None = None) -> Path | None:
        """Save cameras, the selected view's maps and the current setting's whole cloud as OUT/exports/<name>.rrd."""
        cloud = self.whole_cloud()
        if cloud is None:
            return None
        path = self._export_dir() / safe_file_name(name or str(self.export_name.value), ".rrd")
        write_state_rrd(path, self.session.scene, cloud, self.cloud_params, self.cloud_point_size(),
                        self.selected_view,
                        {k.replace(" ", "_"): image for k, (image, _) in
                         self.session.view_maps(self.selected_view, self.cloud_params).items()})
        self.export_status.content = f"wrote `{path}`"
        return path

    # ---- lifecycle ----------------------------------------------------------------------------------
    def wait_idle(self, timeout: float = 60.0) -> bool:
        """Block until no recomputation is pending or running (for tests and benchmarks)."""
        return self._scheduler.wait_idle(timeout)

    def stop(self) -> None:
        self.inspector.stop()
        self.mesh_panel.stop()
        self._scheduler.stop(timeout=10)
        self.server.stop()


def open_server(host: str, port: int) -> viser.ViserServer:
    """A viser server on host:port (port 0 = any free one; a busy port makes viser take the next free one),
    with viser's own banner and log lines kept off the terminal; a port that cannot be bound at all is a
    one-line DeepCError."""
    quiet = io.StringIO()
    try:
        with contextlib.redirect_stdout(quiet), contextlib.redirect_stderr(quiet):
            return viser.ViserServer(host=host, port=port, verbose=False)
    except OSError as exc:
        raise DeepCError(f"cannot serve the viewer on {host}:{port}: {exc.strerror or exc}") from None


def announce(label: str, host: str, requested: int, used: int, note: str) -> None:
    """One line naming the viewer's address (and one before it when the requested port was busy)."""
    if requested and used != requested:
        print(f"{label}: port {requested} is in use; serving on port {used} instead", flush=True)
    print(f"{label}: http://{host}:{used}  ({note})", flush=True)


def hold(server: viser.ViserServer, make_app: Callable[[viser.ViserServer], Any], label: str, host: str,
         requested: int, on_open: Callable[[Any], None] | None = None) -> None:
    """Build an app on ``server`` (viser's own output kept off the terminal), run ``on_open(app)``, name its
    address, serve until Ctrl+C; then stop the app (or the server, when the app never came up)."""
    quiet = io.StringIO()
    app = None
    try:
        with contextlib.redirect_stdout(quiet), contextlib.redirect_stderr(quiet):
            app = make_app(server)
        if on_open is not None:
            on_open(app)
        announce(label, host, requested, server.get_port(), "Ctrl+C to stop")
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        with contextlib.redirect_stdout(quiet), contextlib.redirect_stderr(quiet):
            (server if app is None else app).stop()


def serve(path: str, host: str = "127.0.0.1", port: int = 8080, server: viser.ViserServer | None = None,
          on_open: Callable[[ViewerApp], None] | None = None) -> None:
    """Open a session and serve until interrupted (``deepc view``); the server stops on the way out.

    ``server``: an already running server to take over (``deepc run``'s live viewer, whose browser tabs stay
    connected); else one is opened on host:port. ``on_open(app)`` runs once the app's panel is up (the live
    viewer removes its own panel and clouds then)."""
    try:
        session = ViewerSession.open(path)
    except BaseException as exc:  # a bad folder or a Ctrl+C while it opens stops a server taken over as well
        if server is not None:
            server.stop()
        if isinstance(exc, KeyboardInterrupt):
            return
        raise
    if server is None:
        server, requested = open_server(host, port), port
    else:
        requested = server.get_port()  # (a taken-over server announced its start)
    hold(server, lambda s: ViewerApp(session, host=host, port=port, verbose=False, server=s), "viewer", host,
         requested, on_open)
