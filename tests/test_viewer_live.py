"""The 3-D viewer live while a run runs (workbench/viewer/live.py), its hand-over to the tuning viewer, and both
in a real browser. Every wait has a timeout; servers, pages and run threads are stopped whatever happens."""

from __future__ import annotations

import io
import socket
import threading
import time

import numpy as np
import pytest
from conftest import SAMPLES, wait_for
from PIL import Image

from engine.core.observer import IterationEvent, NullObserver, ObserverList
from engine.core.resample import resample_depth
from engine.patchmatch import PatchMatchOptions
from engine.run.pipeline import PipelineOptions, run_pipeline
from engine.scene import load_scene
from workbench.maps.gt_depth import depth_error
from workbench.viewer.live import LiveViewer

pytestmark = pytest.mark.timeout(300)

SMALL_RUN = PatchMatchOptions(iterations=2, levels=2, geom_passes=1)


@pytest.fixture(scope="module")
def tiny():
    return load_scene(SAMPLES / "tiny")


@pytest.fixture
def live(tiny):
    viewer = LiveViewer(tiny, PipelineOptions(pipeline="full", patchmatch=SMALL_RUN), port=0)
    try:
        yield viewer
    finally:
        viewer.stop()


def _event(scene, view: int, level: int, iteration: int, step: int, noise: float, seed: int = 0) -> IterationEvent:
    """An iteration of ``view`` at ``level`` whose depth is the GT depth with relative noise ``noise``."""
    cam = scene.views[view].camera
    gt = scene.gt_depth(view)
    if level:
        gt = resample_depth(gt, (cam.width >> level, cam.height >> level))
    rng = np.random.default_rng(seed + view)
    depth = (gt * (1 + rng.uniform(-noise, noise, gt.shape))).astype(np.float32)
    normal = np.zeros((*gt.shape, 3), np.float32)
    normal[..., 2] = -1
    return IterationEvent(view, scene.views[view].name, level, "photometric", 0, iteration, step, depth, normal,
                          np.zeros(gt.shape, np.float32), np.zeros(gt.shape, np.uint32), 0.01)


def test_every_view_gets_a_thinned_cloud_and_within_1pct_is_scored_as_the_stream_scores_it(tiny, live):
    live.on_stage("patchmatch_pass", level=0, pass_kind="photometric", pass_index=0, iterations=2)
    events = [_event(tiny, v, 0, 1, v, noise=0.02, seed=3) for v in range(len(tiny.views))]
    for event in events:
        live.on_iteration(event)
    assert live.wait_idle(30)
    assert sorted(live._clouds) == list(range(len(tiny.views)))
    for view, handle in live._clouds.items():
        valid = events[view].depth > 0
        step = int(np.ceil(max(valid.shape) / live.max_size))
        assert 0 < len(handle.points) == int(valid[::step, ::step].sum())
        # the points lie on the view's rays at the estimated depth: projected back, they land on their pixels
        uv, z = tiny.views[view].camera.project(np.asarray(handle.points, np.float64))
        assert np.allclose(z, events[view].depth[::step, ::step][valid[::step, ::step]], rtol=1e-4)
        assert np.abs(uv / step - np.round(uv / step)).max() < 1e-3
    errors = [depth_error(e.depth, tiny.gt_depth(e.view)) for e in events]
    pooled = 100.0 * sum(e.within for e in errors) / sum(e.gt_pixels for e in errors)
    percent, views = live.within_so_far(0)
    assert views == len(tiny.views) and percent == pytest.approx(pooled)
    assert 20 < percent < 80  # ±2 % noise: about half the pixels within 1 %
    text = live.progress.content
    assert f"{len(tiny.views)} of {len(tiny.views)} views done in this pass" in text
    assert f"**{percent:.1f} %**" in text and "level 0" in text and "iteration 2/2" in text
    # the default colouring is the GT error: a bad view is red where a good one is green
    live.on_iteration(_event(tiny, 0, 0, 1, 99, noise=0.2))
    assert live.wait_idle(30)
    assert str(live.color_mode.value) == "depth error (%)"
    red = lambda handle: float(np.mean(handle.colors[:, 0].astype(int) - handle.colors[:, 1]))  # noqa: E731
    assert red(live._clouds[0]) > red(live._clouds[1]) + 50


