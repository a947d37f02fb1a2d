"""The evaluation's lean kernels (Morton keys, voxel ids, chunked k-d tree queries) give exactly what the numpy
array expressions they replace gave (Schöps et al. 2017 scoring; the memory they save is in
benchmarks/results/bench_memory.json)."""

from __future__ import annotations

import numpy as np
import pytest

from engine.evaluation import EvaluationOptions, PointIndex, evaluate_points
from engine.evaluation import point_index as P
from engine.evaluation import voxels as V
from engine.evaluation.point_index import spread_bits


def _spatial_order_numpy(points):
    lo = points.min(axis=0)
    extent = float((points.max(axis=0) - lo).max())
    scale = (2**21 - 1) / extent if extent > 0 else 0.0
    c = ((points - lo) * scale).astype(np.int64)
    key = spread_bits(c[:, 0]) | (spread_bits(c[:, 1]) << 1) | (spread_bits(c[:, 2]) << 2)
    return np.argsort(key, kind="stable")


def _cell_ids_numpy(points, voxel_size, shift):
    inv = np.float32(1.0 / float(np.float32(voxel_size)))
    cells = np.floor(points.astype(np.float32) * inv + np.float32(shift)).astype(np.int64)
    lo = cells.min(axis=0)
    span = cells.max(axis=0) - lo + 1
    key = ((cells[:, 0] - lo[0]) * span[1] + (cells[:, 1] - lo[1])) * span[2] + (cells[:, 2] - lo[2])
    return np.unique(key, return_inverse=True)[1].ravel()


def _first_within_one_tree(queries, data, tolerances):
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(data).query(queries, k=1, distance_upper_bound=float(tolerances[-1]) * (1 + 1e-6))
    return np.searchsorted(tolerances, dist, side="left")


CLOUDS = {
    "float64": np.random.default_rng(0).random((20000, 3)) * [3, 2, 1] - 1,
    "float32": (np.random.default_rng(1).random((8000, 3)) * 10).astype(np.float32),
    "repeated": np.repeat(np.random.default_rng(2).random((700, 3)), 3, axis=0),
    "fortran": np.asfortranarray(np.random.default_rng(3).normal(0, 5, (3000, 3))),
}


@pytest.mark.parametrize("name", sorted(CLOUDS))
def test_morton_order_and_voxel_ids_match_the_array_expressions(name):
    pts = CLOUDS[name]
    assert np.array_equal(P._spatial_order(pts), _spatial_order_numpy(pts))
    for voxel, shift in ((0.01, 0.0), (0.05, 0.5), (0.3, 0.5)):
        ids = V._cell_ids(pts, voxel, shift)
        assert ids.dtype == np.int64 and np.array_equal(ids, _cell_ids_numpy(pts, voxel, shift))
    assert len(V._cell_ids(pts[:0], 0.01, 0.0)) == 0


def test_chunked_queries_and_trees_find_the_same_nearest_points(monkeypatch):
    rng = np.random.default_rng(4)
    tol = np.array([0.01, 0.02, 0.05, 0.1])
    data = CLOUDS["float64"]
    queries = np.concatenate([data[::4] + rng.normal(0, 0.03, (len(data[::4]), 3)), rng.random((300, 3)) * 5])
    expected = _first_within_one_tree(queries, data, tol)
    assert 0 < (expected == len(tol)).sum() < len(expected)  # some queries have no data point within 0.1
    monkeypatch.setattr(P, "QUERY_CHUNK", 997)
    monkeypatch.setattr(P, "TREE_CHUNK", 3001)
    assert np.array_equal(P.first_within(queries, data, tol), expected)  # 7 trees, 6 query chunks
    # a PointIndex answers in its own (Morton) order
    assert np.array_equal(P.first_within(PointIndex(queries), PointIndex(data), tol),
                          expected[_spatial_order_numpy(queries)])
    assert np.array_equal(P.first_within(queries.astype(np.float32), data, tol),
                          _first_within_one_tree(queries.astype(np.float32).astype(np.float64), data, tol))


