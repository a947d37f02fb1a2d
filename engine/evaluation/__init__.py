"""ETH3D-style evaluation of a point cloud: accuracy, completeness and F1 per tolerance (Schöps et al., CVPR 2017).

Two ground-truth forms:

- ``evaluate_points``: GT surface points (e.g. ``SCENE/ground_truth/points.ply``). A reconstructed
  point is *accurate* at tolerance t if a GT point lies within t. Without GT views every other point
  is *inaccurate*. With GT views (camera, GT depth map) the unobserved-space rule applies: a point
  that is not accurate counts as inaccurate only if some GT view sees it more than t in front of
  the GT surface (observed free space); otherwise it is *unobserved* and ignored, as in ETH3D.
- ``evaluate_eth3d``: ETH3D's own format, a MeshLab project (``scan_alignment.mlp``) listing laser
  scans stored in their scanners' frames. Accuracy follows the official program's beam model
  (``ETH3D/multi-view-evaluation`` ``src/accuracy.cc``): a scan ray "sees" a point if it passes within
  the beam radius ``b0 + r tan(half_angle)``; accurate if that scan point is within t, inaccurate if the
  point lies in front of it, unobserved otherwise; scans combine by "accurate in any, else inaccurate
  in any".

Completeness (both forms): a GT point is complete at t if a reconstructed point lies within t.
Every score is a mean over occupied voxels of two grids (cell ``floor(p / voxel + shift)``, shifts 0
and 0.5 voxel), each voxel weighted equally, which cancels point density. Accuracy skips voxels
without classified points. F1 = 2 A C / (A + C), 0 when both are 0. All scores are percentages.

Modules: ``options``, ``result``, ``points`` (GT points), ``chunked`` (the same for a cloud read a chunk at a time),
``eth3d`` (laser scans and the beam model),
``free_space``, ``point_index`` and ``voxels`` (the shared machinery).
"""

from engine.evaluation.chunked import evaluate_point_chunks
from engine.evaluation.eth3d import Eth3dScan, classify_beam, evaluate_eth3d, load_eth3d_mlp
from engine.evaluation.free_space import free_space_margin
from engine.evaluation.options import EvaluationOptions, parse_tolerances
from engine.evaluation.point_index import PointIndex
from engine.evaluation.points import evaluate_file, evaluate_points
from engine.evaluation.result import EvaluationResult

__all__ = ["Eth3dScan", "EvaluationOptions", "EvaluationResult", "PointIndex", "classify_beam", "evaluate_eth3d",
           "evaluate_file", "evaluate_point_chunks", "evaluate_points", "free_space_margin", "load_eth3d_mlp",
           "parse_tolerances"]
