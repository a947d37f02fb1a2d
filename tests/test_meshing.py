"""Meshing (screened Poisson, TSDF) with open3d: surfaces where the data is, scored like clouds, clear errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from engine.core.errors import DeepCError
from engine.evaluation import EvaluationOptions, evaluate_points
from engine.fusion import FusedCloud, fuse, views_from_scene, write_fused_ply
from engine.meshing import (
    MeshOptions,
    TriangleMesh,
    point_spacing,
    poisson_mesh,
    read_mesh,
    sample_surface,
    tsdf_mesh,
    write_mesh_ply,
)
from engine.run.folder import read_map
from engine.scene import load_scene
from support.fake_run import make_fake_run
from tests.conftest import SAMPLES
from workbench.cli.main import main

TOLERANCES = EvaluationOptions(tolerances=(0.01, 0.02, 0.05))


def _square(z: float = 0.0) -> TriangleMesh:
    vertices = np.array([[0, 0, z], [1, 0, z], [1, 1, z], [0, 1, z]], np.float64)
    return TriangleMesh(vertices, np.array([[0, 1, 2], [0, 2, 3]], np.int32), np.tile([0, 0, 1], (4, 1)).astype(
        np.float32), np.full((4, 3), 200, np.uint8))


def _grid(spacing: float) -> np.ndarray:
    u = np.arange(spacing / 2, 1, spacing)
    x, y = np.meshgrid(u, u)
    return np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)


def test_surface_samples_are_uniform_on_the_mesh_and_reproducible():
    points = sample_surface(_square(), 0.01, seed=3)
    assert abs(len(points) - 10_000) <= 1 and np.all(points[:, 2] == 0)
    assert points[:, :2].min() >= 0 and points[:, :2].max() <= 1
    quadrants = np.histogram2d(points[:, 0], points[:, 1], bins=2, range=[[0, 1], [0, 1]])[0]
    assert quadrants.min() > 0.9 * quadrants.max()  # the two triangles are drawn by area, not half each
    np.testing.assert_array_equal(points, sample_surface(_square(), 0.01, seed=3))


def test_a_mesh_on_the_ground_truth_scores_100_and_a_shifted_one_only_beyond_its_offset():
    gt = _grid(0.01)
    assert point_spacing(gt) == pytest.approx(0.01)
    on = evaluate_points(sample_surface(_square(), point_spacing(gt) / 2), gt, TOLERANCES)
    assert on.f1 == pytest.approx([100, 100, 100], abs=0.5)
    off = evaluate_points(sample_surface(_square(z=0.03), point_spacing(gt) / 2), gt, TOLERANCES)
    assert off.f1[0] == 0 and off.f1[1] == 0 and off.f1[2] == pytest.approx(100, abs=0.5)


def _sphere_cloud(n: int = 20000, normals: bool = True) -> FusedCloud:
    rng = np.random.default_rng(0)
    xyz = rng.normal(size=(n, 3))
    xyz /= np.linalg.norm(xyz, axis=1, keepdims=True)
    normal = xyz.astype(np.float32) if normals else np.zeros((n, 3), np.float32)
    return FusedCloud(xyz, normal, np.full((n, 3), 128, np.uint8), np.full(n, 2, np.int32),
                      np.full(n, np.nan, np.float32), np.zeros(n, np.int32), np.full(n, 2, np.int32))


def test_poisson_surface_of_an_oriented_sphere_lies_on_it():
    mesh, notes = poisson_mesh(_sphere_cloud(), MeshOptions(method="poisson", poisson_depth=7))
    radius = np.linalg.norm(mesh.vertices, axis=1)
    assert notes == [] and len(mesh) > 1000
    assert np.median(np.abs(radius - 1)) < 0.01 and np.abs(radius - 1).max() < 0.05
    assert mesh.vertex_colors.shape == mesh.vertices.shape and (mesh.vertex_colors == 128).mean() > 0.9


def test_poisson_estimates_missing_normals_and_says_so():
    mesh, notes = poisson_mesh(_sphere_cloud(normals=False), MeshOptions(method="poisson", poisson_depth=6))
    assert len(notes) == 1 and "no normal" in notes[0] and len(mesh) > 500


def test_poisson_refuses_too_small_or_degenerate_clouds():
    with pytest.raises(DeepCError, match="too few"):
        poisson_mesh(_sphere_cloud(50))
    flat = _sphere_cloud(500)
    flat.xyz = np.zeros_like(flat.xyz)
    with pytest.raises(DeepCError, match="degenerate"):
        poisson_mesh(flat)


@pytest.fixture(scope="module")
def tiny():
    return load_scene(SAMPLES / "tiny")


def _tsdf_inputs(scene):
    cameras = [v.camera for v in scene.views]
    depths = [scene.gt_depth(v.index) for v in scene.views]
    colors = [np.clip(np.rint(scene.image(v.index) * 255), 0, 255).astype(np.uint8) for v in scene.views]
    return cameras, depths, colors


def test_tsdf_of_ground_truth_depth_maps_reproduces_the_ground_truth(tiny):
    cameras, depths, colors = _tsdf_inputs(tiny)
    mesh, voxel = tsdf_mesh(cameras, depths, colors, MeshOptions(method="tsdf", tsdf_voxel_px=1.0))
    assert 0 < voxel < 0.1 and len(mesh) > 1000
    from engine.io.ply import read_points

    gt = read_points(tiny.gt_points_path)
    score = evaluate_points(sample_surface(mesh, point_spacing(gt)), gt, TOLERANCES, tiny.gt_views())
    assert score.f1[2] > 95  # at 5 cm; the voxels are ~3 cm


def test_tsdf_refuses_a_volume_that_would_not_fit_and_maps_without_depth(tiny):
    cameras, depths, colors = _tsdf_inputs(tiny)
    with pytest.raises(DeepCError, match="raise mesh.tsdf_voxel_px"):
        tsdf_mesh(cameras, depths, colors, MeshOptions(method="tsdf", tsdf_voxel_px=0.01, max_memory_gb=0.5))
    with pytest.raises(DeepCError, match="no depth"):
        tsdf_mesh(cameras, [np.zeros_like(d) for d in depths], colors)


def test_mesh_ply_round_trip(tmp_path):
    mesh = _square()
    write_mesh_ply(tmp_path / "m.ply", mesh)
    back = read_mesh(tmp_path / "m.ply")
    np.testing.assert_allclose(back.vertices, mesh.vertices)
    np.testing.assert_array_equal(back.triangles, mesh.triangles)
    np.testing.assert_array_equal(back.vertex_colors, mesh.vertex_colors)
    with pytest.raises(DeepCError, match="not found"):
        read_mesh(tmp_path / "none.ply")


def test_deepc_mesh_and_deepc_eval_on_a_run(tmp_path, capsys):
    run = make_fake_run(SAMPLES / "tiny", tmp_path / "run")
    assert main(["mesh", str(run)]) == 2  # Poisson needs the fused cloud
    assert "no fused.ply" in capsys.readouterr().err
    assert main(["mesh", str(run), "--method", "tsdf"]) == 0
    out = capsys.readouterr().out
    assert "mesh (tsdf" in out and "mesh at 5 cm: F1" in out
    block = json.loads((run / "metrics.json").read_text())["mesh"]
    # the fake run is a fast run that saved no confidence options: it fused what confidence.tau's default keeps of
    # its confidence ramp (engine.run.fused_maps, as the viewer shows it), a little less than every pixel
    assert block["method"] == "tsdf" and block["triangles"] > 1000 and block["eval"]["f1"][2] > 85

    scene = load_scene(SAMPLES / "tiny")
    depth = [read_map(run, "depth", v.name) for v in scene.views]
    normal = [read_map(run, "normal", v.name) for v in scene.views]
    write_fused_ply(run / "fused.ply", fuse(views_from_scene(scene, depth, normal)))
    assert main(["mesh", str(run), "--set", "mesh.poisson_depth=7"]) == 0
    assert json.loads((run / "metrics.json").read_text())["mesh"]["options"]["poisson_depth"] == 7
    assert main(["eval", str(run / "mesh.ply"), str(SAMPLES / "tiny" / "ground_truth" / "points.ply")]) == 0
    assert "sampled as" in capsys.readouterr().out

    assert main(["mesh", str(tmp_path / "missing")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["mesh", str(run), "--set", "mesh.tsdf_voxel_px=-1", "--method", "tsdf"]) == 2


def test_viewer_shows_the_runs_mesh_and_meshes_the_tuned_cloud_on_request(tmp_path):
    from conftest import running_viewer, wait_for

    run = make_fake_run(SAMPLES / "tiny", tmp_path / "run")
    with running_viewer(run) as app:
        panel = app.mesh_panel
        assert panel.show.disabled and panel.handle is None  # nothing to show before a mesh exists
        panel.method.value = "tsdf"
        panel.request("tsdf")
        wait_for(lambda: panel.mesh is not None and panel.handle is not None and panel.handle.visible, timeout=120)
        assert panel.show.value == "cloud + mesh" and app.cloud_handle.visible
        assert "triangles" in panel.status.content and "tsdf of the current cloud" in panel.status.content
        legend = panel.legend.content
        assert "distance of its vertices to the nearest GT point" in legend and " cm" in legend
        # the mesh's own scores, as deepc mesh takes them, in the Metrics folder
        wait_for(lambda: "F1" in app.mesh_metrics.content and "at 2 cm" in app.mesh_metrics.content, timeout=120)
        panel.show.value = "mesh"
        assert panel.handle.visible and not app.cloud_handle.visible
    write_mesh_ply(run / "mesh.ply", panel.mesh)
    with running_viewer(run) as app:  # a run meshed before opens with its mesh available, not yet sent
        panel = app.mesh_panel
        assert panel.mesh is None and panel.handle is None and "the run's mesh.ply" in panel.status.content
        assert not panel.show.disabled and panel.show.value == "cloud"
        from workbench.viewer.mesh import MIN_TRIANGLE_BUDGET

        budget = max(MIN_TRIANGLE_BUDGET, len(read_mesh(run / "mesh.ply")) // 3)
        panel.triangle_budget.value = budget
        panel.show.value = "mesh"  # now it is read, decimated and sent
        wait_for(lambda: panel.handle is not None and panel.handle.visible, timeout=120)
        assert 0 < panel.glb_triangles() <= budget and len(panel.sent.shown) <= budget
        assert len(panel.mesh) > budget and "sent (decimated)" in panel.status.content
        wait_for(lambda: "F1" in app.mesh_metrics.content, timeout=120)


@pytest.mark.browser
@pytest.mark.timeout(300)
def test_viewer_mesh_toggle_in_the_browser(tmp_path, browser_context, monkeypatch):
    from conftest import running_viewer, wait_for

    import workbench.viewer.app as viewer_module

    # a page of 20 000 points renders a frame well within a click's wait in software WebGL on a loaded machine
    # (tiny's whole cloud timed the clicks out at 30 s)
    monkeypatch.setattr(viewer_module, "POINT_BUDGET", 20_000)
    run = make_fake_run(SAMPLES / "tiny", tmp_path / "run")
    with running_viewer(run) as app:
        page = browser_context.new_page()
        try:
            page.goto(f"http://127.0.0.1:{app.port}/")
            wait_for(lambda: len(app.server.get_clients()) > 0)
            page.get_by_text("Connected").wait_for()
            # open the folder by its label's click handler: a real click waits on animation frames, seconds each
            # in software WebGL on a loaded machine (it timed out at 30 s on main too)
            page.get_by_text("Mesh", exact=True).first.dispatch_event("click")
            page.get_by_role("button", name="Mesh the current cloud").click()
            page.get_by_text("of the current cloud").wait_for(timeout=120_000)
            wait_for(lambda: app.mesh_panel.handle is not None and app.mesh_panel.handle.visible)
            assert app.mesh_panel.show.value == "cloud + mesh"
        finally:
            page.close()


def test_decimate_keeps_a_mesh_within_its_triangle_budget():
    import open3d as o3d

    from engine.meshing import decimate

    sphere = TriangleMesh.from_open3d(o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=40))
    small = decimate(sphere, 500)
    assert 0 < len(small) <= 500 < len(sphere)
    assert small.vertex_colors.shape == (len(small.vertices), 3) and small.vertex_colors.dtype == np.uint8
    radius = np.linalg.norm(small.vertices, axis=1)
    assert np.all(np.abs(radius - 1) < 0.1)  # still the sphere, not a few scattered triangles
    assert decimate(sphere, len(sphere)) is sphere  # within the budget: the mesh itself
    with pytest.raises(DeepCError):
        decimate(sphere, 0)


def test_surface_area_of_a_sphere_and_its_sampled_estimate():
    import open3d as o3d

    from engine.meshing.decimate import surface_area

    sphere = TriangleMesh.from_open3d(o3d.geometry.TriangleMesh.create_sphere(radius=2.0, resolution=60))
    whole = surface_area(sphere)
    assert abs(whole - 4 * np.pi * 4.0) / (4 * np.pi * 4.0) < 0.01  # a fine tessellation of 4πr²
    assert abs(surface_area(sphere, sample=len(sphere) // 7) - whole) / whole < 0.05
    assert surface_area(sphere, sample=len(sphere)) == whole  # a sample as large as the mesh is the mesh
