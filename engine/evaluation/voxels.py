"""Density-normalised scores: means over the occupied voxels of two shifted grids (ETH3D, Schöps et al. 2017)."""

from __future__ import annotations

import numba
import numpy as np

from engine.core.errors import DeepCError

GRID_SHIFTS = (0.0, 0.5)



def as_points(xyz: np.ndarray, what: str) -> np.ndarray:
    xyz = np.asarray(xyz)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise DeepCError(f"{what} must be an (N, 3) array of points, got shape {xyz.shape}")
    if len(xyz) and not np.isfinite(xyz).all():
        raise DeepCError(f"{what} has non-finite coordinates")
    return xyz



@numba.njit(cache=True, nogil=True)
def _cell(p: float, inv: np.float32, shift: np.float32) -> int:
    # float32 arithmetic as the official code: float32(p) * inv + shift, then floor
    return int(np.floor(np.float32(p) * inv + shift))


@numba.njit(cache=True, nogil=True)
def _cell_bounds(points: np.ndarray, inv: np.float32, shift: np.float32) -> tuple[np.ndarray, np.ndarray]:
    """(3,) int64 smallest and largest cell index per axis (at least one point)."""
    lo = np.empty(3, np.int64)
    for k in range(3):
        lo[k] = _cell(points[0, k], inv, shift)
    hi = lo.copy()
    for i in range(1, points.shape[0]):
        for k in range(3):
            c = _cell(points[i, k], inv, shift)
            lo[k] = min(lo[k], c)
            hi[k] = max(hi[k], c)
    return lo, hi


@numba.njit(cache=True, nogil=True)
def _cell_keys(points: np.ndarray, inv: np.float32, shift: np.float32, lo: np.ndarray, span: np.ndarray) -> np.ndarray:
    """(N,) int64 row-major key of each point's cell in the box ``lo`` .. ``lo + span``."""
    key = np.empty(points.shape[0], np.int64)
    for i in range(points.shape[0]):
        key[i] = (((_cell(points[i, 0], inv, shift) - lo[0]) * span[1] + (_cell(points[i, 1], inv, shift) - lo[1]))
                  * span[2] + (_cell(points[i, 2], inv, shift) - lo[2]))
    return key


@numba.njit(cache=True, nogil=True)
def _ranks(key: np.ndarray, order: np.ndarray) -> np.ndarray:
    """(N,) int64 rank of each key among the distinct keys (``order`` sorts ``key``): ``np.unique``'s inverse."""
    ids = np.empty(key.shape[0], np.int64)
    rank = -1
    for j in range(order.shape[0]):
        i = order[j]
        if j == 0 or key[i] != key[order[j - 1]]:
            rank += 1
        ids[i] = rank
    return ids


@numba.njit(cache=True, nogil=True)
def _cells_kernel(points: np.ndarray, inv: np.float32, shift: np.float32, axes: int) -> np.ndarray:
    cells = np.empty((points.shape[0], axes), np.int64)
    for i in range(points.shape[0]):
        for k in range(axes):
            cells[i, k] = _cell(points[i, k], inv, shift)
    return cells


def cell_coords(points: np.ndarray, voxel_size: float, shift: float, axes: int = 3) -> np.ndarray:
    """(N, axes) int64 cell of each point in the grid of ``voxel_size`` shifted by ``shift`` voxel, the first
    ``axes`` coordinates (float32 arithmetic as :func:`_cell_ids`)."""
    return _cells_kernel(np.asarray(points), np.float32(1.0 / float(np.float32(voxel_size))), np.float32(shift),
                         axes)


def cell_ranks(cells: np.ndarray) -> np.ndarray:
    """(N,) int64 dense ids of (N, 3) int64 cells in their lexicographic order, the order of :func:`_cell_ids`'s
    row-major keys."""
    if len(cells) == 0:
        return np.zeros(0, np.int64)
    lo = cells.min(axis=0)
    span = cells.max(axis=0) - lo + 1
    key = cell_keys(cells, lo, span)
    if key is not None:
        return key_ranks(key)
    _, ids = np.unique(cells, axis=0, return_inverse=True)
    return ids.ravel()


