"""Ground-truth label maps (Kuhn et al. 2020, §3.2): is an estimated depth an inlier?

For reference pixel p with estimate z_p > 0 and GT z*_p > 0, project X(p, z_p) and X(p, z*_p) into
every source view j of the reference; e_j is the pixel distance between the two projections in j
(index-space pixels at j's working resolution). A view counts when both points lie in front of j and
at least one projection falls inside image j. y(p) = 1 iff e_j < 2 px for at least one counted view,
else 0. Unlabeled (-1): no estimate, no/invalid GT, estimate beyond the depth range's far end, or no
counted view.
"""

from __future__ import annotations

import numpy as np

from engine.core.camera import Camera

UNLABELED = -1


def label_map(depth: np.ndarray, gt_depth: np.ndarray, camera: Camera, source_cameras: list[Camera],
              max_depth: float = np.inf, threshold_px: float = 2.0) -> np.ndarray:
    """(H, W) int8 labels: 1 inlier, 0 outlier, -1 unlabeled.

    Args:
        depth: (H, W) estimated depth (camera z), 0 = none.
        gt_depth: (H, W) GT depth, 0 / non-finite = unknown.
        camera: the reference camera at the maps' resolution.
        source_cameras: cameras of the reference's source views (their working resolution).
        max_depth: estimates beyond this are "unreasonably far" and stay unlabeled.
        threshold_px: inlier threshold on e_j.
    """
    depth = np.asarray(depth, np.float64)
    gt = np.asarray(gt_depth, np.float64)
    if depth.shape != (camera.height, camera.width) or gt.shape != depth.shape:
        raise ValueError(f"depth {depth.shape}, GT {gt.shape} and camera {camera.height}x{camera.width} differ")
    labels = np.full(depth.shape, UNLABELED, np.int8)
    with np.errstate(invalid="ignore"):
        candidate = (depth > 0) & np.isfinite(gt) & (gt > 0) & (depth <= max_depth)
    rows, cols = np.nonzero(candidate)
    if rows.size == 0:
        return labels
    rays = camera.pixel_rays()[rows, cols]
    est_world = camera.camera_to_world(rays * depth[rows, cols, None])
    gt_world = camera.camera_to_world(rays * gt[rows, cols, None])
    counted = np.zeros(rows.size, bool)
    inlier = np.zeros(rows.size, bool)
    for src in source_cameras:
        uv, z = src.project(est_world)
        uv_gt, z_gt = src.project(gt_world)
        inside = _inside(uv, src) | _inside(uv_gt, src)
        ok = (z > 0) & (z_gt > 0) & inside
        err = np.linalg.norm(uv - uv_gt, axis=1)
        counted |= ok
        with np.errstate(invalid="ignore"):
            inlier |= ok & (err < threshold_px)
    labels[rows[counted], cols[counted]] = inlier[counted].astype(np.int8)
    return labels


def _inside(uv: np.ndarray, camera: Camera) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        return ((uv[:, 0] >= -0.5) & (uv[:, 0] < camera.width - 0.5)
                & (uv[:, 1] >= -0.5) & (uv[:, 1] < camera.height - 0.5))
