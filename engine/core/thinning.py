"""Voxel thinning of a point set to a point budget: one point per occupied voxel, the voxel size chosen so that
the occupied voxels fit the budget.

The one owner of the rule the tuning viewer (``workbench/viewer/app.py``) uses to send at most a budget of points
to the browser (docs/decisions.md, "Viewer: at most 200 000 points ..."). Unlike every k-th point, a voxel keeps
sparse parts of a cloud (a thin wall, a far facade) as they are and thins only where points are dense, so the
picture keeps its shape. Deterministic: the grid starts at the points' minimum corner and a voxel's point is the
one with the lowest index among those in it (the mask's, when masked).
"""

from __future__ import annotations

import dataclasses

import numba
import numpy as np

MAX_STEPS = 40  # voxel sizes tried at most; the search usually settles in 3-5
FILL = 0.9  # a voxel size whose occupied voxels are within [FILL, 1] x the budget is taken at once


def voxel_keys(xyz: np.ndarray, origin: np.ndarray, voxel: float) -> np.ndarray:
    """(N,) int64 key of each point's voxel of edge ``voxel`` (model units) on a grid from ``origin`` ((3,))."""
    cells = np.floor((np.asarray(xyz, np.float64) - origin) / voxel).astype(np.int64)
    cells = np.maximum(cells, 0)  # (rounding at the minimum corner)
    extent = cells.max(axis=0) + 1 if len(cells) else np.ones(3, np.int64)
    return (cells[:, 0] * extent[1] + cells[:, 1]) * extent[2] + cells[:, 2]


@dataclasses.dataclass(frozen=True)
class VoxelThinning:
    """A voxel grid over a point set, numbered so that any mask of it thins in one linear pass (:meth:`select`).

    Attributes:
        voxel: voxel edge in model units; 0 when the points fit the budget (nothing is thinned).
        count: points of the whole set (N).
        voxels: occupied voxels of the whole set (what :meth:`select` returns without a mask).
        voxel_of: (N,) int32 voxel number (0 .. voxels - 1, by ascending :func:`voxel_keys` key) of each point, in
            the points' order; None when nothing is thinned.
    """

    voxel: float
    count: int
    voxels: int
    voxel_of: np.ndarray | None = None

    def select(self, mask: np.ndarray | None = None) -> np.ndarray:
        """(M,) int64 indices, ascending, one per voxel that holds a point of ``mask`` ((N,) bool; None: every
        point): the lowest-indexed such point. Without thinning (``voxel`` 0) the masked indices.

        Index the points' colours and attributes with the result: they stay with their points. One sequential
        pass over the points, not a gather through a voxel-sorted order: a preview's whole cost on a cloud of
        millions of points."""
        if self.voxel == 0:
            return np.arange(self.count, dtype=np.int64) if mask is None else np.flatnonzero(mask)
        if mask is None:
            mask = np.ones(self.count, np.bool_)
        return _first_masked(np.ascontiguousarray(mask, np.bool_), self.voxel_of, self.voxels)


@numba.njit(cache=True, nogil=True)
def _first_masked(mask: np.ndarray, voxel_of: np.ndarray, voxels: int) -> np.ndarray:
    """:meth:`VoxelThinning.select`'s pass: the first masked point of each voxel, in the points' order."""
    seen = np.zeros(voxels, np.bool_)
    out = np.empty(voxels, np.int64)
    m = 0
    for i in range(mask.shape[0]):
        if mask[i]:
            v = voxel_of[i]
            if not seen[v]:
                seen[v] = True
                out[m] = i
                m += 1
    return out[:m]


def _occupied(xyz: np.ndarray, origin: np.ndarray, voxel: float) -> int:
    return len(np.unique(voxel_keys(xyz, origin, voxel)))


def voxel_size_for(xyz: np.ndarray, max_points: int, start: float | None = None) -> float:
    """The voxel edge (model units) at which the occupied voxels of ``xyz`` ((N, 3)) are at most ``max_points``
    and, where the search allows, at least :data:`FILL` of it; 0 when N ≤ ``max_points``.

    A bracketed search from ``start`` (default: a flat square's spacing): the next size follows the count's power
    of the size measured over the last two steps (first a surface's, count ∝ 1/size²) and falls back to halving
    the bracket in log space when that guess leaves it; deterministic for given points and start."""
    if max_points < 1:
        raise ValueError(f"a point budget must be at least 1, not {max_points}")
    n = len(xyz)
    if n <= max_points:
        return 0.0
    xyz = np.asarray(xyz, np.float64)
    origin = xyz.min(axis=0)
    extent = float((xyz.max(axis=0) - origin).max())
    if extent == 0.0:
        return 1.0  # every point in one place: one voxel holds them all
    hi = extent * 1.0001  # one voxel along every axis: at most 1 point
    lo, voxel = 0.0, extent / max(1.0, np.sqrt(max_points))  # a flat square's spacing: a first guess
    if start is not None and 0.0 < start < hi:
        voxel = float(start)
    best, previous, power = hi, None, 2.0
    for _ in range(MAX_STEPS):
        count = _occupied(xyz, origin, voxel)
        if count <= max_points:
            best = min(best, voxel)
            hi = min(hi, voxel)
            if count >= FILL * max_points:
                break
        else:
            lo = max(lo, voxel)
        if previous is not None and previous[0] != voxel and previous[1] != count and count > 0:
            # the count's local power of the size, from the last two steps (2 on a surface, 3 in a volume)
            power = float(np.clip(np.log(previous[1] / count) / np.log(voxel / previous[0]), 0.5, 3.0))
        previous = (voxel, count)
        guess = voxel * (count / (0.95 * max_points)) ** (1.0 / power)
        voxel = guess if lo < guess < hi else (np.sqrt(lo * hi) if lo > 0 else hi / 2)
        if hi - lo <= 1e-9 * extent:
            break
    return float(best)


