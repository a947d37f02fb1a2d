"""Nearest-point queries within each tolerance on a spatially ordered k-d tree (``PointIndex``).

Memory: a fused cloud of fountain_p11 at 768x512 holds 3.5 M points (84 MB as float64), so every (N, 3)
temporary counts. The Morton keys are computed in one pass without the float and integer (N, 3) copies numpy
would make, the queries run in chunks of :data:`QUERY_CHUNK` points (the k-d tree answers each point on its
own: chunking changes no result) and a cloud queried as data is indexed in pieces of :data:`TREE_CHUNK` points.
"""

from __future__ import annotations

from collections.abc import Iterator

import numba
import numpy as np
from scipy.spatial import cKDTree

from engine.core.errors import DeepCError
from engine.evaluation.voxels import as_points


@numba.njit(cache=True, nogil=True)
def spread_bits(x: np.ndarray) -> np.ndarray:
    x = x & 0x1FFFFF
    x = (x | (x << 32)) & 0x1F00000000FFFF
    x = (x | (x << 16)) & 0x1F0000FF0000FF
    x = (x | (x << 8)) & 0x100F00F00F00F00F
    x = (x | (x << 4)) & 0x10C30C30C30C30C3
    x = (x | (x << 2)) & 0x1249249249249249
    return x



QUERY_CHUNK = 1 << 18  # points per k-d tree query (6 MB of float64 coordinates)
TREE_CHUNK = 1 << 20  # data points per k-d tree of first_within (24 MB of float64 coordinates)
# Points per leaf of a PointIndex's tree: its nodes take 39 MiB for fountain_p11's 946 k GT points at scipy's
# default 16, 23 MiB at 32, at the same query time (a leaf's distances are computed as any other's: the
# nearest distance, and so every score, does not depend on it)
INDEX_LEAF_SIZE = 32


@numba.njit(cache=True, nogil=True)
def _morton_keys(points: np.ndarray, lo: np.ndarray, scale: float) -> np.ndarray:
    """(N,) int64 Morton keys of ``floor((p - lo) * scale)`` in the points' own float type (numpy's rules:
    ``lo`` and ``scale`` come in that type), as the array expression computed them."""
    n = points.shape[0]
    key = np.empty(n, np.int64)
    for i in range(n):
        c0 = np.int64((points[i, 0] - lo[0]) * scale)
        c1 = np.int64((points[i, 1] - lo[1]) * scale)
        c2 = np.int64((points[i, 2] - lo[2]) * scale)
        key[i] = spread_bits(c0) | (spread_bits(c1) << 1) | (spread_bits(c2) << 2)
    return key


def _spatial_order(points: np.ndarray) -> np.ndarray:
    """A Morton (Z-curve) order: kd-tree queries in this order are several times faster (cache)."""
    if len(points) < 2:
        return np.arange(len(points))
    lo = points.min(axis=0)
    extent = float((points.max(axis=0) - lo).max())
    scale = (2 ** 21 - 1) / extent if extent > 0 else 0.0
    points = np.asarray(points)
    if points.dtype not in (np.float32, np.float64):
        points = points.astype(np.result_type(points.dtype, lo.dtype, scale))
    key = _morton_keys(points, lo.astype(points.dtype), points.dtype.type(scale))
    return np.argsort(key, kind="stable")



class PointIndex:
    """Points prepared for nearest-neighbour queries, as queries and as data: the points in their Morton order and
    a k-d tree over them. Building them takes about a second for 1M points; pass one to :func:`evaluate_points` in
    place of the GT array when the same GT scores many clouds (the viewer).

    ``points`` holds the points in Morton order, not in the order given (every score is a sum over voxels or a
    per-point nearest distance, neither depends on the order), and is the tree's own data: one float64 copy of
    the points (the given array can then be freed) instead of the given order, its permutation and the tree's
    sorted copy (fountain_p11's 946 k GT points: about 90 MiB resident, the array read included, -> 39 MiB
    with :data:`INDEX_LEAF_SIZE`)."""

    def __init__(self, points: np.ndarray, what: str = "ground truth"):
        points = np.asarray(as_points(points, what), np.float64)
        if len(points) == 0:
            raise DeepCError(f"the {what} has no points: nothing to evaluate against")
        self.tree = cKDTree(points[_spatial_order(points)], leafsize=INDEX_LEAF_SIZE, balanced_tree=False,
                            compact_nodes=False)
        self.points: np.ndarray = self.tree.data  # (M, 3) float64 in Morton order, shared with the tree

    def __len__(self) -> int:
        return len(self.points)



def _trees(data: np.ndarray | PointIndex) -> Iterator[cKDTree]:
    """k-d trees whose union holds the data points: a PointIndex's own tree, else one tree per
    :data:`TREE_CHUNK` points of the array in Morton order (spatially compact pieces), built one at a time so
    that only one piece's tree is alive (a tree takes ~3x the float64 coordinates)."""
    if isinstance(data, PointIndex):
        yield data.tree
        return
    points = np.asarray(as_points(data, "data"), np.float64)
    order = _spatial_order(points)
    for start in range(0, len(order), TREE_CHUNK):
        yield cKDTree(points[order[start:start + TREE_CHUNK]], balanced_tree=False, compact_nodes=False)


def first_within(queries: np.ndarray | PointIndex, data: np.ndarray | PointIndex,
                  tolerances: np.ndarray) -> np.ndarray:
    """(Q,) int: index of the smallest tolerance >= the distance from each query to its nearest data
    point (len(tolerances) if none, including when ``data`` is empty), in the order of the queries (of a
    PointIndex: its points', the Morton order).

    The nearest distance over the data is the smallest over its pieces (:func:`_trees`), each found exactly
    (the same float operations per point pair), so the pieces change no result."""
    n_tol = len(tolerances)
    if len(queries) == 0 or len(data) == 0:
        return np.full(len(queries), n_tol, np.int64)
    # a PointIndex's points are in Morton order already: its chunks are slices (no permutation array)
    order = None if isinstance(queries, PointIndex) else _spatial_order(queries)
    queries = np.asarray(queries.points if isinstance(queries, PointIndex) else queries)
    bound = float(tolerances[-1]) * (1 + 1e-6)
    nearest = np.full(len(queries), np.inf)
    for tree in _trees(data):
        for start in range(0, len(queries), QUERY_CHUNK):
            chunk = slice(start, start + QUERY_CHUNK) if order is None else order[start:start + QUERY_CHUNK]
            dist, _ = tree.query(np.asarray(queries[chunk], np.float64), k=1, distance_upper_bound=bound,
                                 workers=-1)
            nearest[chunk] = np.minimum(nearest[chunk], dist)
    # first t with distance <= t; inf (nothing within the largest tolerance) -> n_tol
    return np.searchsorted(tolerances, nearest, side="left").astype(np.int64, copy=False)
