"""Evaluation against ground-truth surface points, with the unobserved-space rule of ETH3D when GT views are given."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from engine.core.camera import Camera
from engine.core.heap_trim import release_free_memory
from engine.evaluation.eth3d import evaluate_eth3d
from engine.evaluation.free_space import free_space_margin
from engine.evaluation.options import EvaluationOptions
from engine.evaluation.point_index import PointIndex, first_within
from engine.evaluation.result import EvaluationResult, make_result, overlap_notes
from engine.evaluation.voxels import as_points, voxel_accuracy, voxel_completeness
from engine.io.ply import read_points


def evaluate_points(recon_xyz: np.ndarray, gt_xyz: np.ndarray | PointIndex,
                    options: EvaluationOptions | None = None,
                    gt_views: list[tuple[Camera, np.ndarray]] | None = None) -> EvaluationResult:
    """Score a reconstruction against GT points (see module docstring).

    Args:
        recon_xyz: (N, 3) reconstructed points, world frame.
        gt_xyz: (M, 3) GT surface points, same frame and unit, or a :class:`PointIndex` of them.
        options: tolerances and voxel size.
        gt_views: optional (camera, (H, W) GT depth, 0 = unknown, or a function reading it) pairs enabling the
            unobserved-space rule; cameras at the depth maps' resolution.
    """
    options = (options or EvaluationOptions()).validate()
    release_free_memory()  # what fusion and writing the cloud freed, before the k-d trees come (heap_trim)
    tol = options.sorted_tolerances()
    recon = as_points(recon_xyz, "reconstruction")
    # one index serves both directions (its Morton order as queries, its tree as data)
    gt_index = gt_xyz if isinstance(gt_xyz, PointIndex) else PointIndex(gt_xyz, "ground truth")
    gt = gt_index.points
    n_tol = len(tol)
    comp = voxel_completeness(gt, first_within(gt_index, recon, tol), n_tol, options.voxel_size)
    if len(recon) == 0:
        zeros = np.zeros(n_tol)
        return make_result(tol, zeros, comp, 0, len(gt), zeros, overlap_notes(zeros, comp, 0, tol))
    first_ok = first_within(recon, gt_index, tol)
    not_acc = first_ok[:, None] > np.arange(n_tol)[None, :]
    if gt_views:
        inaccurate = not_acc & (free_space_margin(recon, gt_views)[:, None] > tol[None, :])
    else:
        inaccurate = not_acc
    unobserved = (not_acc & ~inaccurate).mean(axis=0)
    del not_acc  # (N, n_tol) bool: 21 MB for a fused cloud of 3.5 M points, not needed by the voxel scores
    acc = voxel_accuracy(recon, first_ok, inaccurate, options.voxel_size)
    notes = overlap_notes(acc, comp, len(recon), tol)
    if gt_views and not notes and unobserved[0] > 0.99:
        notes.append("over 99% of the reconstructed points are unobserved by the GT views")
    return make_result(tol, acc, comp, len(recon), len(gt), unobserved, notes)



def evaluate_file(recon_path: str | Path, gt_path: str | Path,
                  options: EvaluationOptions | None = None,
                  gt_views: list[tuple[Camera, np.ndarray]] | None = None) -> EvaluationResult:
    """Evaluate a PLY against a GT ``.ply`` (points) or an ETH3D ``.mlp``; float or double PLYs."""
    recon = read_points(recon_path)
    gt_path = Path(gt_path)
    if gt_path.suffix.lower() == ".mlp":
        return evaluate_eth3d(recon, gt_path, options)
    return evaluate_points(recon, read_points(gt_path), options, gt_views)