def voxel_thinning(xyz: np.ndarray, max_points: int, voxel: float | None = None) -> VoxelThinning:
    """The grid of :func:`voxel_size_for` over ``xyz`` ((N, 3), model units), or of a given ``voxel`` edge, numbered
    for :meth:`VoxelThinning.select`; ``select()`` then returns at most ``max_points`` indices."""
    n = len(xyz)
    if voxel is None:
        voxel = voxel_size_for(xyz, max_points)
    if voxel == 0.0:
        return VoxelThinning(0.0, n, n)
    keys = voxel_keys(xyz, np.asarray(xyz, np.float64).min(axis=0), voxel)
    unique, voxel_of = np.unique(keys, return_inverse=True)
    return VoxelThinning(float(voxel), n, len(unique), voxel_of.astype(np.int32))


@numba.njit(cache=True, nogil=True)
def _first_per_voxel(xyz: np.ndarray, voxel: float, limit: int) -> np.ndarray:
    """:func:`first_per_voxel`'s kernel: one pass over the points with an open-addressing table of the voxel keys
    (room for 2 x ``limit`` keys, so it stays in cache), stopping once ``limit`` voxels are exceeded."""
    n = xyz.shape[0]
    lo = np.empty(3)
    hi = np.empty(3)
    for a in range(3):
        lo[a] = xyz[0, a]
        hi[a] = xyz[0, a]
    for i in range(n):
        for a in range(3):
            v = np.float64(xyz[i, a])
            lo[a] = min(lo[a], v)
            hi[a] = max(hi[a], v)
    # the grid of voxel_keys: cells from the minimum corner, the same float64 arithmetic, so the same voxels
    e1 = np.int64(max(np.floor((hi[1] - lo[1]) / voxel), 0.0)) + 1
    e2 = np.int64(max(np.floor((hi[2] - lo[2]) / voxel), 0.0)) + 1
    bits = 1
    while (1 << bits) < 2 * limit:
        bits += 1
    table = np.full(1 << bits, -1, np.int64)
    slot_mask = (1 << bits) - 1
    shift = np.uint64(64 - bits)
    keep = np.empty(limit + 1, np.int64)
    m = 0
    for i in range(n):
        c0 = max(np.int64(np.floor((np.float64(xyz[i, 0]) - lo[0]) / voxel)), 0)
        c1 = max(np.int64(np.floor((np.float64(xyz[i, 1]) - lo[1]) / voxel)), 0)
        c2 = max(np.int64(np.floor((np.float64(xyz[i, 2]) - lo[2]) / voxel)), 0)
        key = (c0 * e1 + c1) * e2 + c2
        h = np.int64((np.uint64(key) * np.uint64(0x9E3779B97F4A7C15)) >> shift)
        while table[h] != -1 and table[h] != key:
            h = (h + 1) & slot_mask
        if table[h] == -1:
            if m == limit:
                return keep[:m + 1]  # one more than allowed: the caller's "does not fit"
            table[h] = key
            keep[m] = i
            m += 1
    return keep[:m]


def first_per_voxel(xyz: np.ndarray, voxel: float, max_points: int) -> np.ndarray | None:
    """(M,) int64 indices, ascending, of the lowest-indexed point of ``xyz`` ((N, 3), model units) in each voxel of
    edge ``voxel`` on :func:`voxel_keys`' grid (from the points' minimum corner): what
    ``voxel_thinning(xyz, ..., voxel=voxel).select()`` returns, in one linear pass instead of a sort; None when
    more than ``max_points`` voxels are occupied."""
    if voxel <= 0.0 or max_points < 1:
        raise ValueError(f"first_per_voxel needs a voxel edge > 0 and a budget >= 1, not {voxel} and {max_points}")
    if len(xyz) == 0:
        return np.zeros(0, np.int64)
    keep = _first_per_voxel(np.ascontiguousarray(xyz), float(voxel), int(max_points))
    return None if len(keep) > max_points else keep


def thin_to_budget(xyz: np.ndarray, max_points: int, start: float | None = None) -> tuple[np.ndarray, float]:
    """Indices of at most ``max_points`` points of ``xyz`` ((N, 3)), ascending, one per occupied voxel, and the
    voxel edge (model units; 0: all N points, they fit). One pass (:func:`first_per_voxel`) once the edge is known.

    ``start``: the voxel edge of a cloud this one is part of (the tuning viewer's unfiltered cloud, whose grid its
    previews show): kept when its grid fits the budget, however few voxels a strict filter leaves, so the exact
    cloud keeps the previews' resolution; else the size search starts from it."""
    n = len(xyz)
    if n <= max_points:
        return np.arange(n, dtype=np.int64), 0.0
    if start is not None and start > 0.0:
        keep = first_per_voxel(xyz, start, max_points)
        if keep is not None:
            return keep, float(start)
    voxel = voxel_size_for(xyz, max_points, start=start)
    return first_per_voxel(xyz, voxel, max_points), voxel
