"""The viewer's compare mode: ``deepc view RUN_A --compare RUN_B``.

Both runs' compared pixels as two clouds (:func:`engine.compare.clouds.case_clouds`) — A, B or both shown —
coloured by who is right, by where they differ, by run or by image; the selected view's depth maps and case maps of
A and B side by side; a table of A | B | change (each run's fused cloud F1 at every tolerance, the shares within
the tolerance of GT overall and in the view); and, when both runs are ours, the pixel inspector's summary of one
pixel in A and in B. Every number comes from :func:`engine.compare.comparison.compare_runs`; the colours of every
colouring are made once (:func:`workbench.compare.colours.colour_arrays`), so a switch only sends them.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import viser

from engine.compare.clouds import SIDES, case_clouds, pixel_step
from engine.compare.comparison import Comparison, ViewComparison, common_depths
from engine.compare.pixels import DIFFERENT, case_codes
from engine.core.errors import DeepCError
from workbench.compare.colours import COLOURINGS, case_lut, colour_arrays, legend_html
from workbench.maps.images import colorize, subsample
from workbench.trace.figures import summary_markdown
from workbench.viewer.app import add_cameras, hold, open_server, set_home_camera
from workbench.viewer.inspector import nearest_point_on_ray
from workbench.viewer.panel import PANEL_IMAGE, view_label
from workbench.viewer.scheduler import NewestWorker

MAX_POINTS = 200_000  # per run: every compared pixel is a point, a browser draws each one it is sent
SHOWN = ("both", "A", "B")
GAP = 4  # pixels between A's and B's picture


def _probe(run_dir: Path, view: str, pixels: list[tuple[int, int]], progress: Callable | None = None) -> list[dict]:
    from engine.run.probe import probe_run  # lazy: the probe replays PatchMatch (numba)

    return probe_run(run_dir, view, pixels, progress=progress)


def side_by_side(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """(H, W_l + GAP + W_r, 3) uint8: two (H, W, 3) pictures of one view with a white gap between."""
    gap = np.full((left.shape[0], GAP, 3), 255, np.uint8)
    return np.concatenate([left, gap, right], axis=1)


def _delta(a: float | None, b: float | None) -> str:
    return "–" if a is None or b is None or a != a or b != b else f"{b - a:+.2f}"


def _pct(value: float | None) -> str:
    return "–" if value is None or value != value else f"{value:.2f}"


def metrics_table_html(comparison: Comparison, view: ViewComparison, scoring: bool = False) -> str:
    """A | B | change (B − A): each run's fused cloud F1 (and its maps fused by ours, when scored) at every
    tolerance, then the share of GT pixels within the tolerance over all views and in ``view``; then the shares
    of the cases where the runs differ. ``scoring``: the fused clouds are being scored (said in their place)."""
    style = 'style="padding:0 0.4em;text-align:right"'
    rows = [f"<tr><th {style}></th><th {style}>A</th><th {style}>B</th><th {style}>change</th></tr>"]
    if scoring:
        rows.append(f'<tr><td {style} colspan="4"><i>fused F1: scoring both clouds…</i></td></tr>')

    def row(label: str, a: float | None, b: float | None) -> None:
        rows.append(f"<tr><td {style}>{label}</td><td {style}>{_pct(a)}</td><td {style}>{_pct(b)}</td>"
                    f"<td {style}>{_delta(a, b)}</td></tr>")

    for title, blocks in (("fused F1 %", comparison.fused), ("our fusion F1 %", comparison.ours_fused)):
        a, b = blocks.get("a"), blocks.get("b")
        for i, t in enumerate((a or b or {}).get("tolerances", [])):
            row(f"{title} @ {t:g}", a["f1"][i] if a else None, b["f1"][i] if b else None)
    tol = f"{100 * comparison.tolerance:g} %"
    for label, counts in (("all views", comparison.total), (f"view {view.name}", view.counts)):
        shares = counts.shares()
        row(f"right % ({label}, within {tol} of GT)", shares["a_right"], shares["b_right"])
    view_shares, all_shares = view.counts.shares(), comparison.total.shares()
    rows.append(f"<tr><th {style}></th><th {style}>all views</th><th {style}>this view</th><th {style}></th></tr>")
    for key, label in (("a_right_b_wrong", "A right, B wrong %"), ("b_right_a_wrong", "B right, A wrong %"),
                       ("both_wrong", "both wrong %"), ("disagree", "disagree % (no GT)"),
                       ("difference", "differ % (all counted pixels)")):
        rows.append(f"<tr><td {style}>{label}</td><td {style}>{_pct(all_shares[key])}</td>"
                    f"<td {style}>{_pct(view_shares[key])}</td><td {style}></td></tr>")
    notes = "".join(f"<div>{n}</div>" for n in comparison.fused_notes)
    return (f'<div class="deepc-compare-metrics" style="font-size:0.8em"><table style="border-collapse:collapse">'
            f'{"".join(rows)}</table>{notes}</div>')


@dataclass
class _ViewPictures:
    """One view's depth pictures (A | B) and case codes, kept so that a colouring switch only re-indexes."""

    depth: np.ndarray
    codes: np.ndarray
    has_a: np.ndarray
    has_b: np.ndarray


