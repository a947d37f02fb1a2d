"""Synthetic scene generator: ray casting, determinism, GT consistency, sparse model, export."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pycolmap
import pytest
from PIL import Image
from scipy.spatial import cKDTree

from engine.core.camera import Camera
from engine.core.errors import OptionsError
from engine.io.dense import read_depth_map
from engine.io.ply import read_points
from engine.synthetic import random_scene, render_scene, tiny_scene, write_scene
from engine.synthetic.raycast import Box, Cylinder, Quad, Sphere, cast
from engine.synthetic.render import cast_camera_rays
from engine.synthetic.scene import SceneRecipe
from engine.synthetic.texture import Texture

SAMPLES = Path(__file__).resolve().parent.parent / "sample_scenes"


@pytest.fixture(scope="module")
def tiny():
    return render_scene(tiny_scene())


@pytest.fixture(scope="module")
def tiny_written(tiny, tmp_path_factory):
    out = tmp_path_factory.mktemp("scenes") / "tiny"
    write_scene(tiny, out, binary_model=False)
    return out


def _scene_with(prims, camera: Camera) -> SceneRecipe:
    return SceneRecipe("t", 0, prims, [Texture()] * len(prims), np.array([0, 0, 1.0]), (1, 1, 1), (0, 0, 1),
                 [camera], ["a.png"])


def _camera(width=40, height=30, R=None, t=None) -> Camera:
    return Camera.from_params(width, height, 30.0, 31.0, 21.3, 14.1, R, t)


# --- ray casting ---------------------------------------------------------------------------------

def test_plane_depth_matches_closed_form():
    cam = _camera()
    n = np.array([0.2, -0.3, 1.0]) / np.linalg.norm([0.2, -0.3, 1.0])
    p0 = np.array([0.1, 0.0, 5.0])
    u = np.cross(n, [1.0, 0, 0])
    hits = cast_camera_rays(_scene_with([Quad(tuple(p0), tuple(u), tuple(np.cross(n, u)))], cam), cam)
    rays = cam.pixel_rays().reshape(-1, 3)
    expected = (n @ p0) / (rays @ n)  # z-depth of ray (z = 1) meeting the plane n.X = n.p0
    np.testing.assert_allclose(hits.s, expected, rtol=1e-12)
    np.testing.assert_allclose(hits.distance, expected * np.linalg.norm(rays, axis=1), rtol=1e-12)
    np.testing.assert_allclose(np.abs(hits.normal @ n), 1.0, rtol=1e-12)


def test_sphere_depth_matches_closed_form_and_occludes():
    cam = _camera()
    c, r = np.array([0.3, -0.2, 6.0]), 1.5
    wall = Quad((0, 0, 9.0), (1, 0, 0), (0, 1, 0))
    hits = cast_camera_rays(_scene_with([wall, Sphere(tuple(c), r)], cam), cam)
    rays = cam.pixel_rays().reshape(-1, 3)
    a, b, k = (rays * rays).sum(1), rays @ c, c @ c - r * r
    disc = b * b - a * k
    on_sphere = disc > 0
    expected = np.where(on_sphere, (b - np.sqrt(np.maximum(disc, 0))) / a, 9.0)
    np.testing.assert_allclose(hits.s, expected, rtol=1e-10)
    assert set(np.unique(hits.prim[on_sphere])) == {1}
    assert set(np.unique(hits.prim[~on_sphere])) == {0}
    pts = hits.point[on_sphere]
    np.testing.assert_allclose(hits.normal[on_sphere], (pts - c) / r, atol=1e-9)


def test_box_and_cylinder_hits():
    origins = np.array([[0.0, -5.0, 0.5], [0.0, -5.0, 0.5], [4.0, 0.0, 1.0], [0.0, -5.0, 3.0]])
    dirs = np.array([[0.0, 1.0, 0.0], [0.0, 2.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    box = Box((0.0, 0.0, 0.5), (1.0, 0.5, 0.5), ((0, -1, 0), (1, 0, 0), (0, 0, 1)))  # rotated 90 deg
    pole = Cylinder((1.0, 0.0, 0.0), 0.05, 2.0)
    hits = cast([box, pole], origins, dirs)
    np.testing.assert_allclose(hits.s, [4.0, 2.0, 2.95, np.inf])  # box y half-extent is 1 after rotation
    np.testing.assert_allclose(hits.normal[:3], [[0, -1, 0], [0, -1, 0], [1, 0, 0]], atol=1e-12)
    assert hits.prim.tolist() == [0, 0, 1, -1]
    np.testing.assert_allclose(hits.distance[1], 4.0)


# --- determinism -------------------------------------------------------------------------------

def _small_random(seed):
    return render_scene(random_scene(seed, n_views=(3, 3), width=48, height=36, supersample=2))


def test_random_scene_is_deterministic():
    a, b, c = _small_random(7), _small_random(7), _small_random(8)
    for x, y in zip(a.images + a.depths, b.images + b.depths, strict=True):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(a.sparse.xyz, b.sparse.xyz)
    np.testing.assert_array_equal(a.gt_points, b.gt_points)
    assert not np.array_equal(a.images[0], c.images[0])


def test_random_scene_knobs_are_validated():
    with pytest.raises(OptionsError, match="n_boxes"):
        random_scene(1, n_boxes=(3, 1))
    with pytest.raises(OptionsError, match="texture_kinds"):
        random_scene(1, texture_kinds=("marble",))
    s = random_scene(3, n_views=(4, 4), noise_sigma=(2.0, 2.0), jpeg_prob=1.0, texture_kinds=("weak",))
    assert len(s.cameras) == 4 and s.render.noise_sigma == 2.0 and s.render.jpeg_quality >= 60
    assert all(t.kind == "weak" for t in s.textures)


def test_training_recipes_hard_family():
    """Seeds from HARD_SEED_START draw large, often weakly textured objects; earlier seeds keep the scenes
    the cached training runs were made from (the sphere_radius knob draws from the same random stream)."""
    from engine.synthetic.dataset import HARD_SEED_START, training_recipe
    from engine.synthetic.raycast import Sphere

    old = training_recipe(1003)
    spheres = [(round(p.radius, 4), t.kind) for p, t in zip(old.primitives, old.textures, strict=True)
               if isinstance(p, Sphere)]
    assert spheres == [(0.588, "weak"), (0.391, "noise")]  # the held-out scene that motivated the family
    hard = [training_recipe(HARD_SEED_START + i) for i in range(8)]
    radii = [p.radius for r in hard for p in r.primitives if isinstance(p, Sphere)]
    assert all(any(isinstance(p, Sphere) for p in r.primitives) for r in hard)
    assert min(radii) >= 0.45 and max(radii) > 0.8
    weak = np.mean([t.kind == "weak" for r in hard for t in r.textures])
    assert weak > 0.3  # the default family has 0.15


# --- ground truth ------------------------------------------------------------------------------

def test_gt_depth_is_multiview_consistent(tiny):
    """Back-project A's GT depth, project into B: B's GT depth agrees where the same planar surface
    is seen (inverse depth is affine in the image for a plane, so bilinear interpolation is exact)."""
    checked = 0
    for a, b in [(0, 1), (2, 4), (3, 0)]:
        cam_a, cam_b = tiny.cameras[a], tiny.cameras[b]
        da, db = tiny.depths[a], tiny.depths[b]
        pid_a, pid_b = tiny.prim_ids[a], tiny.prim_ids[b]
        X = cam_a.backproject(da).reshape(-1, 3)
        valid = np.isfinite(X[:, 0])
        uv, z = cam_b.project(np.where(valid[:, None], X, 0.0))
        u0, v0 = np.floor(uv[:, 0]), np.floor(uv[:, 1])
        inside = valid & (u0 >= 0) & (v0 >= 0) & (u0 < cam_b.width - 1) & (v0 < cam_b.height - 1)
        idx = np.flatnonzero(inside)
        c0, r0 = u0[idx].astype(int), v0[idx].astype(int)
        fu, fv = uv[idx, 0] - c0, uv[idx, 1] - r0
        prim = pid_a.ravel()[idx]
        planar = np.array([tiny.scene.primitives[p].planar for p in prim])
        corners = [(r0, c0), (r0, c0 + 1), (r0 + 1, c0), (r0 + 1, c0 + 1)]
        same = planar.copy()
        na = tiny.normals[a].reshape(-1, 3)[idx].astype(np.float64) @ cam_a.R  # world normals
        nb = tiny.normals[b].astype(np.float64) @ cam_b.R
        for rr, cc in corners:  # same primitive and same face (boxes) at all four neighbours: not occluded
            same &= (pid_b[rr, cc] == prim) & (np.abs(nb[rr, cc] - na).max(axis=1) < 1e-5)
        with np.errstate(divide="ignore"):  # sky (depth 0) corners are masked out by `same`
            inv = [1.0 / db[rr, cc].astype(np.float64) for rr, cc in corners]
        inv_b = (1 - fv) * ((1 - fu) * inv[0] + fu * inv[1]) + fv * ((1 - fu) * inv[2] + fu * inv[3])
        rel = np.abs(1.0 / inv_b[same] - z[idx][same]) / z[idx][same]
        assert rel.max() < 1e-4, (a, b, rel.max())
        assert same.mean() > 0.5
        checked += int(same.sum())
    assert checked > 20000


def test_sparse_model_is_sfm_like(tiny):
    sp = tiny.sparse
    assert 500 <= sp.num_points
    assert sp.track_lengths().min() >= 2
    errors = []
    for v, cam in enumerate(tiny.cameras):
        sel = sp.obs_view == v
        uv, z = cam.project(sp.xyz[sp.obs_point[sel]])
        assert (z > 0).all()
        errors.append(np.linalg.norm(uv + 0.5 - sp.obs_xy[sel], axis=1))  # COLMAP coords = index + 0.5
        assert np.bincount(sp.obs_point[sel]).max() == 1  # at most one observation per point and image
    errors = np.concatenate(errors)
    assert np.quantile(errors, 0.99) < 1.0 and errors.max() < 2.0
    assert 0.1 < np.median(errors) < 0.8  # noisy, like real SfM, not exact


def test_gt_points_lie_on_gt_depth(tiny):
    cam = tiny.cameras[2]
    uv, z = cam.project(tiny.gt_points)
    col, row = np.rint(uv[:, 0]).astype(int), np.rint(uv[:, 1]).astype(int)
    ok = (z > 0) & (col >= 0) & (row >= 0) & (col < cam.width) & (row < cam.height)
    assert ok.mean() > 0.3
    assert len(tiny.gt_points) > 10000


# --- export and the committed sample scenes ---------------------------------------------------

def _check_model(folder: Path, data=None) -> pycolmap.Reconstruction:
    rec = pycolmap.Reconstruction(str(folder / "sparse"))
    names = sorted(p.name for p in (folder / "images").iterdir())
    assert sorted(im.name for im in rec.images.values()) == names
    for im in rec.images.values():
        cam = rec.cameras[im.camera_id]
        assert cam.model_name == "PINHOLE"
        with Image.open(folder / "images" / im.name) as img:
            assert img.size == (cam.width, cam.height)
        assert (folder / "ground_truth" / "depth_maps" / f"{im.name}.bin").is_file()
    for point in rec.points3D.values():
        assert point.track.length() >= 2
    # Observations reproject within 2 px through pycolmap's own (continuous) projection.
    errs = []
    for im in rec.images.values():
        cam = rec.cameras[im.camera_id]
        for p2d in im.points2D:
            if p2d.has_point3D():
                X = im.cam_from_world() * rec.points3D[p2d.point3D_id].xyz
                errs.append(np.linalg.norm(cam.img_from_cam(X) - p2d.xy))
    assert len(errs) > 0 and max(errs) < 2.0
    return rec


def test_written_tiny_reads_back(tiny, tiny_written):
    rec = _check_model(tiny_written)
    assert rec.num_points3D() == tiny.sparse.num_points
    assert (tiny_written / "sparse" / "points3D.txt").is_file()
    for name, depth in zip(tiny.image_names, tiny.depths, strict=True):
        np.testing.assert_array_equal(read_depth_map(tiny_written / "ground_truth" / "depth_maps" / f"{name}.bin"),
                                      depth)
    pts = read_points(tiny_written / "ground_truth" / "points.ply")
    np.testing.assert_allclose(pts, tiny.gt_points, atol=1e-5)
    assert "MIT" in (tiny_written / "README.txt").read_text()
    assert not [p for p in tiny_written.parent.iterdir() if p.name.startswith(".")]  # no temp folders left


def test_write_scene_replaces_existing_folder(tmp_path):
    data = _small_random(3)
    out = tmp_path / "scene"
    (out / "images").mkdir(parents=True)
    (out / "images" / "stale.png").write_bytes(b"x")
    write_scene(data, out, binary_model=True)
    assert not (out / "images" / "stale.png").exists()
    assert (out / "sparse" / "points3D.bin").is_file()
    _check_model(out)
    assert [p.name for p in tmp_path.iterdir()] == ["scene"]


def test_committed_tiny_matches_regeneration(tiny_written):
    committed = SAMPLES / "tiny"
    if not committed.is_dir():
        pytest.skip("sample_scenes/tiny not generated")
    _check_model(committed)
    for path in sorted((committed / "images").iterdir()):
        a = np.asarray(Image.open(path)).astype(int)
        b = np.asarray(Image.open(tiny_written / "images" / path.name)).astype(int)
        assert a.shape == b.shape
        assert (np.abs(a - b) <= 1).mean() >= 0.999
        name = path.name + ".bin"
        da = read_depth_map(committed / "ground_truth" / "depth_maps" / name)
        db = read_depth_map(tiny_written / "ground_truth" / "depth_maps" / name)
        np.testing.assert_allclose(da, db, rtol=1e-6)
    ra = pycolmap.Reconstruction(str(committed / "sparse"))
    rb = pycolmap.Reconstruction(str(tiny_written / "sparse"))
    assert ra.num_points3D() == rb.num_points3D()
    for image_id, im in ra.images.items():
        np.testing.assert_allclose(im.cam_from_world().matrix(), rb.images[image_id].cam_from_world().matrix(),
                                   atol=1e-9)
    pa = read_points(committed / "ground_truth" / "points.ply").astype(np.float64)
    pb = read_points(tiny_written / "ground_truth" / "points.ply").astype(np.float64)
    # The point COUNT is ill-conditioned: walls and the ground lie exactly on voxel boundaries (y = 2.1 m =
    # 84 voxels, z = 0), so last-bit differences between package installs move points to the neighbouring
    # voxel layer and the thinning keeps a different subset (54,263 committed vs 51,677 regenerated on
    # 2026-11-24, the differing voxels at y index 83 vs 84). The SURFACES must not change: every point of
    # either set lies within a voxel diagonal of the other set.
    voxel = tiny_scene().gt_voxel
    assert abs(len(pa) - len(pb)) <= 0.1 * len(pa)
    for p, q in ((pa, pb), (pb, pa)):
        dist = cKDTree(q).query(p)[0]
        assert np.mean(dist <= voxel * np.sqrt(3)) >= 0.999, np.percentile(dist, [50, 99, 99.9])


def test_committed_small_reads_back():
    small = SAMPLES / "small"
    if not small.is_dir():
        pytest.skip("sample_scenes/small not generated")
    rec = _check_model(small)
    assert (small / "sparse" / "points3D.bin").is_file()
    assert rec.num_images() == 8
    assert {(c.width, c.height) for c in rec.cameras.values()} == {(320, 240)}
    depth = read_depth_map(small / "ground_truth" / "depth_maps" / "view_000.png.bin")
    assert 0.6 < (depth > 0).mean() < 0.98  # some sky
