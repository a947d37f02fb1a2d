"""The evaluation of :func:`engine.evaluation.evaluate_points` for a cloud read a chunk of points at a time (a cloud
on disk, ``engine.fusion.stream``), with the same numbers to the last bit and a memory bounded by the chunk, the
ground truth and one slab of voxels, not by the cloud (Schöps et al. 2017's scores; ETH3D's unobserved space).

- Accuracy: every point's first accurate tolerance (nearest GT point, the GT's k-d tree) and free-space margin are
  the point's own, so chunks change nothing; a point's classification at every tolerance is two small numbers,
  ``a`` (accurate from tolerance ``a`` on) and ``b`` (inaccurate below ``b`` <= ``a``), kept in a temporary file.
- Completeness: each GT point's first tolerance within its nearest distance is the smallest over the chunks of the
  first tolerance within the distance to each chunk's nearest point (a k-d tree of the chunk, queried by the GT
  points within the chunk's bounding box grown by the largest tolerance: the others have no point of the chunk
  within it). The distance of a pair is the same float whatever tree finds it (as
  :func:`engine.evaluation.point_index.first_within`'s pieces).
- The voxel means: accuracy averages accurate / classified over occupied voxels in the order of their cells
  (lexicographic), summed pairwise by numpy. The cloud is cut into slabs of consecutive x cells of at most
  :data:`SLAB_POINTS` points; a slab's voxels follow the previous slab's in that order, so the ratios of the
  slabs one after the other are numpy's array, summed as numpy sums it (``engine.evaluation.pooled.pairwise_sum``;
  the ratios wait in temporary files). A slab reads the chunks that reach it again.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from engine.core.camera import Camera
from engine.core.heap_trim import release_free_memory
from engine.evaluation.free_space import free_space_margin, pack_gt_views
from engine.evaluation.options import EvaluationOptions
from engine.evaluation.point_index import QUERY_CHUNK, PointIndex, first_within
from engine.evaluation.pooled import pairwise_sum
from engine.evaluation.result import EvaluationResult, make_result, overlap_notes
from engine.evaluation.voxels import (
    GRID_SHIFTS,
    as_points,
    cell_coords,
    cell_keys,
    cell_ranks,
    cell_ratios,
    key_ranks,
    voxel_completeness,
)

CHUNK_POINTS = 1 << 18  # points read at once (6 MiB of float64 positions)
SLAB_POINTS = 1 << 19  # points of one slab of the voxel grid (about 30 MiB while its voxels are counted)


class _Completeness:
    """Every GT point's first tolerance within which a reconstructed point lies (``n_tol``: none), in the index's
    (Morton) order, a chunk at a time: the smallest over the chunks, as the tolerance of the smallest distance is
    (the first tolerance >= a distance grows with the distance). One byte a GT point; the GT points near a chunk
    are found a :data:`QUERY_CHUNK` slice of the index at a time (no sorted copy of a coordinate, no permutation)."""

    def __init__(self, gt: PointIndex, tolerances: np.ndarray, code: type):
        self.gt, self.tolerances = gt.points, tolerances
        self.bound = float(tolerances[-1]) * (1 + 1e-6)  # first_within's bound
        self.first = np.full(len(self.gt), len(tolerances), code)

    def add(self, xyz: np.ndarray) -> None:
        margin = 2 * self.bound  # twice: no rounding of the box can leave out a GT point within the bound
        lo, hi = xyz.min(axis=0) - margin, xyz.max(axis=0) + margin
        tree = None
        for start in range(0, len(self.gt), QUERY_CHUNK):
            piece = self.gt[start:start + QUERY_CHUNK]
            near = np.flatnonzero(((piece >= lo) & (piece <= hi)).all(axis=1))
            if not len(near):
                continue
            if tree is None:
                tree = cKDTree(xyz, balanced_tree=False, compact_nodes=False)
            dist, _ = tree.query(piece[near], k=1, distance_upper_bound=self.bound, workers=-1)
            first = self.first[start:start + QUERY_CHUNK]
            first[near] = np.minimum(first[near], np.searchsorted(self.tolerances, dist, side="left"))


class _Slabs:
    """One voxel grid's cells: points per x cell, each chunk's range of them, and the box of all cells."""

    def __init__(self, voxel_size: float, shift: float):
        self.voxel_size, self.shift = voxel_size, shift
        self.values: list[np.ndarray] = []
        self.counts: list[np.ndarray] = []
        self.ranges: list[tuple[int, int]] = []
        self.lo = np.full(3, np.iinfo(np.int64).max)
        self.hi = np.full(3, np.iinfo(np.int64).min)

    def cells(self, xyz: np.ndarray) -> np.ndarray:
        return cell_coords(xyz, self.voxel_size, self.shift)

    def add(self, xyz: np.ndarray) -> None:
        cells = self.cells(xyz)
        self.lo, self.hi = np.minimum(self.lo, cells.min(axis=0)), np.maximum(self.hi, cells.max(axis=0))
        values, counts = np.unique(cells[:, 0], return_counts=True)
        self.values.append(values)
        self.counts.append(counts)
        self.ranges.append((int(values[0]), int(values[-1])))

    def bounds(self, points: int) -> list[tuple[int, int]]:
        """Ranges of x cells (inclusive) of at most ``points`` points each (or one x cell), in order."""
        values, inverse = np.unique(np.concatenate(self.values), return_inverse=True)
        counts = np.bincount(inverse.ravel(), np.concatenate(self.counts)).astype(np.int64)
        out, first, held = [], 0, 0
        for i, c in enumerate(counts):
            if held and held + c > points:
                out.append((int(values[first]), int(values[i - 1])))
                first, held = i, 0
            held += int(c)
        out.append((int(values[first]), int(values[-1])))
        return out

    def ids(self, parts: list[np.ndarray]) -> np.ndarray:
        """Dense ids of the cells of a slab in their lexicographic order; ``parts``: what :meth:`keys` gave."""
        whole = np.concatenate(parts)
        return key_ranks(whole) if whole.ndim == 1 else cell_ranks(whole)

    def keys(self, cells: np.ndarray) -> np.ndarray:
        """The cells' row-major keys in the box of all cells (8 bytes a point), or the cells where it has too many."""
        key = cell_keys(cells, self.lo, self.hi - self.lo + 1)
        return cells if key is None else key


