"""The pixel inspector in a real browser (Debian chromium + playwright): a click fills the inspector with the
right pixel, a region re-run changes the maps and the trace, bad input is a message. Hand-made traces
(support/probe_traces.py) stand in for the engine's probe, so the clicks and the panel are what is tested."""

from __future__ import annotations

import time

import numpy as np
import pytest
from conftest import wait_for

pytestmark = [pytest.mark.browser, pytest.mark.timeout(300)]



def _open(context, inspector_app):
    from support.browser import dismiss_software_webgl_notice

    page = context.new_page()
    page.goto(f"http://127.0.0.1:{inspector_app.port}/")
    wait_for(lambda: len(inspector_app.server.get_clients()) > 0)
    page.get_by_text("Connected").wait_for()
    page.get_by_text("points").first.wait_for()
    dismiss_software_webgl_notice(page)
    page.get_by_text("Inspector", exact=True).click()  # the folder opens
    page.get_by_role("button", name="Look through the view").wait_for()
    return page


def _inspect_typed(page, inspector, x: int, y: int) -> None:
    """Type pixel (x, y), press Inspect pixel and wait until the browser shows its trace."""
    inspector.pixel.value = (x, y)
    page.get_by_role("button", name="Inspect pixel").click()
    wait_for(lambda: inspector.trace is not None and inspector.wait_idle(1))
    page.get_by_text(f"pixel ({x}, {y}) of view 0").first.wait_for()


def _look_through_view(page, inspector_app):
    camera = inspector_app.session.scene.views[inspector_app.selected_view].camera
    client = next(iter(inspector_app.server.get_clients().values()))
    page.get_by_role("button", name="Look through the view").click()
    wait_for(lambda: abs(client.camera.position - camera.center).max() < 1e-3 * (1 + abs(camera.center).max()))
    time.sleep(1.0)  # the browser's camera follows on its next frame


def test_a_click_on_the_map_plane_fills_the_inspector_with_that_pixel(browser_context, inspector_app):
    page = _open(browser_context, inspector_app)
    try:
        inspector = inspector_app.inspector
        inspector.plane_kind.value = "depth"
        _look_through_view(page, inspector_app)
        box = page.locator('canvas[data-engine^="three.js"]').bounding_box()

        def click(fx: float, fy: float) -> None:
            page.mouse.click(box["x"] + fx * box["width"], box["y"] + fy * box["height"])

        camera = inspector_app.session.scene.views[0].camera
        cx, cy = camera.K_idx[0, 2], camera.K_idx[1, 2]
        # The client's camera now is view 0's (same vertical field of view): the canvas centre is the principal
        # point, and a quarter of the canvas height below it is a quarter of the image height lower.
        click(0.5, 0.75)
        wait_for(lambda: inspector.trace is not None and inspector.wait_idle(1))
        x, y = inspector.trace["x"], inspector.trace["y"]
        assert abs(x - cx) <= 1.5 and abs(y - cy - camera.height / 4) <= 1.5, (x, y, cx, cy)
        assert "map plane" in inspector.status.content
        page.get_by_text(f"pixel ({x}, {y}) of view 0: view_000.png").first.wait_for()
        page.get_by_text("winner in bold").first.wait_for()
        # with the plane off the same click hits the cloud and inspects the pixel that holds the point
        inspector.plane_kind.value = "off"
        click(0.5, 0.5)
        wait_for(lambda: "cloud point" in inspector.status.content and inspector.wait_idle(1))
        x, y = inspector.trace["x"], inspector.trace["y"]
        assert abs(x - cx) <= 6 and abs(y - cy) <= 6
        page.get_by_text(f"pixel ({x}, {y}) of view 0: view_000.png").first.wait_for()
    finally:
        page.close()


