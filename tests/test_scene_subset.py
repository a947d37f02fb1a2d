"""What a per-view task holds of a scene (engine/scene.py): ``Scene.subset`` (its views and their images, no sparse
model), the compact image cache (8-bit pixels as the file holds them, the same floats on access), and the
triangulation angles of source-view selection computed one view at a time."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from conftest import SAMPLES
from PIL import Image

from engine.core.camera import Camera
from engine.io.colmap_model import SparseModel
from engine.io.images import decode_image, image_to_float, read_image, resize_area
from engine.scene import SceneOptions, load_scene, triangulation_angle_p75


@pytest.fixture(scope="module")
def tiny():
    return load_scene(SAMPLES / "tiny")


def _original_read(path) -> np.ndarray:
    """``read_image`` as it was before decoding and conversion were split (the reference)."""
    with Image.open(path) as image:
        image.load()
        if image.mode in ("I;16", "I;16B", "I"):
            array = np.repeat((np.asarray(image, dtype=np.float32) / 65535.0)[:, :, None], 3, axis=2)
        else:
            array = np.asarray(image.convert("RGB"), dtype=np.float32) / 255.0
    return np.ascontiguousarray(np.clip(array, 0.0, 1.0))


@pytest.mark.parametrize("mode", ["RGB", "RGBA", "L", "I;16"])
def test_decoded_pixels_give_the_floats_read_image_gave(tmp_path, mode):
    rng = np.random.default_rng(3)
    if mode == "I;16":
        image = Image.fromarray(rng.integers(0, 65536, (7, 9), dtype=np.uint16))
    else:
        bands = {"RGB": 3, "RGBA": 4, "L": 1}[mode]
        image = Image.fromarray(rng.integers(0, 256, (7, 9, bands), dtype=np.uint8).squeeze(), mode)
    path = tmp_path / "im.png"
    image.save(path)
    pixels = decode_image(path)
    assert pixels.dtype == (np.uint8 if mode != "I;16" else np.uint16)
    want = _original_read(path)
    assert np.array_equal(read_image(path), want) and np.array_equal(image_to_float(pixels), want)
    assert read_image(path).dtype == np.float32 and read_image(path).shape == (7, 9, 3)


def test_the_cache_holds_8_bit_images_at_the_working_size_as_bytes(tiny):
    w, h = tiny.views[0].original_size
    image = tiny.image(0)
    assert np.array_equal(image, _original_read(tiny.image_path(0))) and not image.flags.writeable
    assert tiny._image(0).dtype == np.uint8 and tiny._image(0).nbytes == w * h * 3  # a quarter of the floats
    small = load_scene(SAMPLES / "tiny", SceneOptions(max_image_size=96))
    size = small.views[0].camera.size
    assert size != (w, h) and small._image(0).dtype == np.float32  # resized floats are kept as they are
    assert np.array_equal(small.image(0), resize_area(_original_read(small.image_path(0)), size))


def test_a_subset_holds_its_views_and_reads_the_same_images(tiny):
    part = pickle.loads(pickle.dumps(tiny.subset([3, 0])))
    assert sorted(part.views) == [0, 3] and not hasattr(part, "model")
    assert len(pickle.dumps(part)) < 4000  # cameras, names, ranges, source views: no sparse points, no images
    for j in (0, 3):
        assert part.views[j].name == tiny.views[j].name and part.views[j].source_views == tiny.views[j].source_views
        assert np.array_equal(part.image(j), tiny.image(j)) and np.array_equal(part.gray(j), tiny.gray(j))
    with pytest.raises(KeyError):
        part.image(1)


def _angles_by_definition(model: SparseModel, cameras: list[Camera]) -> np.ndarray:
    """For each pair of views, the 75th percentile over every pair of their observations of one point."""
    n = len(cameras)
    out = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1, n):
            angles = []
            for p in range(len(model.points)):
                seen = model.track_image[model.track_point == p]
                ra, rb = cameras[i].center - model.points[p], cameras[j].center - model.points[p]
                angle = np.arccos(np.clip(ra @ rb / (np.linalg.norm(ra) * np.linalg.norm(rb)), -1, 1))
                angles += [angle] * int(np.sum(seen == i) * np.sum(seen == j))
            if angles:
                out[i, j] = out[j, i] = np.percentile(angles, 75)
    return out


def test_triangulation_angles_one_view_at_a_time_are_the_pairs_percentiles():
    rng = np.random.default_rng(0)
    cameras = [Camera.from_params(64, 48, 50, 50, 32, 24, np.eye(3), np.array([-k, 0.1 * k, 0.0]))
               for k in range(5)]
    points = rng.normal([2, 0, 8], 2, (30, 3))
    track_point, track_image = [], []
    for p in range(30):
        seen = rng.choice(5, rng.integers(1, 5), replace=False).tolist()
        if p % 7 == 0:
            seen.append(seen[0])  # a point observed twice by one view: its pairs count twice
        track_point += [p] * len(seen)
        track_image += seen
    order = rng.permutation(len(track_point))  # observations in no particular order
    model = SparseModel(None, {}, [], points, np.array(track_point)[order], np.array(track_image)[order])
    got = triangulation_angle_p75(model, cameras)
    want = _angles_by_definition(model, cameras)
    off = ~np.eye(5, dtype=bool)
    assert np.count_nonzero(want[off]) > 10 and np.allclose(got[off], want[off], rtol=1e-12, atol=0)
    assert np.array_equal(got, got.T)


def test_a_worker_sees_an_image_rewritten_at_the_same_path(tiny, tmp_path):
    """The per-process cache is keyed by the file's modification time and size: a worker outlives runs."""
    import os

    from engine.scene import SceneViews

    view = tiny.views[0]
    path = tmp_path / view.name
    path.parent.mkdir(parents=True, exist_ok=True)
    pixels = decode_image(tiny.image_path(0))
    Image.fromarray(pixels).save(path)
    part = SceneViews(tmp_path, {0: view})
    assert np.array_equal(part.image(0), tiny.image(0))
    Image.fromarray(255 - pixels).save(path)
    os.utime(path, ns=(1, 1))
    assert np.array_equal(part.image(0), image_to_float(255 - pixels))
