"""Fusion through a bounded cache of views (engine.fusion.cached): the same cloud as the in-memory fusion, byte for
byte, with caches small enough that views are evicted and loaded again in the middle of traversals."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from engine.fusion import FUSION_PRESETS, FusedCloud, FusionOptions, fuse, views_from_scene
from engine.fusion.cached import CacheStats, fuse_cached
from engine.scene import SceneOptions, load_scene
from support.gt_normals import depth_normals
from tests.conftest import SAMPLES
from tests.test_fusion import _plane_views


@pytest.fixture(scope="module")
def tiny_views():
    """The views of sample_scenes/tiny at 80 x 60 with GT depth made noisy (multiplicative noise, holes, outlier
    blobs, NaN), their normals and a confidence map per view."""
    scene = load_scene(SAMPLES / "tiny", SceneOptions(max_image_size=80))
    rng = np.random.default_rng(3)
    depths, normals, confidences = [], [], []
    for v in scene.views:
        gt = scene.gt_depth(v.index)
        h, w = gt.shape
        depth = gt * (1 + 0.002 * rng.normal(size=gt.shape))
        yy, xx = np.mgrid[:h, :w]
        for _ in range(4):
            cy, cx, r = rng.uniform(0, h), rng.uniform(0, w), rng.uniform(2, 5)
            blob = (yy - cy) ** 2 + (xx - cx) ** 2 < r * r
            depth[blob] *= 0.8
        depth[rng.random(gt.shape) < 0.05] = 0
        depth[rng.random(gt.shape) < 0.01] = np.nan
        normal = depth_normals(v.camera, gt)
        depths.append(depth.astype(np.float32))
        normals.append(normal.astype(np.float32))
        confidences.append(rng.random(gt.shape).astype(np.float32))
    return scene, depths, normals, confidences


def _same_bytes(a: FusedCloud, b: FusedCloud) -> None:
    for f in dataclasses.fields(FusedCloud):
        x, y = getattr(a, f.name), getattr(b, f.name)
        assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), f.name


def _cached(views, options, cache, confidence):
    stats = CacheStats()
    loads = []

    def load(i):
        loads.append(i)
        return views[i]

    cloud = fuse_cached([v.camera for v in views], [v.overlap for v in views], load, options, cache, confidence,
                        stats)
    assert stats.loads == len(loads) and stats.peak_resident <= (cache or len(views))
    return cloud, stats


@pytest.mark.parametrize(("preset", "with_confidence", "cache"), [
    ("pixels", False, 3), ("pixels", True, 3), ("pixels", True, 2), ("deepc", False, 3), ("deepc", True, 2),
    ("colmap", True, 3)])
def test_cached_fusion_is_the_in_memory_cloud(tiny_views, preset, with_confidence, cache):
    scene, depths, normals, confidences = tiny_views
    views = views_from_scene(scene, depths, normals, confidences if with_confidence else None)
    options = FUSION_PRESETS[preset]
    want = fuse(views, options)
    got, stats = _cached(views, options, cache, with_confidence)
    assert len(want) > 500
    _same_bytes(got, want)
    # views were evicted and loaded again in the middle of traversals
    assert stats.evictions > 0 and stats.loads > len(views) and stats.calls > stats.loads


@pytest.mark.parametrize("cache", [10, None])
def test_a_cache_holding_every_view_loads_each_once(tiny_views, cache):
    """None: 1 + the longest overlap list, here every view of tiny."""
    scene, depths, normals, _ = tiny_views
    views = views_from_scene(scene, depths, normals)
    got, stats = _cached(views, FUSION_PRESETS["pixels"], cache, False)
    _same_bytes(got, fuse(views, FUSION_PRESETS["pixels"]))
    assert stats.loads == len(views) and stats.evictions == 0 and stats.peak_resident == len(views)


def test_cached_fusion_of_views_with_and_without_confidence_and_sizes(monkeypatch):
    """Views of different sizes share the slots; a view without confidence reads NaN like the packed fusion; the
    output fills chunks of max_num_pixels points."""
    views, _, _ = _plane_views(n=6, w=40, h=30, noise=0.003, seed=5, drop=0.1)
    small, _, _ = _plane_views(n=6, w=24, h=18, noise=0.003, seed=6, drop=0.1)
    views[1], views[4] = small[1], small[4]
    options = FusionOptions(min_num_pixels=1, point_per_pixel=True, max_num_pixels=20)
    for k, v in enumerate(views):
        h, w = v.depth.shape
        v.confidence = None if k % 3 == 0 else np.linspace(0, 1, h * w, dtype=np.float32).reshape(h, w)
    want = fuse(views, options)
    monkeypatch.setattr("engine.fusion.cached.CHUNK_POINTS", 8)  # the output fills many chunks
    got, stats = _cached(views, options, 2, True)
    _same_bytes(got, want)
    assert stats.evictions > 0


def test_cached_fusion_refuses_a_cache_of_one_view():
    views, _, _ = _plane_views(n=3)
    with pytest.raises(ValueError, match="at least 2"):
        fuse_cached([v.camera for v in views], [v.overlap for v in views], views.__getitem__, cache_views=1)
    with pytest.raises(ValueError, match="depth shape"):
        fuse_cached([v.camera for v in views], [v.overlap for v in views],
                    lambda i: dataclasses.replace(views[i], depth=views[i].depth[:5]))