def test_a_coarser_level_is_scored_against_gt_at_its_resolution(tiny, live):
    live.on_stage("patchmatch_pass", level=1, pass_kind="photometric", pass_index=0, iterations=2)
    live.on_iteration(_event(tiny, 2, 1, 0, 0, noise=0.0))
    assert live.wait_idle(30)
    percent, views = live.within_so_far(1)
    assert views == 1 and percent > 95  # the GT itself, resampled as the stream resamples it
    assert live.within_so_far(0) is None
    assert "(80×60)" in live.progress.content


def test_the_engine_never_waits_for_the_browser(tiny, live, monkeypatch):
    """A slow drawing (a busy browser) neither slows on_iteration down nor queues work: only the newest
    snapshot of each view is drawn."""
    drawn = []
    original = live._draw

    def slow(snapshot, confidence):
        time.sleep(0.3)
        drawn.append((snapshot.view, snapshot.depth[5, 5]))
        original(snapshot, confidence)

    monkeypatch.setattr(live, "_draw", slow)
    events = [_event(tiny, v, 0, it, it * 5 + v, noise=0.05, seed=it) for it in range(20) for v in range(2)]
    start = time.perf_counter()
    for event in events:
        live.on_iteration(event)
    assert time.perf_counter() - start < 0.25  # 40 iterations handed over while one draw alone takes 0.3 s
    assert live.wait_idle(30)
    assert len(drawn) < 10
    last = {e.view: e.depth[5, 5] for e in events}
    assert {view: value for view, value in drawn[-2:]} == last  # the newest of each view is what is shown


def test_the_panel_names_each_stage_after_patchmatch(tiny, live):
    seen = []
    for name, info in [("patchmatch_done", {}), ("patchmatch", {}),
                       ("confidence", {"confidence": [np.full((120, 160), 0.7, np.float32)] * len(tiny.views)}),
                       ("refinement", {}), ("fusion", {}), ("mesh", {})]:
        live.on_stage(name, **info)
        assert live.wait_idle(30)
        seen.append(live.progress.content)
    assert "counter maps" in seen[0]
    assert "confidence (DeepC network)" in seen[1]
    assert "refinement" in seen[2] and "fusion" in seen[3] and "evaluation" in seen[4]
    # once confidence is known it is offered as a colour, and a view is coloured by it at any level
    assert "confidence" in live.color_mode.options
    live.color_mode.value = "confidence"
    live.on_iteration(_event(tiny, 1, 1, 0, 0, noise=0.01))
    assert live.wait_idle(30)
    assert len(np.unique(live._clouds[1].colors, axis=0)) == 1  # 0.7 everywhere: one viridis colour


def test_the_fused_cloud_replaces_the_per_view_clouds_after_fusion(tiny, live):
    from engine.fusion import FusedCloud

    live.on_iteration(_event(tiny, 0, 0, 0, 0, noise=0.01))
    assert live.wait_idle(30) and live._clouds[0].visible
    n = 50
    xyz = np.random.default_rng(0).uniform(-1, 1, (n, 3)).astype(np.float32)
    cloud = FusedCloud(xyz, np.zeros((n, 3), np.float32), np.full((n, 3), 200, np.uint8), np.full(n, 2, np.int32),
                       np.ones(n, np.float32), np.zeros(n, np.int32), np.full(n, 2, np.int32))
    live.on_stage("fusion", cloud=cloud, pipeline="full")
    assert live.wait_idle(30)
    assert not live._clouds[0].visible and "now: **evaluation and metrics**" in live.progress.content
    live.on_iteration(_event(tiny, 1, 0, 0, 1, noise=0.01))  # (a late update stays hidden behind the cloud)
    assert live.wait_idle(30) and not live._clouds[1].visible


