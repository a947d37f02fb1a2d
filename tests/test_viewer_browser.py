"""The live-tuning viewer in a real browser (Debian chromium + playwright).

Every wait has a timeout; the server and the pages are closed whatever happens.
"""

from __future__ import annotations

import io

import numpy as np
import pytest
from conftest import open_page, running_viewer, wait_for
from PIL import Image

pytestmark = [pytest.mark.browser, pytest.mark.timeout(300)]


@pytest.fixture
def app(fake_run):
    with running_viewer(fake_run) as viewer:
        yield viewer


def _screenshot_is_not_blank(page) -> np.ndarray:
    image = np.asarray(Image.open(io.BytesIO(page.locator("canvas").first.screenshot(timeout=60_000))))
    assert image[..., :3].std() > 10, "the 3-D canvas rendered nothing"
    return image


def _slider_thumb(page, handle):
    return page.locator(f'[id="{handle._impl.uuid}"] [role="slider"]')


def test_cloud_renders_and_the_confidence_slider_updates_points_and_metrics(browser_context, app):
    page = open_page(browser_context, app)
    try:
        page.get_by_text("points").first.wait_for()
        _screenshot_is_not_blank(page)
        # The fake run is a fast run with τ 0.1: it opens so. Switch to vanilla and back in the browser, then
        # raise the threshold by keyboard.
        assert app.pipeline.value == "fast" and app.fused_confidence_tau.value == 0.1
        page.locator(f'[id="{app.pipeline._impl.uuid}"]').click()
        page.get_by_role("option", name="vanilla").click()
        wait_for(lambda: app.cloud_params is not None and app.cloud_params.pipeline == "vanilla" and app.wait_idle(1))
        page.locator(f'[id="{app.pipeline._impl.uuid}"]').click()
        page.get_by_role("option", name="fast").click()
        wait_for(lambda: app.cloud_params is not None and app.cloud_params.pipeline == "fast" and app.wait_idle(1))
        before_points, before_text = len(app.cloud), app.metrics.content
        thumb = _slider_thumb(page, app.fused_confidence_tau)
        thumb.focus()
        for _ in range(10):
            page.keyboard.press("ArrowRight")
        wait_for(lambda: app.fused_confidence_tau.value >= 0.15 and app.wait_idle(1)
                 and app.cloud_params.fused_confidence_tau >= 0.15)
        page.locator(f'[id="{app.fused_confidence_tau._impl.uuid}"]').wait_for()
        assert len(app.cloud) < before_points
        assert app.metrics.content != before_text
        # The browser shows the new count.
        page.get_by_text(f"{len(app.cloud):,} points").wait_for()
    finally:
        page.close()


def test_choosing_the_paper_fusion_preset_in_the_browser(browser_context, app):
    page = open_page(browser_context, app)
    try:
        page.get_by_text("points").first.wait_for()
        default = len(app.cloud)
        page.locator(f'[id="{app.preset._impl.uuid}"]').click()
        page.get_by_role("option", name="deepc", exact=True).click()
        wait_for(lambda: app.min_views.value == 3 and not app.per_pixel.value and app.cloud_params is not None
                 and app.cloud_params.fusion.min_num_pixels == 3 and app.wait_idle(1))
        assert len(app.cloud) < default
        page.get_by_text(f"{len(app.cloud):,} points").wait_for()
    finally:
        page.close()


def test_clicking_a_camera_shows_its_maps(browser_context, app):
    page = open_page(browser_context, app)
    try:
        view = app.session.scene.views[3]
        cam = view.camera
        client = next(iter(app.server.get_clients().values()))
        # Look straight at camera 3's frustum from in front of it, so it fills the middle of the canvas.
        client.camera.position = cam.center + cam.R[2] * app.frustum_scale * 2.5
        client.camera.look_at = cam.center + cam.R[2] * app.frustum_scale * 0.5
        client.camera.up_direction = -cam.R[1]
        page.wait_for_timeout(1500)
        box = page.locator("canvas").first.bounding_box()
        page.mouse.click(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        wait_for(lambda: "view 3:" in app.view_title.content)
        page.get_by_text(f"view 3: {view.name}").wait_for()
        assert page.locator("img").count() >= 5  # image, depth, normal, counter, confidence
    finally:
        page.close()


def test_two_tabs_share_one_session(browser_context, app):
    first, second = open_page(browser_context, app), open_page(browser_context, app)
    try:
        app.min_views.value = 5  # as if a user moved it: runs the callbacks
        assert app.wait_idle(60)
        text = f"{len(app.cloud):,} points"
        first.get_by_text(text).wait_for()
        second.get_by_text(text).wait_for()
    finally:
        first.close()
        second.close()


def test_a_new_page_opens_looking_through_the_first_camera(browser_context, app):
    """`deepc view` opens as the live hand-over does: behind camera 0, looking where it looks (not viser's oblique
    default), and the client reports that pose back."""
    scene = app.session.scene
    first = scene.views[0].camera
    depth = float(np.median([np.mean(v.depth_range) for v in scene.views]))
    page = open_page(browser_context, app)
    try:
        client = next(iter(app.server.get_clients().values()))
        home = first.center - first.R[2] * 0.2 * depth
        wait_for(lambda: np.linalg.norm(client.camera.position - home) < 1e-3 * depth)
        direction = client.camera.look_at - client.camera.position
        assert np.dot(direction / np.linalg.norm(direction), first.R[2]) > 0.999
    finally:
        page.close()