class CompareApp:
    """The compare-mode viewer on its own viser server.

    Args:
        comparison: the two runs compared (:func:`engine.compare.comparison.compare_runs`).
        host, port: where to serve (port 0: any free one); server: an already running server to use instead.
        max_points: at most about this many points per run are drawn.
        probe: ``probe_run(run_dir, view_name, pixels, progress=None) -> list[trace]`` (default: the engine's).
    """

    def __init__(self, comparison: Comparison, host: str = "127.0.0.1", port: int = 8080,
                 server: viser.ViserServer | None = None, max_points: int = MAX_POINTS,
                 probe: Callable | None = None, score_fused: bool = False):
        self.comparison = c = comparison
        # the fused clouds' scores (seconds each for a foreign cloud) arrive after the viewer opens
        self.scoring = score_fused
        self.server = viser.ViserServer(host=host, port=port, verbose=False) if server is None else server
        self.port = self.server.get_port()
        self.probe_fn = probe or _probe
        self.clouds = case_clouds(c, max_points)
        self.colours = colour_arrays(self.clouds)
        self.switch_seconds: list[float] = []  # server-side time of each colouring switch
        self._pictures: dict[int, _ViewPictures] = {}
        self.selected = c.views[0]
        set_home_camera(self.server, c.scene)
        self.frustums, _, pixel_size = add_cameras(self.server, c.scene)
        # a point stands for a step x step block of pixels: drawn as wide, the clouds stay closed surfaces
        shrink = max(c.scene.views[v.index].camera.width / v.size[0] for v in c.views)  # camera px per map px
        point_size = pixel_size * shrink * pixel_step(c, max_points)
        for view, frustum in zip(c.scene.views, self.frustums, strict=True):
            frustum.on_click(lambda _event, i=view.index: self.select_view(i))
        self.handles = {side: self.server.scene.add_point_cloud(
            f"/compare/{side}", self.clouds[side].xyz, colors=self.colours[COLOURINGS[0]][side],
            point_size=point_size, precision="float32") for side in SIDES}
        self._build_gui()
        self.worker: NewestWorker[tuple[str, int, int]] = NewestWorker(self._inspect, self._inspect_failed,
                                                                  name="deepc-compare-probe")
        self.select_view(self.selected.index)
        if c.a.kind == c.b.kind == "deepc":
            self.server.scene.on_click()(lambda event: self.pick(event.ray_origin, event.ray_direction))
        self._scorer = threading.Thread(target=self._score_fused, name="deepc-compare-score", daemon=True)
        if score_fused:
            self._scorer.start()

    def _score_fused(self) -> None:
        """Score both runs' fused clouds (``comparison.fused_scores``) and show them in the metrics table."""
        from engine.compare.comparison import fused_scores  # lazy: evaluation

        c = self.comparison
        try:
            c.fused, notes = fused_scores(c.a, c.b, c.scene)
            c.fused_notes.extend(notes)
        except Exception as exc:  # shown in the table: the pixel comparison stays usable
            c.fused_notes.append(f"fused clouds not scored: {' '.join(str(exc).split())}")
        self.scoring = False
        self.metrics.content = metrics_table_html(c, self.selected, self.scoring)

    def wait_scored(self, timeout: float = 120.0) -> bool:
        """Whether the fused clouds' scores arrived within ``timeout`` seconds (tests)."""
        if self._scorer.is_alive():
            self._scorer.join(timeout)
        return not self.scoring

    # ---- GUI -------------------------------------------------------------------------------------
    def _build_gui(self) -> None:
        gui, c = self.server.gui, self.comparison
        gui.add_markdown(f"**DeepC Workbench · compare** · {c.scene.name}  \n**A:** {c.a.description} · "
                         f"`{c.a.path}`  \n**B:** {c.b.description} · `{c.b.path}`")
        with gui.add_folder("Clouds"):
            self.shown = gui.add_dropdown("Show", SHOWN, initial_value="both")
            self.colouring = gui.add_dropdown("Colour by", COLOURINGS, initial_value=COLOURINGS[0])
            self.legend = gui.add_html(legend_html(COLOURINGS[0], c.total.shares()))
        with gui.add_folder("Metrics"):
            self.metrics = gui.add_html("")
        with gui.add_folder("View"):
            labels = tuple(view_label(v.index, v.name) for v in c.views)
            self.view_dropdown = gui.add_dropdown("View", labels, initial_value=labels[0])
            self.depth_image = gui.add_image(np.zeros((8, 8, 3), np.uint8), label="depth: A | B", format="png")
            self.case_image = gui.add_image(np.zeros((8, 8, 3), np.uint8), label="who is right: A | B",
                                            format="png")
        both_ours = c.a.kind == c.b.kind == "deepc"
        with gui.add_folder("Inspector", expand_by_default=both_ours):
            hint = None if both_ours else "both runs must be deepc runs: the probe replays our PatchMatch"
            self.pixel_x = gui.add_number("x (column)", 0, min=0, step=1, disabled=not both_ours, hint=hint)
            self.pixel_y = gui.add_number("y (row)", 0, min=0, step=1, disabled=not both_ours, hint=hint)
            self.inspect_button = gui.add_button("Inspect this pixel in A and B", disabled=not both_ours, hint=hint)
            self.inspect_status = gui.add_markdown("" if both_ours else f"*{hint}*")
            self.inspect_text = {side: gui.add_markdown("") for side in SIDES}
        self.shown.on_update(lambda _event: self.show(str(self.shown.value)))
        self.colouring.on_update(lambda _event: self.set_colouring(str(self.colouring.value)))
        self.view_dropdown.on_update(lambda _event: self.select_view(int(str(self.view_dropdown.value).split(":")[0])))
        self.inspect_button.on_click(lambda _event: self.inspect(int(self.pixel_x.value), int(self.pixel_y.value)))

    # ---- actions ----------------------------------------------------------------------------------
    def show(self, which: str) -> None:
        """Show both clouds, A's or B's (:data:`SHOWN`)."""
        for side, handle in self.handles.items():
            handle.visible = which in ("both", side.upper())

    def set_colouring(self, colouring: str) -> None:
        """Colour both clouds and the view's case maps by ``colouring`` (:data:`COLOURINGS`): the arrays are made
        already, so this only sends them."""
        start = time.perf_counter()
        with self.server.atomic():
            for side, handle in self.handles.items():
                handle.colors = self.colours[colouring][side]
            self.legend.content = legend_html(colouring, self.comparison.total.shares())
            self._show_cases()
        self.switch_seconds.append(time.perf_counter() - start)

    def _view_pictures(self, view: ViewComparison) -> _ViewPictures:
        cached = self._pictures.get(view.index)
        if cached is None:
            c = self.comparison
            da, db = common_depths(c.a, c.b, view.keys, view.size)
            lo, hi = c.scene.views[view.index].depth_range
            depth = side_by_side(*(colorize(d, lo, hi, "turbo", ~(d > 0)) for d in (da, db)))
            cached = self._pictures[view.index] = _ViewPictures(depth, case_codes(view.maps), da > 0, db > 0)
        return cached

    def _show_cases(self) -> None:
        """The selected view's cases at A's pixels | at B's (a pixel a run has no depth at is black on its side,
        its case shows on the other) under the current colouring (who is right, unless "disagreement")."""
        pictures = self._view_pictures(self.selected)
        colouring = str(self.colouring.value)
        lut = case_lut(colouring if colouring == "disagreement" else "who is right")
        coloured = lut[pictures.codes]
        sides = [np.where(has[:, :, None], coloured, 0).astype(np.uint8) for has in (pictures.has_a, pictures.has_b)]
        self.case_image.image = subsample(side_by_side(*sides), 2 * PANEL_IMAGE)
        self.case_image.label = f"{'disagreement' if colouring == 'disagreement' else 'who is right'}: A | B"

    def select_view(self, index: int) -> None:
        """Show view ``index``'s maps and numbers (also on a frustum click and the view dropdown); a view that was
        not compared keeps the current one."""
        view = next((v for v in self.comparison.views if v.index == index), None)
        if view is None:
            return
        self.selected = view
        label = view_label(view.index, view.name)
        if self.view_dropdown.value != label:
            self.view_dropdown.value = label
        with self.server.atomic():
            self.depth_image.image = subsample(self._view_pictures(view).depth, 2 * PANEL_IMAGE)
            self._show_cases()
            self.metrics.content = metrics_table_html(self.comparison, view, self.scoring)
            for i, frustum in enumerate(self.frustums):
                frustum.color = (230, 60, 40) if i == index else (60, 60, 200)
        self._suggest_pixel(view)

    def _suggest_pixel(self, view: ViewComparison) -> None:
        """Put a pixel where the runs differ (at the scene camera's size) into the inspector's form: the middle one
        of the first case of :data:`DIFFERENT` the view has (where GT says who is right, before disagreement)."""
        case = next((k for k in DIFFERENT if view.maps[k].any()), None)
        if case is None:
            return
        rows, cols = np.nonzero(view.maps[case])
        camera = self.comparison.scene.views[view.index].camera
        mid = len(rows) // 2
        self.pixel_x.value = int(cols[mid] * camera.width / view.size[0])
        self.pixel_y.value = int(rows[mid] * camera.height / view.size[1])

    def pick(self, origin: Any, direction: Any) -> tuple[int, int, int] | None:
        """Inspect the pixel of the front-most shown point under a click ray (origin, direction: (3,) world);
        returns its (view index, x, y) at the scene camera's size, or None when the ray hits no point."""
        hits = []
        for side, handle in self.handles.items():
            cloud = self.clouds[side]
            i = nearest_point_on_ray(cloud.xyz, origin, direction) if handle.visible else None
            if i is not None:
                hits.append((float(np.dot(cloud.xyz[i] - np.asarray(origin), direction)), side, i))
        if not hits:
            return None
        _, side, i = min(hits)
        cloud = self.clouds[side]
        view = int(cloud.view[i])
        size = next(v.size for v in self.comparison.views if v.index == view)
        camera = self.comparison.scene.views[view].camera
        x, y = (int(cloud.pixel[i, k] * full / size[k]) for k, full in enumerate(camera.size))
        self.select_view(view)
        self.pixel_x.value, self.pixel_y.value = x, y
        self.inspect(x, y)
        return view, x, y

    def inspect(self, x: int, y: int) -> None:
        """Probe pixel (x, y) (the scene camera's pixels) of the selected view in A and in B, on a worker."""
        self.inspect_status.content = f"probing pixel ({x}, {y}) of {self.selected.name} in A and B…"
        self.worker.submit((self.selected.name, x, y))

    def _inspect(self, job: tuple[str, int, int]) -> None:
        view, pixel = job[0], job[1:]
        for side, run in (("a", self.comparison.a), ("b", self.comparison.b)):
            traces = self.probe_fn(run.path, view, [pixel])
            trace = next((t for t in traces if (t["x"], t["y"]) == pixel), None)
            if trace is None:
                raise DeepCError(f"the probe of {run.path} returned no trace for pixel {pixel} of {view}")
            self.inspect_text[side].content = f"**{side.upper()}** · " + summary_markdown(trace, view)
        self.inspect_status.content = f"pixel {pixel} of {view} in A and B"

    def _inspect_failed(self, exc: Exception) -> None:
        self.inspect_status.content = f"**error:** {' '.join(str(exc).split())}"

    def wait_idle(self, timeout: float = 60.0) -> bool:
        """Whether the inspector's worker went idle within ``timeout`` seconds (tests)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.worker.idle():
                return True
            time.sleep(0.02)
        return False

    def stop(self) -> None:
        self.worker.stop(timeout=10)
        self.server.stop()


def open_comparison(path_a: str | Path, path_b: str | Path, scene: str | Path | None = None, maps: str = "fused",
                    tolerance: float = 0.01, evaluate_fused: bool = True) -> Comparison:
    """Runs ``path_a`` and ``path_b`` compared as ``deepc compare`` compares them (their fused clouds scored, with
    ``evaluate_fused``)."""
    from engine.compare.comparison import compare_runs, reference_scene  # lazy: scenes, evaluation
    from engine.compare.sources import open_run

    a, b = open_run(path_a, maps), open_run(path_b, maps)
    return compare_runs(a, b, reference_scene(a, b, scene), tolerance, evaluate_fused=evaluate_fused)


def serve_compare(path_a: str, path_b: str, host: str = "127.0.0.1", port: int = 8080, scene: str | None = None,
                  maps: str = "fused", tolerance: float = 0.01) -> None:
    """Compare the runs, serve the compare mode until interrupted (``deepc view A --compare B``), then stop."""
    # bad runs fail before a port is taken; the fused clouds are scored once the viewer is open
    comparison = open_comparison(path_a, path_b, scene, maps, tolerance, evaluate_fused=False)
    hold(open_server(host, port), lambda server: CompareApp(comparison, host=host, server=server, score_fused=True),
         "viewer (compare)", host, port)