def test_confidence_given_during_patchmatch_colours_its_view(tiny, live):
    live.on_iteration(_event(tiny, 0, 0, 0, 0, noise=0.01))
    assert live.wait_idle(30)
    live.color_mode.value = "depth"
    ramp = np.tile(np.linspace(0, 1, 160, dtype=np.float32), (120, 1))
    live.set_confidence(0, ramp)
    assert live.color_mode.options[1] == "confidence"
    live.color_mode.value = "confidence"
    assert live.wait_idle(30)
    colors = live._clouds[0].colors
    assert len(np.unique(colors, axis=0)) > 20  # the ramp, re-coloured without a new iteration


def test_without_gt_the_default_colour_is_depth(tmp_path, temple_copy):
    scene = load_scene(temple_copy)
    viewer = LiveViewer(scene, PipelineOptions(), port=0)
    try:
        assert viewer.color_mode.options == ("depth",) and viewer.color_mode.value == "depth"
        assert "within 1 %" not in viewer._progress_text(viewer._progress)
    finally:
        viewer.stop()
    with pytest.raises(OSError), socket.create_connection(("127.0.0.1", viewer.port), timeout=2):
        pass


# ---- in a real browser ------------------------------------------------------------------------------------

class _Gate(NullObserver):
    """Holds the run at the end of PatchMatch until released (at most ``timeout`` seconds)."""

    def __init__(self, timeout: float = 120.0):
        self.reached, self.go, self.timeout = threading.Event(), threading.Event(), timeout

    def on_stage(self, name: str, **info) -> None:
        if name == "patchmatch_done":
            self.reached.set()
            self.go.wait(self.timeout)


def _canvas(page) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(page.locator("canvas").first.screenshot(timeout=60_000))))[..., :3]


@pytest.mark.browser
def test_in_chromium_points_show_during_the_run_and_the_tuning_panel_after_it(browser_context, tiny, tmp_path):
    from support.browser import dismiss_software_webgl_notice
    from workbench.viewer.app import ViewerApp
    from workbench.viewer.session import ViewerSession

    options = PipelineOptions(pipeline="fast", patchmatch=SMALL_RUN)
    live = LiveViewer(tiny, options, port=0)
    gate = _Gate()
    outcome: dict = {}

    def run() -> None:
        try:
            outcome["result"] = run_pipeline(tiny, tmp_path / "out", options, observer=ObserverList([live, gate]))
        except BaseException as exc:  # noqa: BLE001 - reported by the test below
            outcome["error"] = exc

    thread = threading.Thread(target=run, name="test-live-run", daemon=True)
    page = app = None
    try:
        page = browser_context.new_page()
        page.goto(f"http://127.0.0.1:{live.port}/")
        page.get_by_text("Connected").wait_for()
        wait_for(lambda: len(live.server.get_clients()) == 1)
        clients = set(live.server.get_clients())
        page.get_by_text("starting").first.wait_for()
        thread.start()
        wait_for(gate.reached.is_set, timeout=240)
        assert live.wait_idle(30) and "result" not in outcome and "error" not in outcome  # the run has not ended
        page.get_by_text("PatchMatch done").first.wait_for()
        assert len(live._clouds) == len(tiny.views)
        dismiss_software_webgl_notice(page)
        page.wait_for_timeout(1500)
        with_points = _canvas(page)
        for handle in live._clouds.values():
            handle.visible = False
        page.wait_for_timeout(1500)
        without = _canvas(page)
        changed = np.abs(with_points.astype(int) - without.astype(int)).max(axis=2) > 40
        assert changed.mean() > 0.01, "the live clouds drew nothing in the browser"
        for handle in live._clouds.values():
            handle.visible = True
        gate.go.set()
        thread.join(240)
        assert "result" in outcome, outcome.get("error")
        app = ViewerApp(ViewerSession.open(tmp_path / "out"), server=live.hand_over())
        live.release(app)
        page.get_by_text("Reset to the run's settings").wait_for()
        page.get_by_text("run: fast").first.wait_for()  # on the run's own settings
        assert app.pipeline.value == "fast" and app.fused_confidence_tau.value == options.confidence.tau
        assert app.wait_idle(120)
        page.get_by_text(f"{len(app.cloud):,} points").first.wait_for()
        assert page.get_by_text("views done in this pass").count() == 0  # the progress panel is gone
        assert page.get_by_text("PatchMatch done").count() == 0
        assert set(app.server.get_clients()) == clients  # the same connection: no reload, no restart
    finally:
        gate.go.set()
        if page is not None:
            page.close()
        if app is not None:
            app.stop()
        live.stop()
        thread.join(120)
    assert not thread.is_alive()
    assert not [t for t in threading.enumerate() if t.name.startswith(("deepc-live-viewer", "deepc-viewer"))
                and t.is_alive()]
    with pytest.raises(OSError), socket.create_connection(("127.0.0.1", live.port), timeout=2):
        pass


