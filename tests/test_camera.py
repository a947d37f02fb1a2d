"""Camera conventions: continuous K, index-space K, exact rescaling, projection."""

from __future__ import annotations

import numpy as np

from engine.core.camera import Camera, rescaled_size


def _rotation(rng) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def test_projection_and_backprojection_round_trip():
    rng = np.random.default_rng(0)
    cam = Camera.from_params(64, 48, 60.0, 62.0, 31.7, 24.2, _rotation(rng), rng.normal(size=3))
    depth = rng.uniform(2, 5, size=(48, 64)).astype(np.float32)
    world = cam.backproject(depth)
    uv, z = cam.project(world.reshape(-1, 3))
    cols, rows = np.meshgrid(np.arange(64), np.arange(48))
    np.testing.assert_allclose(uv[:, 0], cols.ravel(), atol=1e-8)
    np.testing.assert_allclose(uv[:, 1], rows.ravel(), atol=1e-8)
    np.testing.assert_allclose(z, depth.ravel(), rtol=1e-6)


def test_pixel_centre_convention():
    cam = Camera.from_params(4, 2, 10.0, 10.0, 2.0, 1.0)
    # The continuous principal point (2, 1) is the corner between pixels (1, 0) and (2, 1): index space 1.5, 0.5.
    np.testing.assert_allclose(cam.K_idx[:2, 2], [1.5, 0.5])
    uv, _ = cam.project(np.array([[0.0, 0.0, 1.0]]))
    np.testing.assert_allclose(uv[0], [1.5, 0.5])


def test_rescaling_is_exact_in_continuous_coordinates():
    rng = np.random.default_rng(1)
    cam = Camera.from_params(1536, 1024, 1379.7, 1382.1, 760.6, 503.7, _rotation(rng), rng.normal(size=3))
    width, height = rescaled_size(1536, 1024, 768)
    assert (width, height) == (768, 512)
    small = cam.rescaled(width, height)
    points = cam.camera_to_world(np.c_[rng.uniform(-1, 1, (20, 2)), rng.uniform(3, 6, 20)])
    big_uv, _ = cam.project(points)
    small_uv, _ = small.project(points)
    # Continuous coordinates (index + 0.5) scale exactly with the size ratio.
    np.testing.assert_allclose((small_uv + 0.5) * 2.0, big_uv + 0.5, atol=1e-9)


def test_rescaled_size_rounds_and_never_upscales():
    assert rescaled_size(1000, 333, 500) == (500, 166)
    assert rescaled_size(100, 80, 500) == (100, 80)
    assert rescaled_size(100, 80, 0) == (100, 80)