def cell_keys(cells: np.ndarray, lo: np.ndarray, span: np.ndarray) -> np.ndarray | None:
    """(N,) int64 row-major keys of (N, 3) int64 cells in the box ``lo`` .. ``lo + span - 1`` (ordered as the cells
    lexicographically), or None where the box has 2^62 cells or more (the keys would overflow)."""
    if float(span[0]) * float(span[1]) * float(span[2]) >= 2 ** 62:
        return None
    return ((cells[:, 0] - lo[0]) * span[1] + (cells[:, 1] - lo[1])) * span[2] + (cells[:, 2] - lo[2])


def key_ranks(key: np.ndarray) -> np.ndarray:
    """(N,) int64 dense ids of the keys in their order (``np.unique``'s inverse)."""
    return _ranks(key, np.argsort(key))


def cell_ratios(ids: np.ndarray, cells: int, accurate: np.ndarray, inaccurate: np.ndarray) -> np.ndarray:
    """accurate / (accurate + inaccurate) of the voxels (dense ``ids`` 0 .. ``cells`` - 1) holding classified
    points, in their order: what accuracy averages (the counts, sums of 1.0, are exact)."""
    acc = np.bincount(ids, weights=accurate.astype(np.float64), minlength=cells)
    bad = np.bincount(ids, weights=inaccurate.astype(np.float64), minlength=cells)
    valid = acc + bad > 0
    return acc[valid] / (acc[valid] + bad[valid])


def _cell_ids(points: np.ndarray, voxel_size: float, shift: float) -> np.ndarray:
    """(N,) int64 dense ids (0..cells-1, in the order of the cells' row-major keys) of each point's voxel;
    float32 arithmetic as the official code. Computed point by point (no (N, 3) temporaries: 3.5 M points
    of a fused cloud would take 84 MB per copy)."""
    inv = np.float32(1.0 / float(np.float32(voxel_size)))
    shift32 = np.float32(shift)
    points = np.asarray(points)
    if len(points) == 0:
        return np.zeros(0, np.int64)
    lo, hi = _cell_bounds(points, inv, shift32)
    span = hi - lo + 1
    if float(span[0]) * float(span[1]) * float(span[2]) < 2 ** 62:
        key = _cell_keys(points, inv, shift32, lo, span)
        return _ranks(key, np.argsort(key))
    # astronomically large extent for the voxel size
    cells = np.floor(points.astype(np.float32) * inv + shift32).astype(np.int64)
    _, ids = np.unique(cells, axis=0, return_inverse=True)
    return ids.ravel()


def voxel_completeness(gt: np.ndarray, first_ok: np.ndarray, n_tol: int, voxel_size: float) -> np.ndarray:
    """Mean over voxels (both grids) of the fraction of GT points complete at each tolerance."""
    sums = np.zeros(n_tol)
    n_cells = 0
    ids = total = None
    for shift in GRID_SHIFTS:
        del ids, total  # the last grid's go before this grid's are made (8 B a GT point and 8 B a cell)
        ids = _cell_ids(gt, voxel_size, shift)
        total = np.bincount(ids).astype(np.float64)
        n_cells += len(total)
        for t in range(n_tol):
            ok = np.bincount(ids, weights=(first_ok <= t).astype(np.float64), minlength=len(total))
            sums[t] += float(np.sum(ok / total))
    return sums / max(n_cells, 1)



def voxel_accuracy(recon: np.ndarray, first_ok: np.ndarray, inaccurate: np.ndarray, voxel_size: float) -> np.ndarray:
    """Mean over voxels with classified points of accurate / (accurate + inaccurate).

    Args:
        first_ok: (N,) index of the first tolerance at which each point is accurate (n_tol = never).
        inaccurate: (N, n_tol) bool, point inaccurate at that tolerance (only where not accurate).
    """
    n_tol = inaccurate.shape[1]
    sums = np.zeros(n_tol)
    counts = np.zeros(n_tol)
    ids = None
    for shift in GRID_SHIFTS:
        del ids  # the last grid's ids go before this grid's are made
        ids = _cell_ids(recon, voxel_size, shift)
        m = int(ids.max()) + 1 if len(ids) else 0
        for t in range(n_tol):
            ratios = cell_ratios(ids, m, first_ok <= t, inaccurate[:, t])
            sums[t] += float(np.sum(ratios))
            counts[t] += len(ratios)
    return np.where(counts > 0, sums / np.maximum(counts, 1), 0.0)

