"""The viewer's pixel inspector: "why is this depth wrong?" answered for one pixel, and a region re-run.

Click a point of the cloud (the pixel of the view that made it, or of the selected view where that view sees
the point) or a pixel of the selected view's map shown as a plane in the scene ("Map plane"), or type the
pixel: the probe (``engine.run.probe.probe_run``) replays the pixel's PatchMatch iterations from the run
folder's maps and checkpoints in a worker thread, and the Inspector folder shows its trace — cost and depth
against the iteration, the winner's per-view costs with the selected views marked, the candidate table of
any iteration, the pixel's window projected into each source image, and the final depth against GT, its
label, confidence and the counter's verdicts (``workbench/trace/``).

The "Re-run region" folder re-runs PatchMatch on a box of the view (``engine.run.probe.rerun_region``) with
the common options changed and shows the depth and error maps before and after side by side, the region's
share within 1 % of GT, and the inspected pixel's new trace over its old one. Both jobs run on
:class:`workbench.viewer.scheduler.NewestWorker` threads (a newer click wins); a bad pixel or view is a
:class:`engine.core.errors.DeepCError` whose one line the panel shows. The engine functions are injected so that
tests can drive the panel with traces made by hand.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from engine.core.errors import DeepCError
from engine.patchmatch.options import PATTERNS, PatchMatchOptions
from workbench.trace.figures import ORIGIN_COLOURS, PANEL_PX, candidate_table_html, summary_markdown, trace_figure
from workbench.trace.windows import THUMB, ray_points, window_thumbnails
from workbench.viewer.legends import scale_html
from workbench.viewer.region import region_markdown, region_picture, region_scales
from workbench.viewer.scheduler import NewestWorker

# A probe replays the whole view, so 9 pixels cost what one does (fountain_p11 at 192 px: 9.8 s for 25, 9.6 s
# for 1): the clicked pixel's neighbours within this many pixels come along and answer at once when clicked next.
# Each trace is also a JSON file of about 350 KB in OUT/probes/, hence not more.
PROBE_NEIGHBOURS = 1
PICK_RADIANS = 0.006  # a click picks cloud points within this angle of its ray (about 5 px at a 60° view)
REGION_SIDE = 64  # default side of the re-run box, centred on the inspected pixel
MAP_KINDS = ("depth", "cost", "GT error", "image")  # what the map plane can show

# The region form's options: PatchMatchOptions field -> (label, kind). Level and pass are rerun_region's own.
REGION_OPTIONS = {"window": ("Window (px, odd)", int), "fine_window": ("Fine window (px, 0 = off)", int),
                  "iterations": ("Iterations (0 = the run's)", int), "pattern": ("Pattern", str),
                  "k_viewsel": ("k (view selection)", int), "geom_lambda": ("Geometric weight", float)}


def _engine_probe(run_dir, view, pixels, progress=None):
    from engine.run.probe import probe_run  # lazy: the probe replays PatchMatch (numba)

    return probe_run(run_dir, view, pixels, progress=progress)


def _engine_rerun(run_dir, view, **kwargs):
    from engine.run.probe import rerun_region  # lazy: re-runs PatchMatch (numba)

    return rerun_region(run_dir, view, **kwargs)


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def _progress_text(args: tuple) -> str:
    """What the probe reports as progress ((description, done, total), (done, total) or a message), in short."""
    if len(args) == 3 and isinstance(args[0], str) and all(isinstance(a, int | float) for a in args[1:]) and args[2]:
        return f"{args[0]} · {100 * args[1] / args[2]:.0f} %"
    if len(args) >= 2 and all(isinstance(a, int | float) for a in args[:2]) and args[1]:
        return f"{100 * args[0] / args[1]:.0f} %"
    if len(args) == 1 and isinstance(args[0], float) and args[0] <= 1:
        return f"{100 * args[0]:.0f} %"
    return " ".join(str(a) for a in args)


@dataclasses.dataclass(frozen=True)
class ProbeRequest:
    """One pixel to inspect: view index, column, row (full resolution) and where the request came from."""

    view: int | str
    x: int
    y: int
    source: str = "typed"
    started: float = dataclasses.field(default_factory=time.perf_counter, compare=False)


def nearest_point_on_ray(points: np.ndarray, origin, direction, max_angle: float = PICK_RADIANS) -> int | None:
    """Index of the front-most point within ``max_angle`` of the ray (else the closest in angle within
    3 × that), or None: what a click on a point cloud hits."""
    d = np.asarray(direction, np.float64)
    d = d / np.linalg.norm(d)
    rel = np.asarray(points, np.float64) - np.asarray(origin, np.float64)
    along = rel @ d
    with np.errstate(invalid="ignore", divide="ignore"):
        angle = np.linalg.norm(rel - along[:, None] * d, axis=1) / along
    angle[~(along > 0)] = np.inf
    if not len(angle) or not np.isfinite(angle).any():
        return None
    close = np.flatnonzero(angle < max_angle)
    if len(close):
        return int(close[np.argmin(along[close])])
    best = int(np.argmin(angle))
    return best if angle[best] < 3 * max_angle else None


class InspectorPanel:
    """The Inspector and Re-run region folders of a :class:`workbench.viewer.app.ViewerApp` (``app``).

    Args:
        app: the viewer (its ``server``, ``session``, ``cloud``, ``selected_view`` and ``select_view``).
        probe: ``probe_run(run_dir, view, pixels, progress=None) -> list[trace]`` (default: the engine's).
        rerun_region: ``rerun_region(run_dir, view, box=..., level=..., pass_index=..., overrides=...,
            probe_pixels=...) -> RegionResult`` (default: the engine's).
    """

    def __init__(self, app: Any, probe: Callable | None = None, rerun_region: Callable | None = None):
        self.app = app
        self.probe_fn = probe or _engine_probe
        self.region_fn = rerun_region or _engine_rerun
        self._lock = threading.Lock()
        self._traces: dict[tuple[str, int, int], dict] = {}  # the run's traces, by (view name, x, y)
        self.trace: dict | None = None  # the trace shown
        self.compare: dict | None = None  # the run's trace under a re-run's trace
        self.request: ProbeRequest | None = None  # the newest request
        self.region: Any = None  # the newest RegionResult shown
        self.latencies: list[tuple[str, float]] = []  # (what, seconds) of each job shown: benchmarks read them
        self.map_plane = None  # the scene image handle of the clickable map
        self._plane_view: int | None = None
        session = app.session
        self.run_dir: Path | None = session.out_dir if session.has_maps else None
        run_options = (session.run.options or {}) if session.run is not None else {}
        try:
            saved = run_options.get("patchmatch")
            self.options = PatchMatchOptions.from_dict(saved, saved=True) if saved else PatchMatchOptions()
        except DeepCError:
            self.options = PatchMatchOptions()
        self._build_gui()
        self.worker: NewestWorker[ProbeRequest] = NewestWorker(self._run_probe, self._probe_failed,
                                                               name="deepc-probe")
        self.region_worker: NewestWorker[dict] = NewestWorker(self._run_region, self._region_failed,
                                                              name="deepc-region")
        app.server.scene.on_click()(self._scene_clicked)

    # ---- GUI -------------------------------------------------------------------------------------
    def _build_gui(self) -> None:
        gui = self.app.server.gui
        usable = self.run_dir is not None
        camera = self.app.session.scene.views[0].camera
        with gui.add_folder("Inspector", expand_by_default=False) as self.folder:
            self.help = gui.add_markdown(
                "Click a point of the cloud, or a pixel of the map plane, or type a pixel of the selected view: "
                "its PatchMatch trace follows." if usable else "no run folder: open the output of deepc run")
            self.pixel = gui.add_vector2("Pixel (x, y)", initial_value=(camera.width // 2, camera.height // 2),
                                         step=1, disabled=not usable,
                                         hint="column and row at the maps' resolution, of the View folder's view")
            self.inspect_button = gui.add_button("Inspect pixel", disabled=not usable)
            self.plane_kind = gui.add_dropdown("Map plane", options=("off", *MAP_KINDS), initial_value="off",
                                               disabled=not usable,
                                               hint="the selected view's map as a clickable plane in front of its "
                                                    "camera; 'Look through the view' lines it up with the screen")
            self.look_button = gui.add_button("Look through the view", disabled=not usable)
            self.status = gui.add_markdown("")
            self.summary = gui.add_markdown("")
            self.windows = gui.add_image(np.full((8, 8, 3), 255, np.uint8), label="window in each source image",
                                         format="png", visible=False)
            self.plots = gui.add_image(np.full((8, 8, 3), 255, np.uint8), label="trace", format="png", visible=False)
            self.entry = gui.add_slider("Iteration", min=0, max=1, step=1, initial_value=0, disabled=True,
                                        hint="the trace entry whose candidates the table lists")
            self.table = gui.add_html("")
            self.save_button = gui.add_button("Save trace (.rrd)", disabled=True,
                                              hint="OUT/exports/probe_<view>_<x>_<y>.rrd, the probe layout")
        with gui.add_folder("Re-run region", expand_by_default=False):
            self.box_origin = gui.add_vector2("Box corner (x0, y0)", initial_value=(0, 0), step=1,
                                              disabled=not usable)
            self.box_size = gui.add_vector2("Box size (w, h)", initial_value=(REGION_SIDE, REGION_SIDE), step=1,
                                            disabled=not usable)
            self.level = gui.add_number("Level", initial_value=0, min=0, step=1, disabled=not usable,
                                        hint="pyramid level to re-run (0 = finest)")
            self.pass_index = gui.add_number("Pass", initial_value=0, min=0, step=1, disabled=not usable,
                                             hint="pass of that level (0 = photometric)")
            self.region_inputs: dict[str, Any] = {}
            for field, (label, kind) in REGION_OPTIONS.items():
                value = getattr(self.options, field)
                if field == "pattern":
                    handle = gui.add_dropdown(label, options=PATTERNS, initial_value=value, disabled=not usable)
                elif kind is float:
                    handle = gui.add_number(label, initial_value=float(value), min=0.0, step=0.05,
                                            disabled=not usable)
                else:
                    handle = gui.add_number(label, initial_value=int(value or 0), min=0, step=1,
                                            disabled=not usable)
                self.region_inputs[field] = handle
            self.region_button = gui.add_button("Re-run region", disabled=not usable)
            self.region_status = gui.add_markdown("")
            self.region_image = gui.add_image(np.full((8, 8, 3), 255, np.uint8), label="before | after",
                                              format="png", visible=False)
            self.region_legend = gui.add_html("")
            self.region_numbers = gui.add_markdown("")
        self.inspect_button.on_click(lambda _event: self.inspect_typed())
        self.entry.on_update(lambda _event: self._entry_changed())
        self.plane_kind.on_update(lambda _event: self.update_map_plane())
        self.look_button.on_click(lambda event: self.look_through_view(event.client))
        self.region_button.on_click(lambda _event: self.rerun_from_form())
        self.save_button.on_click(lambda _event: self.save_rrd())
        self.app.view_dropdown.on_update(lambda _event: self._view_changed())

    def _view_changed(self) -> None:
        """The map plane follows the View folder's view."""
        if str(self.plane_kind.value) != "off":
            self.update_map_plane()

    # ---- requests ----------------------------------------------------------------------------------
    def inspect_typed(self) -> None:
        x, y = self.pixel.value
        self.inspect(self.app.selected_view, int(round(x)), int(round(y)), source="typed")

    def inspect(self, view: int | str, x: int, y: int, source: str = "typed") -> ProbeRequest:
        """Probe pixel (x, y) of ``view`` (index or name) in the worker; the newest request wins."""
        request = ProbeRequest(view, int(x), int(y), source)
        with self._lock:
            self.request = request
        self.status.content = f"probing pixel ({x}, {y}) of {self._view_name(view)}…"
        if self.run_dir is None:
            self.status.content = "**cannot probe:** no run folder (open the output of deepc run)"
            return request
        self.worker.submit(request)
        return request

    def _view_name(self, view: int | str) -> str:
        views = self.app.session.scene.views
        if isinstance(view, int | np.integer) and 0 <= view < len(views):
            return views[view].name
        return str(view)

    def _view_index(self, name: str) -> int | None:
        for v in self.app.session.scene.views:
            if v.name == name:
                return v.index
        return None

    def _current(self, request: ProbeRequest) -> bool:
        with self._lock:
            return self.request is request

    def _run_probe(self, request: ProbeRequest) -> None:
        name = self._view_name(request.view)
        key = (name, request.x, request.y)
        trace = self._traces.get(key)
        if trace is None:
            def progress(*args) -> None:
                if self._current(request):
                    self.status.content = f"probing pixel ({request.x}, {request.y}) of {name}… {_progress_text(args)}"
            traces = self.probe_fn(self.run_dir, request.view if isinstance(request.view, str) else name,
                                   self._with_neighbours(request), progress=progress)
            for t in traces:
                self._traces[(t["view"], t["x"], t["y"])] = t
            trace = next((t for t in traces if (t["x"], t["y"]) == (request.x, request.y)), None)
            if trace is None:
                raise DeepCError(f"the probe returned no trace for pixel ({request.x}, {request.y}) of {name}")
        if not self._current(request):
            return  # a newer click came in: its own trace follows
        self.show_trace(trace)
        seconds = time.perf_counter() - request.started
        self.latencies.append(("probe", seconds))
        self.status.content = f"pixel ({request.x}, {request.y}) of {name} · {request.source} · {seconds:.2f} s"

    def _with_neighbours(self, request: ProbeRequest) -> list[tuple[int, int]]:
        """The pixel first, then its neighbours within ``PROBE_NEIGHBOURS`` that lie in the image and were not
        probed yet (a pixel outside the image goes alone: the probe's message is about it)."""
        index = self._view_index(self._view_name(request.view))
        pixels = [(request.x, request.y)]
        if index is None:
            return pixels
        camera = self.app.session.scene.views[index].camera
        if not (0 <= request.x < camera.width and 0 <= request.y < camera.height):
            return pixels
        name = self.app.session.scene.views[index].name
        r = PROBE_NEIGHBOURS
        around = [(request.x + dx, request.y + dy) for dy in range(-r, r + 1) for dx in range(-r, r + 1) if dx or dy]
        pixels += [(x, y) for x, y in around if 0 <= x < camera.width and 0 <= y < camera.height
                   and (name, x, y) not in self._traces]
        return pixels

    def _probe_failed(self, exc: Exception) -> None:
        message = _one_line(exc) if isinstance(exc, DeepCError) else f"{type(exc).__name__}: {_one_line(exc)}"
        self.status.content = f"**cannot probe:** {message}"

    # ---- showing a trace ------------------------------------------------------------------------------
    def show_trace(self, trace: dict, compare: dict | None = None, title_note: str = "") -> None:
        """Fill the Inspector folder with ``trace`` (and ``compare``, the run's trace, dashed under it)."""
        index = self._view_index(trace["view"])
        label = f"{index}: {trace['view']}" if index is not None else str(trace["view"])
        steps = trace.get("iterations") or []
        last = max(0, len(steps) - 1)
        figure = trace_figure(trace, last, title=f"pixel ({trace['x']}, {trace['y']}) · {label}{title_note}",
                              compare=compare)
        windows = self._windows(trace, index, last)
        app = self.app
        with app.server.atomic():
            self.trace, self.compare = trace, compare
            self.summary.content = summary_markdown(trace, label) + (f"  \n*{title_note.strip(' ·')}*"
                                                                     if title_note else "")
            self.plots.image = figure
            self.plots.visible = True
            self._set_entry(last, len(steps))
            self.table.content = candidate_table_html(trace, last)
            if windows is not None:
                self.windows.image = windows
            self.windows.visible = windows is not None
            self.pixel.value = (trace["x"], trace["y"])
            self.save_button.disabled = False
            if compare is None and index is not None:  # the re-run box: centred on the pixel, inside the image
                camera = self.app.session.scene.views[index].camera
                w, h = min(REGION_SIDE, camera.width), min(REGION_SIDE, camera.height)
                self.box_origin.value = (min(max(0, trace["x"] - w // 2), camera.width - w),
                                         min(max(0, trace["y"] - h // 2), camera.height - h))
                self.box_size.value = (w, h)
        self._show_candidates(trace, last)
        if str(self.plane_kind.value) != "off":
            self.update_map_plane()  # the plane marks the inspected pixel

    def _set_entry(self, value: int, count: int) -> None:
        self._setting_entry = True
        try:
            self.entry.max = max(1, count - 1)
            self.entry.value = value
            self.entry.disabled = count <= 1
        finally:
            self._setting_entry = False

    def _entry_changed(self) -> None:
        if getattr(self, "_setting_entry", False) or self.trace is None:
            return
        entry = int(self.entry.value)
        trace = self.trace
        self.table.content = candidate_table_html(trace, entry)
        index = self._view_index(trace["view"])
        self.plots.image = trace_figure(trace, entry, title=f"pixel ({trace['x']}, {trace['y']}) · {trace['view']}",
                                        compare=self.compare)
        windows = self._windows(trace, index, entry)
        if windows is not None:
            self.windows.image = windows
        self._show_candidates(trace, entry)

    def _show_candidates(self, trace: dict, entry: int) -> None:
        """The pixel's ray in the scene with entry ``entry``'s candidates on it (coloured by origin, as in
        rerun), the winner larger in orange and the GT point in green."""
        index = self._view_index(trace["view"])
        steps = trace.get("iterations") or []
        if index is None or not steps:
            return
        app = self.app
        view = app.session.scene.views[index]
        camera, x, y = view.camera, trace["x"], trace["y"]
        step = steps[max(0, min(entry, len(steps) - 1))]
        candidates = [c for c in step.get("candidates") or [] if c.get("depth") and c["depth"] > 0]
        size = float(app.default_point_size)
        scene = app.server.scene
        with app.server.atomic():
            scene.add_line_segments("/inspector/ray", ray_points(camera, x, y, view.depth_range)[None],
                                    (255, 140, 0), thickness=2.0, thickness_units="screen")
            if candidates:
                scene.add_point_cloud(
                    "/inspector/candidates", ray_points(camera, x, y, [c["depth"] for c in candidates]).astype(
                        np.float32),
                    colors=np.array([ORIGIN_COLOURS.get(str(c["origin"]).split(":")[0], (255, 255, 255))
                                     for c in candidates], np.uint8), point_size=4 * size, precision="float32")
            winner = step["after"].get("depth")
            if winner:
                scene.add_point_cloud("/inspector/winner", ray_points(camera, x, y, [winner]).astype(np.float32),
                                      colors=(255, 140, 0), point_size=8 * size, precision="float32")
            gt = (trace.get("final") or {}).get("gt_depth")
            if gt:
                scene.add_point_cloud("/inspector/gt", ray_points(camera, x, y, [gt]).astype(np.float32),
                                      colors=(40, 200, 80), point_size=8 * size, precision="float32")

    def _windows(self, trace: dict, index: int | None, entry: int) -> np.ndarray | None:
        """The thumbnails of the pixel's window in its source images, under entry ``entry``'s plane."""
        steps = trace.get("iterations") or []
        if index is None or not steps:
            return None
        scene = self.app.session.scene
        step = steps[entry]
        after = step["after"]
        winner = step["candidates"][step["winner"]] if step.get("candidates") else {}
        names = [trace["view"], *list(trace.get("source_views") or [])]
        indices = [index, *[self._view_index(n) for n in names[1:]]]
        keep = [k for k, i in enumerate(indices) if i is not None]
        images = [(np.asarray(scene.image(indices[k])) * 255 + 0.5).astype(np.uint8) for k in keep]
        cameras = [scene.views[indices[k]].camera for k in keep]
        x, y = trace["x"], trace["y"]
        # a window of `window` pixels at pyramid level L covers 2^L times as many full-resolution pixels
        half = (self.options.window // 2) * 2 ** int(step.get("level") or 0)
        costs = winner.get("view_costs") if winner else None
        return window_thumbnails(images, cameras, [names[k] for k in keep], x, y, float(after["depth"] or 0),
                                 after.get("normal"), half, set(winner.get("selected_views") or []),
                                 [costs[k - 1] for k in keep[1:]] if costs else None,
                                 columns=round(PANEL_PX / THUMB))  # about the panel's width: shown at its size

    def save_rrd(self) -> Path | None:
        """The shown trace (and its view's depth and GT error maps) as OUT/exports/probe_<view>_<x>_<y>.rrd."""
        from workbench.rerun.probe import write_probe_recording  # lazy: rerun
        from workbench.viewer.export import safe_file_name

        trace, app = self.trace, self.app
        if trace is None or app.session.out_dir is None:
            return None
        index = self._view_index(trace["view"])
        maps = app.session.view_maps(index, app.params())
        path = app.session.out_dir / "exports" / safe_file_name(
            f"probe_{Path(trace['view']).stem}_{trace['x']}_{trace['y']}", ".rrd")
        shown = {kind: maps[k][0] for k, kind in (("depth", "depth"), ("GT error", "error")) if k in maps}
        write_probe_recording(path, app.session.scene, [trace], self.options.window, {index: shown})
        self.status.content = f"wrote `{path}`"
        return path

    # ---- clicks ---------------------------------------------------------------------------------------
    def _scene_clicked(self, event: Any) -> None:
        try:
            picked = self.pick(event.ray_origin, event.ray_direction)
        except Exception as exc:  # noqa: BLE001 - a bad click is a message, never a dead callback
            self.status.content = f"**cannot pick:** {_one_line(exc)}"
            return
        if picked is None:
            return
        view, x, y, source = picked
        if view != self.app.selected_view:
            self.app.select_view(view)
        self.inspect(view, x, y, source=source)

    def pick(self, origin, direction) -> tuple[int, int, int, str] | None:
        """(view, x, y, what was hit) under a click ray: the map plane, or the front-most cloud point near
        the ray (in the selected view where it sees the point, else in the view whose pixel made it)."""
        scene = self.app.session.scene
        origin, direction = np.asarray(origin, np.float64), np.asarray(direction, np.float64)
        plane_hit = self._plane_pixel(origin, direction)
        cloud = self.app.cloud
        point_hit = None
        if cloud is not None and len(cloud):
            i = nearest_point_on_ray(cloud.xyz, origin, direction)
            if i is not None:
                point_hit = (i, float(np.dot(np.asarray(cloud.xyz[i], np.float64) - origin, direction)))
        if plane_hit is not None and (point_hit is None or plane_hit[2] <= point_hit[1]):
            return self._plane_view, plane_hit[0], plane_hit[1], "map plane"
        if point_hit is None:
            return None
        point = np.asarray(cloud.xyz[point_hit[0]], np.float64)
        selected = self.app.selected_view
        for view in (selected, int(cloud.source_view[point_hit[0]])):
            pixel = self._pixel_of(view, point)
            if pixel is not None:
                return view, pixel[0], pixel[1], f"cloud point {point_hit[0]:,}"
        view = int(cloud.source_view[point_hit[0]])
        uv, _ = scene.views[view].camera.project(point[None])
        return view, int(round(uv[0, 0])), int(round(uv[0, 1])), f"cloud point {point_hit[0]:,}"

    def _pixel_of(self, view: int, point: np.ndarray) -> tuple[int, int] | None:
        """The pixel of ``view`` whose depth map holds ``point`` (within 1 %), else None."""
        session = self.app.session
        camera = session.scene.views[view].camera
        uv, z = camera.project(point[None])
        if not np.isfinite(uv).all() or z[0] <= 0:
            return None
        x, y = int(round(uv[0, 0])), int(round(uv[0, 1]))
        if not (0 <= x < camera.width and 0 <= y < camera.height) or session.data is None:
            return None
        depth = session.data[view].depth
        if depth.shape != (camera.height, camera.width) or abs(depth[y, x] - z[0]) > 0.01 * z[0]:
            return None
        return x, y

    # ---- the map plane ----------------------------------------------------------------------------------
    def _plane_distance(self, view: int) -> float:
        """How far in front of the camera the map plane stands: before the scene's nearest depth."""
        return 0.5 * float(self.app.session.scene.views[view].depth_range[0])

    def _plane_pixel(self, origin: np.ndarray, direction: np.ndarray) -> tuple[int, int, float] | None:
        """(x, y, distance along the ray) where the ray meets the shown map plane inside the image, else None."""
        if self.map_plane is None or self._plane_view is None or not self.map_plane.visible:
            return None
        camera = self.app.session.scene.views[self._plane_view].camera
        o = camera.world_to_camera(origin)
        d = camera.R @ direction
        if abs(d[2]) < 1e-12:
            return None
        s = (self._plane_distance(self._plane_view) - o[2]) / d[2]
        if s <= 0:
            return None
        hit = o + s * d
        uv = camera.K_idx @ (hit / hit[2])
        x, y = int(np.floor(uv[0] + 0.5)), int(np.floor(uv[1] + 0.5))
        if not (0 <= x < camera.width and 0 <= y < camera.height):
            return None
        return x, y, float(s * np.linalg.norm(direction))

    def update_map_plane(self) -> None:
        """Show the selected view's chosen map on a plane that fills its camera's view, or hide it."""
        kind = str(self.plane_kind.value)
        app = self.app
        if kind == "off":
            if self.map_plane is not None:
                self.map_plane.visible = False
            self._show_frustum(None)
            return
        from viser.transforms import SO3  # lazy: viser

        view = app.selected_view
        maps = app.session.view_maps(view, app.params())
        if kind not in maps:
            self.status.content = f"**no {kind} map** for this view"
            return
        image = maps[kind][0]
        trace = self.trace
        if trace is not None and trace["view"] == app.session.scene.views[view].name:
            image = mark_pixel(image, trace["x"], trace["y"])
        camera = app.session.scene.views[view].camera
        distance = self._plane_distance(view)
        # the image's centre is the principal ray at `distance`; it spans the image exactly
        centre_px = np.array([(camera.width - 1) / 2, (camera.height - 1) / 2, 1.0])
        centre = np.linalg.inv(camera.K_idx) @ centre_px * distance
        self.map_plane = app.server.scene.add_image(
            "/inspector/map", image, render_width=distance * camera.width / camera.fx,
            render_height=distance * camera.height / camera.fy, format="png",
            wxyz=SO3.from_matrix(camera.R.T).wxyz, position=camera.camera_to_world(centre))
        self._plane_view = view
        self._show_frustum(view)

    def _show_frustum(self, hidden: int | None) -> None:
        """Every camera frustum drawn except view ``hidden``'s, whose image the map plane stands in for."""
        for i, frustum in enumerate(self.app.frustums):
            frustum.visible = i != hidden

    def look_through_view(self, client: Any) -> None:
        """Put a browser's camera where the selected view's camera is, with its field of view."""
        if client is None:
            return
        camera = self.app.session.scene.views[self.app.selected_view].camera
        with client.atomic():
            client.camera.fov = float(2 * np.arctan2(camera.height / 2, camera.fy))
            client.camera.position = camera.center
            client.camera.look_at = camera.center + camera.R[2] * float(
                np.mean(self.app.session.scene.views[self.app.selected_view].depth_range))
            client.camera.up_direction = -camera.R[1]

    # ---- region re-run --------------------------------------------------------------------------------
    def region_overrides(self) -> dict[str, Any]:
        """The form's options that differ from the run's (PatchMatchOptions field names)."""
        out = {}
        for field, handle in self.region_inputs.items():
            kind = REGION_OPTIONS[field][1]
            value = kind(handle.value)
            if field == "iterations" and value == 0:
                continue  # 0: the run's schedule
            if value != getattr(self.options, field):
                out[field] = value
        return out

    def rerun_from_form(self) -> None:
        x0, y0 = (int(round(v)) for v in self.box_origin.value)
        w, h = (int(round(v)) for v in self.box_size.value)
        self.rerun(self.app.selected_view, (x0, y0, w, h), level=int(self.level.value),
                   pass_index=int(self.pass_index.value), overrides=self.region_overrides())

    def rerun(self, view: int | str, box: tuple[int, int, int, int], level: int = 0, pass_index: int = 0,
              overrides: dict | None = None) -> None:
        """Re-run PatchMatch on ``box`` (x0, y0, width, height) of ``view`` in the region worker."""
        if self.run_dir is None:
            self.region_status.content = "**cannot re-run:** no run folder"
            return
        pixels = ()
        trace = self.trace
        if trace is not None and trace["view"] == self._view_name(view):
            x, y = trace["x"], trace["y"]
            if box[0] <= x < box[0] + box[2] and box[1] <= y < box[1] + box[3]:
                pixels = ((x, y),)
        job = {"view": view, "box": tuple(int(v) for v in box), "level": level, "pass_index": pass_index,
               "overrides": dict(overrides or {}), "pixels": pixels, "started": time.perf_counter()}
        changed = ", ".join(f"{k} {v}" for k, v in job["overrides"].items()) or "the run's options"
        self.region_status.content = f"re-running box {job['box']} with {changed}…"
        self.region_worker.submit(job)

    def _run_region(self, job: dict) -> None:
        name = self._view_name(job["view"])
        result = self.region_fn(self.run_dir, job["view"] if isinstance(job["view"], str) else name, box=job["box"],
                             level=job["level"], pass_index=job["pass_index"], overrides=job["overrides"] or None,
                             probe_pixels=job["pixels"])
        scales = region_scales(result, self.app.session.scene.views[self._view_index(name)].depth_range)
        picture = region_picture(result, scales, job["pixels"][0] if job["pixels"] else None)
        seconds = time.perf_counter() - job["started"]
        changed = ", ".join(f"{k} {v}" for k, v in job["overrides"].items()) or "run options"
        with self.app.server.atomic():
            self.region = result
            self.region_image.image = picture
            self.region_image.visible = True
            self.region_legend.content = "".join(scale_html(scale) for scale in scales)
            self.region_numbers.content = region_markdown(result)
            self.region_status.content = f"box {tuple(result.box)} of {name} · {changed} · {seconds:.2f} s"
        self.latencies.append(("region", seconds))
        traces = list(getattr(result, "traces", None) or [])
        if traces:
            old = self._traces.get((traces[0]["view"], traces[0]["x"], traces[0]["y"]), self.trace)
            self.show_trace(traces[0], compare=old, title_note=" · after re-run")

    def _region_failed(self, exc: Exception) -> None:
        message = _one_line(exc) if isinstance(exc, DeepCError) else f"{type(exc).__name__}: {_one_line(exc)}"
        self.region_status.content = f"**cannot re-run:** {message}"

    # ---- lifecycle -------------------------------------------------------------------------------------
    def wait_idle(self, timeout: float = 60.0) -> bool:
        """Block until neither worker has a job (tests, benchmarks)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.worker.idle() and self.region_worker.idle():
                return True
            time.sleep(0.02)
        return False

    def stop(self) -> None:
        self.worker.stop(timeout=10)
        self.region_worker.stop(timeout=10)


def mark_pixel(image: np.ndarray, x: int, y: int, colour=(255, 0, 255)) -> np.ndarray:
    """A copy of ``image`` with a cross (arms of about 3 % of the image) centred on pixel (x, y), the pixel
    itself left as it is."""
    out = np.array(image, copy=True)
    h, w = out.shape[:2]
    arm = max(2, round(0.03 * max(h, w)))
    for dx in range(-arm, arm + 1):
        if dx and 0 <= x + dx < w and 0 <= y < h:
            out[y, x + dx] = colour
        if dx and 0 <= y + dx < h and 0 <= x < w:
            out[y + dx, x] = colour
    return out


__all__ = ["InspectorPanel", "ProbeRequest", "nearest_point_on_ray"]