def evaluate_point_chunks(n: int, read: Callable[[int, int], np.ndarray], gt_xyz: np.ndarray | PointIndex,
                          options: EvaluationOptions | None = None,
                          gt_views: list[tuple[Camera, np.ndarray]] | None = None,
                          scratch: str | Path | None = None) -> EvaluationResult:
    """:func:`engine.evaluation.evaluate_points` of ``n`` points that ``read(start, count)`` gives, (count, 3)
    float64, a chunk at a time (see the module docstring); the same result.

    Args:
        n: the points.
        read: the points ``start`` .. ``start + count - 1``, e.g. :meth:`engine.fusion.cloud.DiskCloud.read_xyz`.
        gt_xyz, options, gt_views: as :func:`engine.evaluation.evaluate_points`.
        scratch: the folder of the temporary files (2 bytes a point, and the slabs' ratios; default: the system's).
    """
    options = (options or EvaluationOptions()).validate()
    release_free_memory()
    tol = options.sorted_tolerances()
    n_tol = len(tol)
    gt_index = gt_xyz if isinstance(gt_xyz, PointIndex) else PointIndex(gt_xyz, "ground truth")
    code = np.uint8 if n_tol < 255 else np.uint16
    complete = _Completeness(gt_index, tol, code)
    packed = pack_gt_views(gt_views) if gt_views else None
    # reading and resampling each GT depth map leaves tens of MiB free on the heap; returned, they do not stay
    # resident under the chunks' arrays (engine/core/heap_trim.py)
    release_free_memory()
    slabs = [_Slabs(options.voxel_size, shift) for shift in GRID_SHIFTS]
    unobserved = np.zeros(n_tol, np.int64)
    with tempfile.TemporaryFile(dir=scratch) as classes:
        for start in range(0, n, CHUNK_POINTS):
            xyz = as_points(read(start, CHUNK_POINTS), "reconstruction")
            complete.add(xyz)
            a = first_within(xyz, gt_index, tol)  # accurate at tolerance t >= a
            b = a  # inaccurate at t < b: not accurate, and (with GT views) seen in front of the GT surface by > t
            if packed is not None:
                b = np.minimum(a, (free_space_margin(xyz, packed)[:, None] > tol[None, :]).sum(axis=1))
            steps = np.arange(n_tol)[None, :]
            unobserved += ((b[:, None] <= steps) & (steps < a[:, None])).sum(axis=0)
            classes.write(np.stack([a, b], axis=1).astype(code).tobytes())
            for grid in slabs:
                grid.add(xyz)
        xyz = a = b = packed = None  # the last chunk's arrays and the GT views go before the voxel grids are made
        release_free_memory()
        comp = voxel_completeness(gt_index.points, complete.first, n_tol, options.voxel_size)
        release_free_memory()  # the GT voxels' arrays, before the cloud's slabs
        if n == 0:
            zeros = np.zeros(n_tol)
            return make_result(tol, zeros, comp, 0, len(gt_index), zeros, overlap_notes(zeros, comp, 0, tol))
        acc = _voxel_accuracy(n, read, classes, code, slabs, n_tol, scratch)
    unobserved = unobserved / n
    notes = overlap_notes(acc, comp, n, tol)
    if gt_views and not notes and unobserved[0] > 0.99:
        notes.append("over 99% of the reconstructed points are unobserved by the GT views")
    return make_result(tol, acc, comp, n, len(gt_index), unobserved, notes)


