"""The viewer's pixel inspector without a browser: requests, picking, the map plane, the region re-run and bad
input, driven by hand-made traces (support/probe_traces.py) in place of the engine's probe."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import SAMPLES, wait_for

from support.probe_traces import make_trace
from workbench.trace.figures import FONT_PT, PANEL_PX, candidate_table_html, summary_markdown, trace_figure, trace_plot
from workbench.trace.windows import window_corners, window_thumbnails

pytestmark = pytest.mark.timeout(300)



def test_figures_of_a_trace(noisy_run):
    from engine.scene import load_scene

    scene = load_scene(SAMPLES / "tiny")
    trace = make_trace(scene, 0, 40, 30, 3.0)
    image = trace_figure(trace, 3)
    assert image.dtype == np.uint8 and image.shape == (2 * 500, 2 * PANEL_PX, 3) and image.std() > 10
    table = candidate_table_html(trace, 3)
    assert table.count("<tr") == 1 + 2 * len(trace["iterations"][3]["candidates"])  # a candidate, its view costs
    assert "pattern:0" in table and "L1 p1 i0" in table
    text = summary_markdown(trace, "0: view_000.png")
    assert "pixel (40, 30)" in text and "counter: 2 of 4" in text and "GT" in text


def test_trace_text_is_legible_and_the_candidate_table_fits_at_the_default_panel_width(noisy_run):
    """Shown at the default panel width (viser's 20 em), no text of the trace figure is under 10 px (it was
    about 6 px), and the candidate table has no row wider than three columns, however many source views."""
    from matplotlib.text import Text

    from engine.scene import load_scene

    trace = make_trace(load_scene(SAMPLES / "tiny"), 0, 40, 30, 3.0)
    figure = trace_plot(trace, 3, title="pixel (40, 30) · 0: view_000.png · after re-run")
    figure.canvas.draw()
    image_width = figure.get_figwidth() * figure.dpi
    texts = [t for t in figure.findobj(Text) if t.get_visible() and t.get_text().strip()]
    assert len(texts) > 20
    shown_px = [t.get_fontsize() * figure.dpi / 72 * PANEL_PX / image_width for t in texts]
    assert min(shown_px) >= 10, min(shown_px)
    renderer = figure.canvas.get_renderer()
    ticks = {id(t) for ax in figure.axes for t in ax.get_xticklabels() + ax.get_yticklabels()}
    for text in (t for t in texts if id(t) not in ticks):  # titles, labels and legends are not cut off
        box = text.get_window_extent(renderer)
        assert box.x0 >= -1 and box.x1 <= image_width + 1, text.get_text()
    wide = dict(trace, source_views=[f"view_{i:03d}.png" for i in range(12)])
    for step in wide["iterations"]:
        for cand in step["candidates"]:
            cand["view_costs"] = [0.5] * 12
    table = candidate_table_html(wide, 3)
    assert "width:100%" in table and "table-layout:fixed" in table
    rows = table.split("<tr")[1:]
    assert all(row.count("<td") + row.count("<th") <= 3 for row in rows)
    assert table.count(">view_0") == 12 * len(wide["iterations"][3]["candidates"])  # every view's cost is there


def test_window_corners_lie_on_the_plane_and_project_back(noisy_run):
    from engine.scene import load_scene

    scene = load_scene(SAMPLES / "tiny")
    camera = scene.views[0].camera
    normal = np.array([0.3, -0.2, -0.93])
    normal /= np.linalg.norm(normal)
    corners = window_corners(camera, 50, 40, 4.0, normal, 5)
    uv, z = camera.project(corners)
    np.testing.assert_allclose(uv, [[45, 35], [55, 35], [55, 45], [45, 45]], atol=1e-6)
    centre = np.linalg.inv(camera.K_idx) @ np.array([50, 40, 1.0]) * 4.0
    offsets = camera.world_to_camera(corners) - centre
    np.testing.assert_allclose(offsets @ normal, 0.0, atol=1e-9)
    images = [(np.asarray(scene.image(i)) * 255).astype(np.uint8) for i in (0, 1, 2)]
    strip = window_thumbnails(images, [scene.views[i].camera for i in (0, 1, 2)], ["a", "b", "c"], 50, 40, 4.0,
                              normal, 5, {"b"}, [0.3, None])
    assert strip.shape[1] == 3 * strip.shape[0] - 3 * 14


def test_typed_pixel_fills_the_inspector(inspector_app):
    inspector = inspector_app.inspector
    inspector.inspect(1, 40, 30)
    wait_for(lambda: inspector.trace is not None and inspector.wait_idle(1))
    assert inspector.trace["view"] == "view_001.png" and (inspector.trace["x"], inspector.trace["y"]) == (40, 30)
    assert "pixel (40, 30) of view 1: view_001.png" in inspector.summary.content
    assert inspector.plots.visible and inspector.windows.visible
    assert "winner in bold" in inspector.table.content
    assert tuple(inspector.pixel.value) == (40, 30) and inspector.entry.max == len(inspector.trace["iterations"]) - 1
    depth = inspector_app.session.data[1].depth[30, 40]
    assert inspector.trace["final"]["depth"] == pytest.approx(depth)
    # another entry of the trace: its candidates
    inspector.entry.value = 2
    assert "L1 p0 i2" in inspector.table.content
    # one probe traced the pixel's 8 neighbours too: the same pixel and a neighbour come from the cache
    assert inspector_app.hand.calls[-1][2][0] == (40, 30) and len(inspector_app.hand.calls[-1][2]) == 9
    calls = len(inspector_app.hand.calls)
    inspector.inspect(1, 40, 30)
    assert inspector.wait_idle(10) and len(inspector_app.hand.calls) == calls
    inspector.inspect(1, 41, 31)
    wait_for(lambda: inspector.trace["x"] == 41 and inspector.wait_idle(1))
    assert len(inspector_app.hand.calls) == calls
    # at the image corner only the neighbours inside the image come along
    inspector.inspect(1, 0, 0)
    wait_for(lambda: inspector.trace["x"] == 0 and inspector.wait_idle(1))
    assert sorted(inspector_app.hand.calls[-1][2]) == [(0, 0), (0, 1), (1, 0), (1, 1)]
    # the re-run box is centred on the pixel, inside the image (tiny: 160x120)
    assert tuple(inspector.box_origin.value) == (0, 0) and tuple(inspector.box_size.value) == (64, 64)
    inspector.inspect(1, 159, 119)
    wait_for(lambda: inspector.trace["x"] == 159 and inspector.wait_idle(1))
    assert tuple(inspector.box_origin.value) == (96, 56)


@pytest.mark.parametrize(("view", "x", "y", "message"), [
    (0, 500, 20, "outside view"), (0, -1, 3, "outside view"), ("nope.png", 3, 3, "no view 'nope.png'")])
def test_bad_pixel_or_view_is_a_message_and_the_panel_goes_on(inspector_app, view, x, y, message):
    inspector = inspector_app.inspector
    inspector.inspect(view, x, y)
    wait_for(lambda: "cannot probe" in inspector.status.content)
    assert message in inspector.status.content and "\n" not in inspector.status.content
    inspector.inspect(0, 10, 10)
    wait_for(lambda: inspector.trace is not None and inspector.trace["x"] == 10 and inspector.wait_idle(1))


def test_a_click_on_the_cloud_picks_the_pixel_that_holds_the_point(inspector_app):
    inspector = inspector_app.inspector
    view = inspector_app.session.scene.views[2]
    depth = inspector_app.session.data[2].depth
    x, y = 70, 55
    assert depth[y, x] > 0
    point = view.camera.backproject(depth)[y, x]
    inspector_app.select_view(2)
    # a ray from the camera through that pixel, as a browser click sends it
    direction = point - view.camera.center
    picked = inspector.pick(view.camera.center, direction / np.linalg.norm(direction))
    assert picked is not None and picked[0] == 2 and abs(picked[1] - x) <= 1 and abs(picked[2] - y) <= 1
    # a ray into the void picks nothing
    assert inspector.pick(view.camera.center, -view.camera.R[2]) is None


def test_the_map_plane_turns_a_click_into_its_pixel(inspector_app):
    inspector = inspector_app.inspector
    inspector_app.select_view(3)
    inspector.plane_kind.value = "depth"
    assert inspector.map_plane is not None and inspector._plane_view == 3
    assert [f.visible for f in inspector_app.frustums] == [True, True, True, False, True]  # the plane stands in for it
    camera = inspector_app.session.scene.views[3].camera
    ray = camera.R.T @ (np.linalg.inv(camera.K_idx) @ np.array([33.2, 71.8, 1.0]))
    picked = inspector.pick(camera.center, ray / np.linalg.norm(ray))
    assert picked[:3] == (3, 33, 72) and picked[3] == "map plane"
    inspector_app.select_view(1)  # the plane follows the view
    assert inspector._plane_view == 1
    inspector.plane_kind.value = "off"
    assert not inspector.map_plane.visible and all(f.visible for f in inspector_app.frustums)
    assert inspector.pick(camera.center, ray / np.linalg.norm(ray))[3] != "map plane"


def test_region_rerun_shows_before_after_and_the_new_trace(inspector_app):
    inspector = inspector_app.inspector
    data = inspector_app.session.data[0].depth
    gt = inspector_app.session.scene.gt_depth(0)
    wrong = np.argwhere((np.abs(data - gt) > 0.05 * gt) & (gt > 0) & (data > 0))
    y, x = (int(v) for v in wrong[len(wrong) // 2])
    inspector_app.select_view(0)
    inspector.inspect(0, x, y)
    wait_for(lambda: inspector.trace is not None and inspector.trace["x"] == x and inspector.wait_idle(1))
    assert "✘" in inspector.summary.content
    before_trace = inspector.trace
    inspector.region_inputs["window"].value = 7
    inspector.region_inputs["iterations"].value = 4
    inspector.rerun_from_form()
    wait_for(lambda: inspector.region is not None and inspector.wait_idle(1))
    call = inspector_app.hand.calls[-1]
    assert call[0] == "region" and call[5] == {"window": 7, "iterations": 4}
    x0, y0, w, h = call[2]
    assert x0 <= x < x0 + w and y0 <= y < y0 + h
    assert inspector.region_image.visible and "within 1 % of GT" in inspector.region_numbers.content
    assert inspector.region.within_1pct_after > inspector.region.within_1pct_before
    assert inspector.trace is not before_trace and inspector.compare is before_trace
    assert "after re-run" in inspector.summary.content and "✔" in inspector.summary.content


def test_region_outside_the_image_is_a_message(inspector_app):
    inspector = inspector_app.inspector
    inspector.rerun(0, (150, 100, 64, 64))
    wait_for(lambda: "cannot re-run" in inspector.region_status.content)
    assert "not inside view" in inspector.region_status.content


def test_a_trace_in_rerun_with_the_probe_layout(inspector_app, tmp_path):
    from workbench.rerun.replay import default_layout, layout_file, recording_contents

    inspector = inspector_app.inspector
    inspector.inspect(0, 40, 30)
    wait_for(lambda: inspector.trace is not None and inspector.wait_idle(1))
    path = inspector.save_rrd()
    assert path.is_file() and path.parent.name == "exports" and "wrote" in inspector.status.content
    contents = recording_contents(path).contents
    base = "/probe/000_view_000.png/40_30"
    for part in ("cost", "depth", "gt_depth", "candidates", "ray", "gt", "windows", "candidates_table", "summary"):
        assert f"{base}/{part}" in contents.entities, part
    assert "/maps/000_view_000.png/depth" in contents.entities
    assert "view_iteration" in contents.timelines
    assert default_layout(path) == "probe"
    from layouts import probed_pixels

    assert probed_pixels(contents, contents.views[0]) == ["40_30"]
    assert layout_file(path, "probe", tmp_path).is_file()


@pytest.fixture(scope="module")
def engine_run(tmp_path_factory):
    """A real vanilla run of sample_scenes/tiny with its pass history (short schedule)."""
    from engine.patchmatch.options import PatchMatchOptions
    from engine.run.pass_history import HISTORY_DIR, PassHistory
    from engine.run.pipeline import PipelineOptions, run_pipeline
    from engine.scene import load_scene

    out = tmp_path_factory.mktemp("engine_run")
    options = PipelineOptions(patchmatch=PatchMatchOptions(iterations=1, levels=2, geom_passes=1))
    run_pipeline(load_scene(SAMPLES / "tiny"), out, options, history=PassHistory(out / HISTORY_DIR))
    return out


def test_the_engine_probe_and_region_rerun_in_the_inspector(engine_run):
    """The inspector on the engine's own probe_run / rerun_region: the real schema fills every widget."""
    from workbench.viewer.app import ViewerApp
    from workbench.viewer.session import ViewerSession

    inspector_app = ViewerApp(ViewerSession.open(engine_run), port=0)
    try:
        assert inspector_app.wait_idle(120)
        inspector = inspector_app.inspector
        inspector.plane_kind.value = "GT error"
        inspector.inspect(0, 70, 50)
        wait_for(lambda: inspector.trace is not None and inspector.wait_idle(1), timeout=300)
        trace = inspector.trace
        assert (trace["view"], trace["x"], trace["y"]) == ("view_000.png", 70, 50)
        assert trace["final"]["depth"] == pytest.approx(float(inspector_app.session.data[0].depth[50, 70]), rel=1e-6)
        assert "GT" in inspector.summary.content and "counter:" in inspector.summary.content
        assert inspector.plots.visible and inspector.windows.visible and "winner in bold" in inspector.table.content
        for entry in (0, len(trace["iterations"]) // 2):
            inspector.entry.value = entry
            assert "winner in bold" in inspector.table.content
        inspector.rerun(0, (50, 30, 40, 40), overrides={"window": 7})
        wait_for(lambda: inspector.region is not None and inspector.wait_idle(1), timeout=300)
        assert inspector.region.depth_after.shape == (40, 40)
        assert "within 1 % of GT" in inspector.region_numbers.content
        assert inspector.compare is trace and "after re-run" in inspector.summary.content
        inspector.inspect(0, 70, 500)
        wait_for(lambda: "cannot probe" in inspector.status.content and inspector.wait_idle(1))
        assert "outside view" in inspector.status.content
    finally:
        inspector_app.stop()


def test_a_run_without_pass_history_says_so(noisy_run):
    """A run folder made without history (here: one that never ran PatchMatch) cannot be probed: one line."""
    from workbench.viewer.app import ViewerApp
    from workbench.viewer.session import ViewerSession

    inspector_app = ViewerApp(ViewerSession.open(noisy_run), port=0)  # the engine's own probe
    try:
        inspector_app.inspector.inspect(0, 10, 10)
        inspector = inspector_app.inspector
        wait_for(lambda: "cannot probe" in inspector.status.content and inspector.wait_idle(1))
        assert "history" in inspector_app.inspector.status.content and inspector_app.inspector.trace is None
    finally:
        inspector_app.stop()


def test_pass_labels_of_a_trace_plot_never_overlap():
    """At the panel's width a 21-entry trace of 3 levels × 3 passes has no room for 'L2 p0' at every pass start:
    the levels are labelled instead; a long trace labels every pass."""
    from workbench.trace.figures import fitting_labels

    starts = [(0, "L2 p0"), (2, "L2 p1"), (4, "L2 p2"), (6, "L1 p0"), (9, "L1 p1"), (12, "L1 p2"), (15, "L0 p0"),
              (18, "L0 p1"), (20, "L0 p2")]
    font_px = FONT_PT * 100 / 72
    tight = fitting_labels(starts, 0.75 * PANEL_PX / 21, font_px)
    assert [name for _, name in tight] == ["L2", "L1", "L0"]
    roomy = fitting_labels(starts, 40.0, font_px)
    assert roomy == starts
    for labels, px in ((tight, 0.75 * PANEL_PX / 21), (roomy, 40.0)):
        spans = [(start * px, start * px + 0.6 * font_px * len(name)) for start, name in labels]
        assert all(a[1] <= b[0] for a, b in zip(spans, spans[1:], strict=False))