def test_region_rerun_in_the_browser_changes_the_maps_and_the_trace(browser_context, inspector_app):
    page = _open(browser_context, inspector_app)
    try:
        inspector = inspector_app.inspector
        _inspect_typed(page, inspector, 40, 30)
        before = inspector.trace
        page.get_by_text("Re-run region", exact=True).first.click()  # the folder opens
        page.get_by_role("button", name="Re-run region").click()
        wait_for(lambda: inspector.region is not None and inspector.wait_idle(1))
        page.get_by_text("within 1 % of GT").first.wait_for()
        page.get_by_text("after re-run").first.wait_for()
        assert inspector.trace is not before and inspector.compare is before
        assert (inspector.region.depth_after != inspector.region.depth_before).any()
    finally:
        page.close()


def test_bad_pixel_and_unknown_view_are_messages_in_the_browser(browser_context, inspector_app):
    page = _open(browser_context, inspector_app)
    try:
        inspector = inspector_app.inspector
        inspector.pixel.value = (500, 20)
        page.get_by_role("button", name="Inspect pixel").click()
        page.get_by_text("cannot probe: pixel (500, 20) is outside view view_000.png").wait_for()
        inspector.inspect("no_such_view.png", 3, 3)
        page.get_by_text("cannot probe: no view 'no_such_view.png'").wait_for()
        # the inspector still works
        inspector.pixel.value = (12, 14)
        page.get_by_role("button", name="Inspect pixel").click()
        page.get_by_text("pixel (12, 14) of view 0").first.wait_for()
    finally:
        page.close()


def test_a_saved_trace_replays_in_the_rerun_web_viewer_with_the_probe_layout(browser_context, inspector_app, tmp_path):
    from test_replay_browser import _panels_show, blueprint_titles

    from workbench.rerun.replay import WebViewer, default_layout, layout_file

    inspector = inspector_app.inspector
    inspector.inspect(0, 40, 30)
    wait_for(lambda: inspector.trace is not None and inspector.wait_idle(1))
    path = inspector.save_rrd()
    assert default_layout(path) == "probe"
    titles = blueprint_titles(layout_file(path, "probe", tmp_path))
    assert {"cost · pixel 40_30", "candidates on the pixel's ray", "window in each source image"} <= set(titles)
    def drawn(pixels):  # the source windows: image pixels over much of the panel, not an empty panel's caption
        flat = pixels.reshape(-1, pixels.shape[-1]).astype(int)
        colours, counts = np.unique(flat, axis=0, return_counts=True)
        share = float(np.mean(np.abs(flat - colours[counts.argmax()]).sum(axis=1) > 30))
        return None if share > 0.2 else f"{100 * share:.0f} % of the panel off its background (want 20 %)"

    with WebViewer(path) as viewer:
        _panels_show(browser_context, viewer, path, "probe", None, {"window in each source image": drawn})


def test_at_the_default_panel_width_figures_are_shown_at_their_size_and_the_table_fits(browser_context,
                                                                                      inspector_app):
    """The trace figure and the window thumbnails are drawn for the default panel: chromium shows them at (about)
    the width they were drawn for, so their text stays the size it was set (11 px, not 6); the candidate table
    needs no horizontal scrolling."""
    from workbench.trace.figures import PANEL_PX, PIXEL_RATIO

    page = _open(browser_context, inspector_app)
    try:
        _inspect_typed(page, inspector_app.inspector, 40, 30)
        page.get_by_text("winner in bold").first.wait_for()
        page.wait_for_timeout(1000)
        shown = page.locator("img").evaluate_all(
            "images => images.filter(i => i.naturalWidth > 0 && i.offsetParent !== null)"
            ".map(i => [i.naturalWidth, i.clientWidth])")
        figure = [c for n, c in shown if n == PIXEL_RATIO * PANEL_PX]
        assert figure and abs(figure[0] - PANEL_PX) <= 0.1 * PANEL_PX, shown
        table = page.locator("table").filter(has_text="origin").first
        fits = table.evaluate("t => [t.scrollWidth, t.parentElement.clientWidth, t.closest('div').scrollWidth,"
                              " t.closest('div').clientWidth]")
        assert fits[0] <= fits[1] + 1 and fits[2] <= fits[3] + 1, fits
    finally:
        page.close()
