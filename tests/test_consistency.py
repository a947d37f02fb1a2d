"""Counter maps (engine.consistency) against a plain-Python reference and on ground-truth maps."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import support.patchmatch_reference as ref
from engine.consistency import CounterOptions, compute_counter_maps
from engine.core.errors import OptionsError
from engine.patchmatch import PatchMatchOptions, ViewMaps
from support.pm_synthetic import make_scene


@pytest.fixture(scope="module")
def gt_maps():
    views, gts = make_scene(64, 48, n_views=3)
    maps = []
    for v, gt in zip(views, gts, strict=True):
        X = v.camera.pixel_rays() * gt[..., None]
        n = np.cross(np.gradient(X, axis=1), np.gradient(X, axis=0))
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        n[np.einsum("hwc,hwc->hw", n, v.camera.pixel_rays()) > 0] *= -1
        maps.append(ViewMaps(gt.copy(), n.astype(np.float32), np.zeros_like(gt), np.zeros(gt.shape, np.uint32)))
    return views, maps


def _counter_ref(views, maps, i: int, x: int, y: int, o: CounterOptions) -> int:
    v, m = views[i], maps[i]
    z, n = float(m.depth[y, x]), m.normal[y, x].astype(np.float64)
    if z <= 0:
        return 0
    prob = ref.RefProblem(v.image_gray, v.camera, [views[j].image_gray for j in v.source_views],
                          [views[j].camera for j in v.source_views], [maps[j].depth for j in v.source_views],
                          PatchMatchOptions())
    X = z * prob.ray(x, y)
    count = 0
    for k, j in enumerate(v.source_views):
        c, s = v.camera, views[j].camera
        err = ref.reprojection_error_ref(c.K_idx, c.R, c.t, s.K_idx, s.R, s.t, maps[j].depth, x, y, z)
        if err < 0 or err > o.reproj_px:
            continue
        Cj = c.R @ s.center + c.t  # source centre in the reference frame
        a, b = -X, Cj - X
        angle = math.degrees(math.acos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1)))
        if angle < o.tri_angle_min_deg or (o.check_facing and n @ b <= 0):
            continue
        if prob.photometric(x, y, z, n, k) > 1 - o.ncc_min:
            continue
        count += 1
    return min(count, o.cap)


def test_counter_matches_reference(gt_maps) -> None:
    views, maps = gt_maps
    o = CounterOptions(tri_angle_min_deg=1.0)
    counters = compute_counter_maps(views, maps, o)
    rng = np.random.default_rng(0)
    for i in range(len(views)):
        assert counters[i].dtype == np.uint8 and counters[i].shape == maps[i].depth.shape
        for _ in range(25):
            x, y = int(rng.integers(0, 64)), int(rng.integers(0, 48))
            assert counters[i][y, x] == _counter_ref(views, maps, i, x, y, o), (i, x, y)


def test_counter_on_ground_truth_is_high_and_drops_for_wrong_depth(gt_maps) -> None:
    views, maps = gt_maps
    o = CounterOptions(tri_angle_min_deg=1.0)
    good = compute_counter_maps(views, maps, o)
    assert np.mean([(c >= 1).mean() for c in good]) > 0.8
    wrong = [dataclasses.replace(maps[0], depth=maps[0].depth * 1.2)] + maps[1:]
    bad = compute_counter_maps(views, wrong, o)
    assert bad[0].mean() < 0.3 * good[0].mean()


def test_counter_empty_and_options(gt_maps) -> None:
    views, maps = gt_maps
    empty = [ViewMaps.empty(*m.depth.shape) for m in maps]
    assert all(not c.any() for c in compute_counter_maps(views, empty))
    capped = compute_counter_maps(views, maps, CounterOptions(cap=1, tri_angle_min_deg=1.0))
    assert max(int(c.max()) for c in capped) == 1
    for bad in (dict(reproj_px=0), dict(cap=0), dict(rel_depth=-1.0), dict(tri_angle_min_deg=95)):
        with pytest.raises(OptionsError):
            CounterOptions(**bad).validate()
    strict = compute_counter_maps(views, maps, CounterOptions(tri_angle_min_deg=1.0, rel_depth=1e-6))
    assert sum(int(c.sum()) for c in strict) <= sum(int(c.sum()) for c in compute_counter_maps(
        views, maps, CounterOptions(tri_angle_min_deg=1.0)))