def test_deepc_run_interrupted_during_patchmatch_stops_the_live_viewer(tmp_path):
    """SIGINT while the live 3-D viewer serves a running ``deepc run``: exit status 130 and its port closed."""
    import signal
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-m", "workbench.cli", "run", str(SAMPLES / "small"), "--out",
                             str(tmp_path / "out"), "--port", "0"], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    port = None
    try:
        deadline = time.monotonic() + 240
        for line in proc.stdout:
            if line.startswith("live 3-D viewer: http://127.0.0.1:"):
                port = int(line.split()[3].rsplit(":", 1)[1])
                break
            assert time.monotonic() < deadline, line
        assert port
        # keep reading its output: a full pipe would block the run's progress writes and so its stop
        threading.Thread(target=proc.stdout.read, daemon=True).start()
        socket.create_connection(("127.0.0.1", port), timeout=20).close()  # serving while PatchMatch runs
        proc.send_signal(signal.SIGINT)
        code = proc.wait(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
    assert code == 130
    assert not (tmp_path / "out" / "metrics.json").exists()  # stopped during the run, not after it
    with pytest.raises(OSError), socket.create_connection(("127.0.0.1", port), timeout=2):
        pass


def test_a_pass_start_names_no_view_until_one_reports(tiny, live):
    """At a pass start the panel neither shows "view None" nor the previous pass's view and map size."""
    live.on_stage("patchmatch_pass", level=1, pass_kind="photometric", pass_index=0, iterations=2)
    live.on_iteration(_event(tiny, 3, 1, 1, 0, noise=0.0))
    assert live.wait_idle(30) and "view 3: " in live.progress.content and "(80×60)" in live.progress.content
    live.on_stage("patchmatch_pass", level=0, pass_kind="photometric", pass_index=0, iterations=2)
    assert live.wait_idle(30)
    text = live.progress.content
    assert "None" not in text and "view 3" not in text and "(80×60)" not in text
    assert "level 0" in text and "first view to come" in text and f"0 of {len(tiny.views)} views done" in text
    live.on_iteration(_event(tiny, 1, 0, 0, 1, noise=0.0))
    assert live.wait_idle(30) and "view 1: " in live.progress.content and "(160×120)" in live.progress.content


def test_one_view_is_one_view_and_the_error_colour_names_its_unit(tiny):
    import copy

    one = copy.copy(tiny)
    one.views = tiny.views[:1]
    viewer = LiveViewer(one, PipelineOptions(pipeline="vanilla", patchmatch=SMALL_RUN), port=0)
    try:
        viewer.on_stage("patchmatch_pass", level=0, pass_kind="photometric", pass_index=0, iterations=2)
        assert viewer.wait_idle(30)
        assert "· 1 view ·" in viewer._panel[0].content and "0 of 1 view done" in viewer.progress.content
        # "error" is the depth error in % of the GT depth here, the distance to GT points in cm in the tuning viewer
        assert viewer.color_mode.value == "depth error (%)" and "% of the GT depth" in viewer.legend.content
        assert viewer.live_point_size.label == "Point size (× pixel)"  # relative to a thinned pixel's footprint
    finally:
        viewer.stop()
