"""Density-normalised scores: means over the occupied voxels of two shifted grids (ETH3D, Schöps et al. 2017)."""

from __future__ import annotations

import numpy as np

from engine.errors import DeepCError

_GRID_SHIFTS = (0.0, 0.5)



def as_points(xyz: np.ndarray, what: str) -> np.ndarray:
    xyz = np.asarray(xyz)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise DeepCError(f"{what} must be an (N, 3) array of points, got shape {xyz.shape}")
    if len(xyz) and not np.isfinite(xyz).all():
        raise DeepCError(f"{what} has non-finite coordinates")
    return xyz



def _cell_ids(points: np.ndarray, voxel_size: float, shift: float) -> np.ndarray:
    """(N,) int64 dense ids (0..cells-1) of each point's voxel; float32 arithmetic as the official code."""
    inv = np.float32(1.0 / float(np.float32(voxel_size)))
    cells = np.floor(points.astype(np.float32) * inv + np.float32(shift)).astype(np.int64)
    lo = cells.min(axis=0)
    span = cells.max(axis=0) - lo + 1
    if float(span[0]) * float(span[1]) * float(span[2]) < 2 ** 62:
        key = ((cells[:, 0] - lo[0]) * span[1] + (cells[:, 1] - lo[1])) * span[2] + (cells[:, 2] - lo[2])
        _, ids = np.unique(key, return_inverse=True)
    else:  # astronomically large extent for the voxel size
        _, ids = np.unique(cells, axis=0, return_inverse=True)
    return ids.ravel()



def voxel_completeness(gt: np.ndarray, first_ok: np.ndarray, n_tol: int, voxel_size: float) -> np.ndarray:
    """Mean over voxels (both grids) of the fraction of GT points complete at each tolerance."""
    sums = np.zeros(n_tol)
    n_cells = 0
    for shift in _GRID_SHIFTS:
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
    for shift in _GRID_SHIFTS:
        ids = _cell_ids(recon, voxel_size, shift)
        m = int(ids.max()) + 1 if len(ids) else 0
        for t in range(n_tol):
            acc = np.bincount(ids, weights=(first_ok <= t).astype(np.float64), minlength=m)
            bad = np.bincount(ids, weights=inaccurate[:, t].astype(np.float64), minlength=m)
            valid = acc + bad > 0
            sums[t] += float(np.sum(acc[valid] / (acc[valid] + bad[valid])))
            counts[t] += int(valid.sum())
    return np.where(counts > 0, sums / np.maximum(counts, 1), 0.0)