def _voxel_accuracy(n: int, read: Callable[[int, int], np.ndarray], classes, code, slabs: list[_Slabs], n_tol: int,
                    scratch: str | Path | None) -> np.ndarray:
    """:func:`engine.evaluation.voxels.voxel_accuracy` slab by slab."""
    sums, counts = np.zeros(n_tol), np.zeros(n_tol)
    width = 2 * np.dtype(code).itemsize
    for grid in slabs:
        bounds = grid.bounds(SLAB_POINTS)
        files = [tempfile.TemporaryFile(dir=scratch) for _ in range(n_tol)] if len(bounds) > 1 else []
        totals = np.zeros(n_tol, np.int64)
        try:
            for lo, hi in bounds:
                cells, ab = [], []
                for c, (c_lo, c_hi) in enumerate(grid.ranges):
                    if c_hi < lo or c_lo > hi:
                        continue
                    start = c * CHUNK_POINTS
                    xyz = read(start, CHUNK_POINTS)
                    cell = grid.cells(xyz)
                    inside = (cell[:, 0] >= lo) & (cell[:, 0] <= hi)
                    classes.seek(start * width)
                    pairs = np.frombuffer(classes.read(len(xyz) * width), code).reshape(-1, 2)
                    cells.append(grid.keys(cell[inside]))
                    ab.append(pairs[inside])
                ids = grid.ids(cells)
                del cells
                a, b = np.concatenate(ab).T.astype(np.int64)
                m = int(ids.max()) + 1
                for t in range(n_tol):
                    ratios = cell_ratios(ids, m, a <= t, b > t)
                    totals[t] += len(ratios)
                    if files:
                        files[t].write(ratios.tobytes())
                    else:
                        sums[t] += float(np.sum(ratios))
            for t, handle in enumerate(files):
                handle.seek(0)
                sums[t] += float(pairwise_sum(_blocks(handle, SLAB_POINTS), int(totals[t]), max(128, SLAB_POINTS)))
            counts += totals
        finally:
            for handle in files:
                handle.close()
    return np.where(counts > 0, sums / np.maximum(counts, 1), 0.0)


def _blocks(handle, values: int):
    """The float64 values of a file, ``values`` at a time."""
    while data := handle.read(values * 8):
        yield np.frombuffer(data, np.float64)
