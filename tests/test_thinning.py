"""Voxel thinning to a point budget (engine/core/thinning.py): plain numpy, no viewer."""

from __future__ import annotations

import numpy as np
import pytest

from engine.core.thinning import voxel_keys, voxel_size_for, voxel_thinning


def _surface(n: int, seed: int = 0) -> np.ndarray:
    """A dense patch and a sparse far strip: thinning must keep the strip."""
    rng = np.random.default_rng(seed)
    dense = np.column_stack([rng.random(n), rng.random(n), 0.01 * rng.random(n)])
    strip = np.column_stack([np.linspace(3, 4, 50), np.full(50, 2.0), np.zeros(50)])
    return np.vstack([dense, strip])


@pytest.mark.parametrize("budget", [1, 500, 5_000, 19_999])
def test_budget_respected_and_every_occupied_voxel_represented_once(budget):
    xyz = _surface(20_000)
    thinning = voxel_thinning(xyz, budget)
    chosen = thinning.select()
    assert 1 <= len(chosen) <= budget
    assert thinning.voxel > 0
    keys = voxel_keys(xyz, xyz.min(axis=0), thinning.voxel)
    # every voxel that holds a point holds exactly one chosen point, and it is the lowest-indexed one there
    assert len(np.unique(keys[chosen])) == len(chosen) == len(np.unique(keys))
    order = np.lexsort((np.arange(len(xyz)), keys))
    first = order[np.r_[True, keys[order][1:] != keys[order][:-1]]]
    np.testing.assert_array_equal(np.sort(chosen), np.sort(first))


def test_the_budget_is_used_not_wasted():
    xyz = _surface(40_000)
    chosen = voxel_thinning(xyz, 10_000).select()
    assert len(chosen) >= 0.5 * 10_000  # a size search, not a power-of-two grid that may land at a quarter


def test_sparse_parts_survive_where_every_kth_point_would_drop_them():
    xyz = _surface(40_000)
    chosen = voxel_thinning(xyz, 2_000).select()
    on_strip = np.count_nonzero(xyz[chosen, 0] >= 3)
    assert on_strip >= 10  # every 21st point would keep 2 or 3 of the 50


def test_deterministic_and_attributes_stay_with_their_points():
    xyz = _surface(30_000, seed=3)
    colors = (np.arange(len(xyz))[:, None] * [1, 7, 13] % 256).astype(np.uint8)  # a colour that names its point
    a, b = voxel_thinning(xyz, 3_000), voxel_thinning(xyz.copy(), 3_000)
    assert a.voxel == b.voxel
    np.testing.assert_array_equal(a.select(), b.select())
    chosen = a.select()
    np.testing.assert_array_equal(colors[chosen], (chosen[:, None] * [1, 7, 13] % 256).astype(np.uint8))
    np.testing.assert_array_equal(xyz[chosen], _surface(30_000, seed=3)[chosen])


def test_a_mask_thins_its_own_points_on_the_same_grid():
    xyz = _surface(30_000, seed=1)
    thinning = voxel_thinning(xyz, 2_000)
    mask = xyz[:, 0] < 0.5
    chosen = thinning.select(mask)
    assert mask[chosen].all()
    keys = voxel_keys(xyz, xyz.min(axis=0), thinning.voxel)
    assert len(chosen) == len(np.unique(keys[mask])) == len(np.unique(keys[chosen]))
    assert len(chosen) <= thinning.voxels <= 2_000


def test_clouds_within_the_budget_are_whole():
    xyz = _surface(100)
    thinning = voxel_thinning(xyz, 1_000)
    assert thinning.voxel == 0 and voxel_size_for(xyz, 1_000) == 0
    np.testing.assert_array_equal(thinning.select(), np.arange(len(xyz)))
    mask = np.arange(len(xyz)) % 3 == 0
    np.testing.assert_array_equal(thinning.select(mask), np.flatnonzero(mask))
    with pytest.raises(ValueError):
        voxel_size_for(xyz, 0)


@pytest.mark.parametrize("scale", [1.0, 0.02, 30.0])
def test_a_start_voxel_is_kept_when_it_fits_and_searched_from_when_not(scale):
    """A filtered cloud starts from its unfiltered cloud's voxel: kept when its grid fits the budget (the previews'
    resolution), however sparse the filter left it; a start over the budget is searched from, filling the budget
    within [FILL, 1]; the points are the grid's of that voxel, ascending."""
    from engine.core.thinning import FILL, thin_to_budget

    xyz = _surface(20_000)
    budget = 3_000
    fitted = voxel_thinning(xyz, budget)
    subset = xyz[np.random.default_rng(1).random(len(xyz)) < 0.6]  # a strict filter's part of the cloud
    keep, voxel = thin_to_budget(subset, budget, start=fitted.voxel * scale)
    assert len(keep) <= budget and np.all(np.diff(keep) > 0)
    if scale >= 1.0:
        assert voxel == fitted.voxel * scale  # fits: the start's grid, as coarse as it is
    else:  # far too fine: over the budget, searched
        assert len(keep) >= FILL * budget
    np.testing.assert_array_equal(keep, voxel_thinning(subset, budget, voxel=voxel).select())
    keep, voxel = thin_to_budget(subset[:100], budget, start=fitted.voxel)
    assert voxel == 0.0 and len(keep) == 100


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_first_per_voxel_is_the_sorted_grids_choice_in_one_pass(dtype):
    """The one-pass kernel keeps the points the sorted grid keeps (the lowest-indexed of each voxel), in index
    order, and says when the voxels exceed the budget instead of sending more."""
    from engine.core.thinning import first_per_voxel

    xyz = _surface(30_000, seed=5).astype(dtype)
    grid = voxel_thinning(xyz, 2_500)
    reference = grid.select()
    np.testing.assert_array_equal(first_per_voxel(xyz, grid.voxel, 2_500), reference)
    np.testing.assert_array_equal(first_per_voxel(xyz, grid.voxel, len(reference)), reference)
    assert first_per_voxel(xyz, grid.voxel, len(reference) - 1) is None
    assert len(first_per_voxel(xyz[:0], grid.voxel, 10)) == 0
