"""Scene loading: real and synthetic scenes, depth ranges, source views, ground truth, bad input."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from conftest import sample_scene_dirs, shared_scene_dirs

from engine.core.errors import DeepCError
from engine.io.dense import read_depth_map, write_dense_map
from engine.scene import SceneOptions, load_scene

ALL_SCENES = sample_scene_dirs() + shared_scene_dirs()


def _gt_containment(scene) -> float:
    inside = total = 0
    for view in scene.views:
        gt = scene.gt_depth(view.index)
        if gt is None:
            continue
        z = gt[gt > 0]
        inside += np.count_nonzero((z >= view.depth_range[0]) & (z <= view.depth_range[1]))
        total += z.size
    return inside / total


@pytest.mark.parametrize("path", ALL_SCENES, ids=[f"{p.parent.name}/{p.name}" for p in ALL_SCENES])
def test_every_scene_loads_and_depth_ranges_contain_the_ground_truth(path):
    scene = load_scene(path, SceneOptions(max_image_size=320))
    assert len(scene.views) >= 2
    for view in scene.views:
        assert max(view.camera.width, view.camera.height) <= 320
        assert 0 < view.depth_range[0] < view.depth_range[1]
        assert view.source_views and view.index not in view.source_views
        assert len(set(view.source_views)) == len(view.source_views) <= 10
    image = scene.image(0)
    assert image.shape == (scene.views[0].camera.height, scene.views[0].camera.width, 3)
    assert image.dtype == np.float32 and 0 <= image.min() and image.max() <= 1
    if scene.has_gt_depth:
        assert _gt_containment(scene) >= 0.98


def test_source_views_prefer_shared_points_and_respect_the_angle_gate(fountain_copy):
    scene = load_scene(fountain_copy)
    for view in scene.views:
        shared = scene.shared_points[view.index, view.source_views]
        assert list(shared) == sorted(shared, reverse=True)
    strict = load_scene(fountain_copy, SceneOptions(min_triangulation_angle=20.0))
    assert sum(map(len, (v.source_views for v in strict.views))) < sum(map(len, (v.source_views for v in scene.views)))
    few = load_scene(fountain_copy, SceneOptions(num_source_views=3))
    assert all(v.source_views == full.source_views[:3] for v, full in zip(few.views, scene.views, strict=True))


def test_depth_range_follows_colmap_then_acmm_rule(fountain_copy):
    scene = load_scene(fountain_copy)
    view = scene.views[3]
    model = scene.model
    z = np.sort(view.camera.world_to_camera(model.points[model.track_point[model.track_image == 3]])[:, 2])
    expected = (z[int(0.01 * len(z))] * 0.75 * 0.6, z[int(0.99 * len(z))] * 1.25 * 1.2)
    np.testing.assert_allclose(view.depth_range, expected)


def test_rescaling_keeps_exact_intrinsics_and_gt_follows(fountain_copy):
    full = load_scene(fountain_copy)
    half = load_scene(fountain_copy, SceneOptions(max_image_size=192))
    a, b = full.views[0].camera, half.views[0].camera
    assert (b.width, b.height) == (192, 128)
    np.testing.assert_allclose(b.K[:2] * 2, a.K[:2])
    gt = half.gt_depth(0)
    assert gt.shape == (128, 192) and (gt > 0).mean() > 0.5


def test_depth_range_override(fountain_copy):
    scene = load_scene(fountain_copy, SceneOptions(depth_range=(1.0, 30.0)))
    assert all(v.depth_range == (1.0, 30.0) for v in scene.views)


def test_model_in_sparse_0_and_text_format(temple_copy):
    shutil.move(temple_copy / "sparse", temple_copy / "model0")
    (temple_copy / "sparse").mkdir()
    shutil.move(temple_copy / "model0", temple_copy / "sparse" / "0")
    scene = load_scene(temple_copy)
    assert len(scene.views) == 16 and scene.model.path.name == "0"


def test_gt_depth_at_another_proportional_resolution_is_resampled(fountain_copy):
    path = fountain_copy / "ground_truth" / "depth_maps" / "0000.jpg.bin"
    depth = read_depth_map(path)
    write_dense_map(path, np.repeat(np.repeat(depth, 2, axis=0), 2, axis=1))  # 768x512 for a 384x256 image
    scene = load_scene(fountain_copy)
    np.testing.assert_array_equal(scene.gt_depth(0), depth)


def test_non_pinhole_cameras_are_undistorted_or_refused(temple_copy, tmp_path):
    cameras = temple_copy / "sparse" / "cameras.txt"
    lines = []
    for line in cameras.read_text().splitlines():
        if line.startswith("#") or not line.strip():
            lines.append(line)
            continue
        cid, _, w, h, fx, fy, cx, cy = line.split()
        lines.append(f"{cid} SIMPLE_RADIAL {w} {h} {(float(fx) + float(fy)) / 2} {cx} {cy} 0.05")
    cameras.write_text("\n".join(lines) + "\n")
    with pytest.raises(DeepCError, match="SIMPLE_RADIAL.*undistort"):
        load_scene(temple_copy, SceneOptions(undistort=False))
    lines = []
    scene = load_scene(temple_copy, SceneOptions(cache_dir=str(tmp_path / "cache")), report=lines.append)
    assert lines[0].startswith("undistorting 16 images (SIMPLE_RADIAL) at ") and "undistorted 16 images" in lines[1]
    assert len(scene.views) == 16 and scene.image(0).ndim == 3
    assert all(scene.model.cameras[c].model in ("PINHOLE", "SIMPLE_PINHOLE") for c in scene.model.cameras)
    assert not list((tmp_path / "cache" / "undistorted").glob(".undistort-*"))  # no partial cache left


# ---- bad input: one line naming the file and the problem -------------------------------------------

def _error(path, **options) -> str:
    with pytest.raises(DeepCError) as info:
        load_scene(path, SceneOptions(**options))
    text = str(info.value)
    assert "\n" not in text
    return text


def test_missing_scene_and_missing_images_folder(tmp_path, temple_copy):
    assert "not found" in _error(tmp_path / "nowhere")
    shutil.rmtree(temple_copy / "images")
    text = _error(temple_copy)
    assert str(temple_copy) in text and "images/" in text


def test_missing_model(temple_copy):
    shutil.rmtree(temple_copy / "sparse")
    assert "sparse/" in _error(temple_copy)


def test_image_listed_in_the_model_but_absent(temple_copy):
    (temple_copy / "images" / "templeSR0005.png").unlink()
    text = _error(temple_copy)
    assert "templeSR0005.png" in text and "missing" in text


def test_unreadable_image(temple_copy):
    (temple_copy / "images" / "templeSR0003.png").write_bytes(b"this is not a png")
    text = _error(temple_copy)
    assert "templeSR0003.png" in text and "unreadable" in text


def test_truncated_image_fails_when_read(temple_copy):
    path = temple_copy / "images" / "templeSR0002.png"
    path.write_bytes(path.read_bytes()[:2000])
    scene = load_scene(temple_copy)
    with pytest.raises(DeepCError, match="templeSR0002.png.*unreadable"):
        scene.image(1)


def test_image_of_the_wrong_size(temple_copy):
    from PIL import Image
    Image.new("RGB", (100, 100)).save(temple_copy / "images" / "templeSR0004.png")
    assert "100x100" in _error(temple_copy)


def test_malformed_model(temple_copy):
    with open(temple_copy / "sparse" / "images.txt", "a") as f:
        f.write("17 not a pose\n")
    text = _error(temple_copy)
    assert "malformed COLMAP model" in text and "sparse" in text


def test_truncated_binary_model(fountain_copy):
    path = fountain_copy / "sparse" / "images.bin"
    path.write_bytes(path.read_bytes()[:5000])
    text = _error(fountain_copy)
    assert "images.bin" in text and "corrupt COLMAP binary model" in text  # names the file, not just the folder


def test_empty_model_asks_for_points_or_a_depth_range(temple_copy):
    lines = (temple_copy / "sparse" / "points3D.txt").read_text().splitlines()
    (temple_copy / "sparse" / "points3D.txt").write_text("\n".join(line for line in lines if line.startswith("#")))
    images = (temple_copy / "sparse" / "images.txt").read_text().splitlines()
    body = [line for line in images if not line.startswith("#")]
    kept = [line if i % 2 == 0 else "" for i, line in enumerate(body)]  # drop the 2-D observations
    (temple_copy / "sparse" / "images.txt").write_text("\n".join(kept) + "\n")
    text = _error(temple_copy)
    assert "no 3D points" in text and "--depth-range" in text
    scene = load_scene(temple_copy, SceneOptions(depth_range=(0.3, 1.0)))
    assert all(v.source_views for v in scene.views)  # falls back to camera geometry


def test_gt_with_another_aspect_ratio(fountain_copy):
    path = fountain_copy / "ground_truth" / "depth_maps" / "0002.jpg.bin"
    write_dense_map(path, np.ones((256, 300), np.float32))
    text = _error(fountain_copy)
    assert "0002.jpg.bin" in text and "not proportional" in text


def test_gt_with_non_finite_depth(fountain_copy):
    path = fountain_copy / "ground_truth" / "depth_maps" / "0001.jpg.bin"
    depth = read_depth_map(path)
    depth[10, 10] = np.nan
    write_dense_map(path, depth)
    text = _error(fountain_copy)
    assert "0001.jpg.bin" in text and "non-finite" in text


def test_truncated_gt_depth(fountain_copy):
    path = fountain_copy / "ground_truth" / "depth_maps" / "0001.jpg.bin"
    path.write_bytes(path.read_bytes()[:1000])
    text = _error(fountain_copy)
    assert "0001.jpg.bin" in text and "truncated" in text
