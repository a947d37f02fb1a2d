"""The viewer's point and triangle budgets in a real browser (Debian chromium + playwright, software WebGL): a cloud
over the budget is sent thinned and the page says so, the budget control changes what is sent, and the run's
mesh is sent only when shown, decimated to its triangle budget. Counts are read server side from viser's scene.
Every wait has a timeout; the server and the pages are always closed."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import SAMPLES, open_page, running_viewer, wait_for

from engine.meshing import TriangleMesh, write_mesh_ply
from support.fake_run import make_fake_run

pytestmark = [pytest.mark.browser, pytest.mark.timeout(400)]

SMALL_BUDGET = 20_000  # well under the tiny fake run's cloud


def _element(page, handle):
    return page.locator(f'[id="{handle._impl.uuid}"]')


def _open_folder(page, title: str) -> None:
    """Expand a collapsed GUI folder: its label's click handler, without waiting on animation frames (software
    WebGL under load can take seconds a frame)."""
    page.get_by_text(title, exact=True).first.dispatch_event("click")


def _sent_points(app) -> int:
    """Points of the cloud node in viser's scene: what every client is sent."""
    return int(app.server.scene._handle_from_node_name["/fused"].points.shape[0])


@pytest.fixture
def small_budget_app(fake_run, monkeypatch):
    import workbench.viewer.app as viewer_module

    monkeypatch.setattr(viewer_module, "POINT_BUDGET", SMALL_BUDGET)  # the control's initial value
    with running_viewer(fake_run) as viewer:
        yield viewer


def test_a_cloud_over_the_budget_is_sent_thinned_and_the_page_says_so(browser_context, small_budget_app):
    app = small_budget_app
    total = len(app.cloud)
    assert total > SMALL_BUDGET and int(app.point_budget.value) == SMALL_BUDGET
    page = open_page(browser_context, app)
    try:
        sent = _sent_points(app)
        assert 0 < sent <= SMALL_BUDGET
        page.get_by_text(f"{sent:,} sent of {total:,}").wait_for()
        page.get_by_text("cloud thinned").first.wait_for()
        page.get_by_text(f"{total:,} points ({sent:,} sent, thinned)").wait_for()

        # a budget typed into the control: more points are sent, still within it, and the page follows
        _element(page, app.point_budget).fill("40000")
        wait_for(lambda: int(app.point_budget.value) == 40_000 and app.wait_idle(1)
                 and SMALL_BUDGET < _sent_points(app) <= 40_000, timeout=120)
        more = _sent_points(app)
        page.get_by_text(f"{more:,} sent of {total:,}").wait_for()
        assert len(app.cloud) == total  # the whole cloud stays for the scores and exports

        # a budget above the cloud: all of it is sent
        _element(page, app.point_budget).fill(str(total + 1000))
        wait_for(lambda: app.wait_idle(1) and _sent_points(app) == total, timeout=120)
        page.get_by_text(f"whole cloud sent: all {total:,}").wait_for()
    finally:
        page.close()


def _sphere_mesh(app, resolution: int = 60) -> TriangleMesh:
    """A sphere around the middle of the fused cloud: a mesh of a few tens of thousands of triangles."""
    import open3d as o3d

    xyz = np.asarray(app.cloud.xyz, np.float64)
    sphere = o3d.geometry.TriangleMesh.create_sphere(radius=float(np.ptp(xyz, axis=0).max()) / 4,
                                                     resolution=resolution)
    sphere.translate(np.median(xyz, axis=0))
    return TriangleMesh.from_open3d(sphere)


def test_the_mesh_is_sent_only_when_shown_and_decimated(browser_context, tmp_path, monkeypatch):
    import workbench.viewer.app as viewer_module

    monkeypatch.setattr(viewer_module, "POINT_BUDGET", SMALL_BUDGET)  # a lighter page: its frames come sooner
    run = make_fake_run(SAMPLES / "tiny", tmp_path / "run")
    with running_viewer(run) as app:
        mesh = _sphere_mesh(app)
    write_mesh_ply(run / "mesh.ply", mesh)
    budget = len(mesh) // 4
    with running_viewer(run) as app:
        panel = app.mesh_panel
        page = open_page(browser_context, app)
        try:
            _open_folder(page, "Mesh")
            page.get_by_text("sent when shown").wait_for()
            page.wait_for_timeout(1000)  # time a start-up send would have had
            assert "/mesh" not in app.server.scene._handle_from_node_name and panel.handle is None
            _element(page, panel.triangle_budget).fill(str(budget))
            wait_for(lambda: int(panel.triangle_budget.value) == budget)
            assert "/mesh" not in app.server.scene._handle_from_node_name  # a budget alone sends nothing
            _element(page, panel.show).click()
            page.get_by_role("option", name="mesh", exact=True).click()
            wait_for(lambda: panel.handle is not None and panel.handle.visible, timeout=120)
            assert app.server.scene._handle_from_node_name["/mesh"] is panel.handle
            assert 0 < panel.glb_triangles() <= budget < len(mesh)
            page.get_by_text("sent (decimated)").wait_for()
            page.get_by_text("distance of its vertices to the nearest GT point").wait_for()
            assert not app.cloud_handle.visible  # "mesh" alone
        finally:
            page.close()
