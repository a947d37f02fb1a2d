"""COLMAP-style fusion (Schönberger et al. 2016): kernel vs reference, geometry, attributes, PLY, pycolmap referee."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from engine.core.camera import Camera
from engine.core.errors import OptionsError
from engine.fusion import (
    FUSION_PRESETS,
    FusedCloud,
    FusionOptions,
    FusionView,
    fuse,
    read_fused_ply,
    views_from_scene,
    write_fused_ply,
)
from engine.fusion.kernel import median_inplace
from engine.fusion.packing import rgb_uint8, to_uint8
from engine.io.ply import read_ply
from engine.scene import load_scene
from support.colmap_fusion import colmap_reference_fusion
from support.fusion_reference import fuse_reference
from support.gt_normals import depth_normals
from tests.conftest import SAMPLES


def _look_at(center: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    z = target - center
    z /= np.linalg.norm(z)
    x = np.cross([0.0, -1.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return R, -R @ center


def _plane_views(n=3, w=40, h=30, noise=0.0, seed=0, plane=(0.1, -0.2, 1.0), offset=5.0, drop=0.0):
    """Views of the plane n.X = offset (world), analytic depth and normals (optionally perturbed)."""
    rng = np.random.default_rng(seed)
    nrm = np.array(plane) / np.linalg.norm(plane)
    views = []
    for i in range(n):
        C = np.array([0.4 * (i - (n - 1) / 2), 0.1 * i, 0.0])
        R, t = _look_at(C, np.array([0.0, 0.0, 5.0]))
        cam = Camera.from_params(w, h, 35.0, 35.0, w / 2, h / 2, R, t)
        rays_w = cam.pixel_rays() @ R  # world direction of camera-frame rays (z = 1)
        depth = (offset - nrm @ C) / (rays_w @ nrm)  # camera z along rays with z = 1
        depth = depth * (1 + noise * rng.normal(size=depth.shape))
        depth[rng.random(depth.shape) < drop] = 0
        n_cam = R @ nrm
        n_cam = -n_cam if n_cam[2] > 0 else n_cam
        normal = np.broadcast_to(n_cam, (h, w, 3)).copy()
        if noise:
            normal += noise * 5 * rng.normal(size=normal.shape)
            normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
        rgb = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
        views.append(FusionView(cam, depth.astype(np.float32), normal.astype(np.float32), rgb, None,
                                [j for j in range(n) if j != i]))
    return views, nrm, offset


def _assert_same(a: FusedCloud, b: FusedCloud):
    assert len(a) == len(b)
    np.testing.assert_allclose(a.xyz, b.xyz, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.normal, b.normal, atol=1e-6)
    np.testing.assert_array_equal(a.rgb, b.rgb)
    np.testing.assert_array_equal(a.num_views, b.num_views)
    np.testing.assert_array_equal(a.num_pixels, b.num_pixels)
    np.testing.assert_array_equal(a.source_view, b.source_view)
    np.testing.assert_allclose(a.mean_confidence, b.mean_confidence, atol=1e-6)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_kernel_matches_reference_on_noisy_maps(seed):
    views, _, _ = _plane_views(n=4, w=24, h=18, noise=0.004, seed=seed, drop=0.2)
    rng = np.random.default_rng(seed)
    views[1].confidence = rng.random((18, 24)).astype(np.float32)
    for opts in (FusionOptions(), FUSION_PRESETS["colmap"], FusionOptions(min_num_pixels=1, max_traversal_depth=2),
                 FusionOptions(max_num_pixels=4, min_num_pixels=2), FUSION_PRESETS["pixels"],
                 FusionOptions(point_per_pixel=True, max_num_pixels=3, min_num_pixels=1)):
        _assert_same(fuse(views, opts), fuse_reference(views, opts))


def test_kernel_matches_reference_on_real_gt_maps():
    scene = load_scene(SAMPLES / "fountain_p11")
    views = []
    for i in range(3):
        cam = scene.views[i].camera
        d = scene.gt_depth(i)
        n = depth_normals(cam, d)
        d = np.where(np.abs(n).sum(-1) > 0, d, 0)
        small = cam.rescaled(48, 32)
        views.append(FusionView(small, d[::8, ::8].copy(), n[::8, ::8].copy(), scene.image(i)[::8, ::8].copy(),
                                None, [j for j in range(3) if j != i]))
    _assert_same(fuse(views), fuse_reference(views))


def test_plane_points_and_normals_exact():
    views, nrm, offset = _plane_views(n=3)
    cloud = fuse(views, FUSION_PRESETS["deepc"])
    assert len(cloud) > 500
    # Component-wise medians of points on a plane lie near it, not on it (COLMAP does the same):
    # within a tenth of the pixel footprint (5 m / f = 0.14 m here).
    assert np.abs(cloud.xyz @ nrm - offset).max() < 0.1 * 5.0 / 35.0
    np.testing.assert_allclose(np.abs(cloud.normal @ nrm), 1.0, atol=1e-6)
    assert (cloud.normal @ nrm).max() < 0 or (cloud.normal @ nrm).min() > 0  # consistent orientation
    assert cloud.num_views.min() >= 2 and cloud.num_views.max() <= 3
    assert np.isnan(cloud.mean_confidence).all()
    assert set(np.unique(cloud.source_view)) <= {0, 1, 2}
    again = fuse(views, FUSION_PRESETS["deepc"])  # deterministic
    np.testing.assert_array_equal(cloud.xyz, again.xyz)


def test_point_per_pixel_keeps_the_clusters_pixels():
    """Per-pixel emission keeps exactly the pixels of the clusters the median mode keeps, each at its own
    back-projected position with its own normal, colour and view; cluster attributes are shared."""
    views, nrm, offset = _plane_views(n=3, noise=0.002, seed=3, drop=0.1)
    views[2].confidence = np.full(views[2].depth.shape, 0.5, np.float32)
    merged = fuse(views, FUSION_PRESETS["deepc"])
    pixels = fuse(views, FUSION_PRESETS["deepc"].replace(point_per_pixel=True))
    assert len(pixels) == int(merged.num_pixels.sum()) > 2 * len(merged)
    # every point is some view's pixel, exactly: its own depth along its own ray
    for i, v in enumerate(views):
        own = pixels.xyz[pixels.source_view == i]
        world = v.camera.backproject(v.depth)[v.depth > 0]
        dist, idx = cKDTree(world).query(own)
        assert len(own) > 0 and dist.max() < 1e-9
        np.testing.assert_array_equal(pixels.rgb[pixels.source_view == i], v.rgb[v.depth > 0][idx])
    # a cluster's points share its counts; the per-pixel cloud has all the views' samples, not one per cluster
    assert set(np.unique(pixels.num_pixels)) == set(np.unique(merged.num_pixels))
    assert np.abs(np.linalg.norm(pixels.normal, axis=1) - 1).max() < 1e-5
    conf = pixels.mean_confidence
    np.testing.assert_allclose(conf[pixels.source_view == 2], 0.5)  # the cluster's mean over view 2's pixels
    assert np.all(np.isnan(conf) | np.isclose(conf, 0.5))
    # masking by num_pixels is still exactly a higher min_num_pixels
    strict = fuse(views, FUSION_PRESETS["deepc"].replace(point_per_pixel=True, min_num_pixels=3))
    loose = fuse(views, FUSION_PRESETS["deepc"].replace(point_per_pixel=True, min_num_pixels=1))
    np.testing.assert_array_equal(loose.subset(loose.num_pixels >= 3).xyz, strict.xyz)


def test_min_num_pixels_and_single_view():
    views, _, _ = _plane_views(n=1)
    views[0].overlap = []
    assert len(fuse(views, FusionOptions(min_num_pixels=2))) == 0
    one = fuse(views, FusionOptions(min_num_pixels=1))
    assert len(one) == int((views[0].depth > 0).sum())
    assert len(fuse([], FusionOptions())) == 0


def test_mean_confidence_and_rgb():
    views, _, _ = _plane_views(n=3)
    for i, v in enumerate(views):
        v.confidence = np.full(v.depth.shape, 0.2 * (i + 1), np.float32)
        v.rgb = np.full(v.depth.shape + (3,), 0.5, np.float32)  # float rgb -> 128
    cloud = fuse(views)
    assert np.all((cloud.mean_confidence >= 0.2 - 1e-6) & (cloud.mean_confidence <= 0.6 + 1e-6))
    assert np.all(cloud.rgb == 128)


def test_median_kernel_matches_numpy():
    rng = np.random.default_rng(3)
    scratch = np.empty(200)
    for n in (1, 2, 3, 4, 7, 8, 31, 32, 33, 48, 49, 50, 200):
        buf = rng.normal(size=200)
        assert median_inplace(buf, n, scratch) == pytest.approx(float(np.median(buf[:n])), abs=0)
        ties = rng.integers(0, 4, size=200).astype(np.float64)  # colours: many equal values (rank path)
        assert median_inplace(ties, n, scratch) == float(np.median(ties[:n]))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_colour_kernel_matches_numpy(dtype):
    rng = np.random.default_rng(5)
    # halves of 1/255 steps, values out of [0, 1] and NaN are where a rounding slip would show
    rgb = np.concatenate([rng.uniform(-0.1, 1.1, 3000), (np.arange(256) + 0.5) / 255, np.arange(256) / 255,
                          [np.nan, np.inf, -np.inf]]).astype(dtype)
    out = np.empty(rgb.size, np.uint8)
    to_uint8(rgb, out)
    with np.errstate(invalid="ignore"):
        np.testing.assert_array_equal(out, rgb_uint8(rgb))


def test_depth_normals_of_plane():
    views, nrm, _ = _plane_views(n=1)
    v = views[0]
    n = depth_normals(v.camera, v.depth)
    valid = np.abs(n).sum(-1) > 0
    assert valid.sum() == (v.depth.shape[0] - 2) * (v.depth.shape[1] - 2)
    np.testing.assert_allclose(n[valid], np.broadcast_to(v.normal[0, 0], n[valid].shape), atol=1e-5)


def test_presets_and_options():
    assert FusionOptions().to_dict() == FUSION_PRESETS["deepc"].to_dict()
    assert FUSION_PRESETS["pixels"] == FUSION_PRESETS["deepc"].replace(min_num_pixels=2, point_per_pixel=True)
    d = FusionOptions()
    assert (d.max_reproj_error, d.max_depth_error, d.max_normal_error, d.min_num_pixels, d.max_num_pixels,
            d.max_traversal_depth, d.check_num_images) == (1.0, 0.01, 20.0, 3, 10000, 100, 50)
    assert (FUSION_PRESETS["colmap"].max_reproj_error, FUSION_PRESETS["colmap"].min_num_pixels) == (2.0, 5)
    assert FUSION_PRESETS["acmm"].max_normal_error == 10.0 and FUSION_PRESETS["acmm"].min_num_pixels == 3
    assert FUSION_PRESETS["deepc_lowres"].max_normal_error == 5.0 and FUSION_PRESETS["deepc_lowres"].min_num_pixels == 4
    paper = FUSION_PRESETS["refined_paper"]
    assert (paper.max_normal_error, paper.min_num_pixels) == (5.0, 3)
    for bad in (dict(max_reproj_error=-1), dict(min_num_pixels=20, max_num_pixels=10), dict(max_traversal_depth=0),
                dict(max_normal_error=200.0)):
        with pytest.raises(OptionsError):
            FusionOptions(**bad).validate()


def test_bad_views():
    views, _, _ = _plane_views(n=2)
    views[0].normal = views[0].normal[:, :, :2]
    with pytest.raises(ValueError, match="normal"):
        fuse(views)
    views, _, _ = _plane_views(n=2)
    views[1].overlap = [5]
    with pytest.raises(ValueError, match="overlap"):
        fuse(views)


def test_fused_ply_roundtrip(tmp_path):
    views, _, _ = _plane_views(n=3)
    views[0].confidence = np.full(views[0].depth.shape, 0.9, np.float32)
    cloud = fuse(views)
    path = tmp_path / "fused.ply"
    write_fused_ply(path, cloud)
    header = path.read_bytes()[:400].decode("ascii", "replace")
    for line in ("format binary_little_endian", "property float x", "property float nx", "property uchar red",
                 "property int num_views", "property float confidence", "property int source_view"):
        assert line in header
    back = read_fused_ply(path)
    np.testing.assert_allclose(back.xyz, cloud.xyz, atol=1e-5)
    np.testing.assert_array_equal(back.rgb, cloud.rgb)
    np.testing.assert_array_equal(back.num_views, cloud.num_views)
    np.testing.assert_array_equal(back.source_view, cloud.source_view)
    np.testing.assert_array_equal(np.isnan(back.mean_confidence), np.isnan(cloud.mean_confidence))
    sub = back.subset(back.num_views >= 3)
    assert len(sub) == int((cloud.num_views >= 3).sum())
    cols = read_ply(path)
    assert cols["x"].dtype == np.float32


def test_matches_pycolmap_fusion(tmp_path):
    """Same maps (GT depth of fountain_p11 at 384x256, normals from depth) through COLMAP's own fusion."""
    pytest.importorskip("pycolmap")
    scene = load_scene(SAMPLES / "fountain_p11")
    depths, normals = [], []
    for i, v in enumerate(scene.views):
        d = scene.gt_depth(i)
        n = depth_normals(v.camera, d)
        depths.append(np.where(np.abs(n).sum(-1) > 0, d, 0).astype(np.float32))
        normals.append(n)
    views = views_from_scene(scene, depths, normals)
    opts = FUSION_PRESETS["deepc"]
    ours = fuse(views, opts)
    ref = colmap_reference_fusion(scene, views, opts, tmp_path / "ws")
    assert abs(len(ours) - len(ref)) <= 0.05 * len(ref), (len(ours), len(ref))
    dist, _ = cKDTree(ref.xyz).query(ours.xyz)
    # Pixel footprint: depth / focal length in the seed view.
    z = np.array([views[s].camera.world_to_camera(p)[2] for p, s in zip(ours.xyz[::50], ours.source_view[::50],
                                                                          strict=True)])
    footprint = np.median(z) / views[0].camera.fx
    assert np.median(dist) < footprint
    assert math.isclose(np.median(ref.num_views), np.median(ours.num_views), abs_tol=1)