def test_scores_do_not_depend_on_the_chunk_sizes(monkeypatch):
    rng = np.random.default_rng(5)
    gt = CLOUDS["float64"]
    recon = np.concatenate([gt[::2] + rng.normal(0, 0.01, (len(gt[::2]), 3)), rng.random((500, 3))])
    options = EvaluationOptions(voxel_size=0.05)
    whole = evaluate_points(recon, gt, options).to_dict()
    monkeypatch.setattr(P, "QUERY_CHUNK", 1000)
    monkeypatch.setattr(P, "TREE_CHUNK", 2500)
    assert evaluate_points(recon, gt, options).to_dict() == whole


def test_the_gt_index_holds_one_copy_of_the_points():
    """A PointIndex keeps its points once, in Morton order, as its tree's own data: the array given can be freed
    (the scoring of a run then holds 32 bytes a GT point, not the given order, its permutation and a sorted copy)."""
    pts = CLOUDS["float64"]
    index = PointIndex(pts)
    assert np.array_equal(index.points, pts[_spatial_order_numpy(pts)])
    assert index.points is index.tree.data and not np.shares_memory(index.points, pts)
    assert index.tree.leafsize == P.INDEX_LEAF_SIZE


def _old_chunked_completeness(gt, chunks, tol):
    """The chunked completeness as it was (nearest float64 distance per GT point, in the given order)."""
    from scipy.spatial import cKDTree

    nearest = np.full(len(gt), np.inf)
    for xyz in chunks:
        dist, _ = cKDTree(xyz).query(gt, k=1, distance_upper_bound=float(tol[-1]) * (1 + 1e-6))
        nearest = np.minimum(nearest, dist)
    return np.searchsorted(tol, nearest, side="left")


def test_chunked_scores_equal_the_whole_array_reference_with_a_small_completeness_memory(monkeypatch):
    """evaluate_point_chunks's scores are the one-tree, given-order reference's to the last bit, and while the chunks
    are scored it holds a byte per GT point for completeness besides a query's points (it held 32 bytes a GT point,
    and a 24-byte copy of those near each chunk)."""
    import tracemalloc

    from engine.evaluation import chunked

    rng = np.random.default_rng(6)
    gt = rng.random((200_000, 3)) * [3.0, 1.0, 1.0]
    recon = np.concatenate([gt[::8] + rng.normal(0, 0.01, (len(gt[::8]), 3)), rng.random((2_000, 3)) * 3])
    tol = np.array([0.01, 0.02, 0.05])
    options = EvaluationOptions(tolerances=tuple(tol), voxel_size=0.05)
    monkeypatch.setattr(chunked, "CHUNK_POINTS", 5_000)
    monkeypatch.setattr(chunked, "QUERY_CHUNK", 10_000)  # the GT points a query takes at once
    first_ok = _first_within_one_tree(recon, gt, tol)
    inaccurate = first_ok[:, None] > np.arange(len(tol))[None, :]
    acc = V.voxel_accuracy(recon, first_ok, inaccurate, 0.05)
    chunks = [recon[s:s + 5_000] for s in range(0, len(recon), 5_000)]
    comp = V.voxel_completeness(gt, _old_chunked_completeness(gt, chunks, tol), len(tol), 0.05)
    want = chunked.make_result(tol, acc, comp, len(recon), len(gt), np.zeros(len(tol)),
                               chunked.overlap_notes(acc, comp, len(recon), tol))

    index = PointIndex(gt)
    at_completeness = []
    voxel_completeness = chunked.voxel_completeness

    def spy(*args):
        at_completeness.append(tracemalloc.get_traced_memory()[1])
        return voxel_completeness(*args)

    # the kernels compiled (or loaded from numba's cache) before the allocations are traced
    chunked.evaluate_point_chunks(len(recon[:100]), lambda s, c: recon[s:s + c].copy(), gt[:100], options)
    monkeypatch.setattr(chunked, "voxel_completeness", spy)
    tracemalloc.start()
    try:
        got = chunked.evaluate_point_chunks(len(recon), lambda s, c: recon[s:s + c].copy(), index, options)
    finally:
        tracemalloc.stop()
    assert got == want
    assert at_completeness[0] < 8 * len(gt), at_completeness  # 5.5 here; the old code held 32 and copied 24
