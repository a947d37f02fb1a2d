"""GT depth at a PatchMatch level's resolution and the relative error of a depth map against it.

The rerun stream (``workbench/rerun/stream.py``) and the live 3-D viewer (``workbench/viewer/live.py``) both score
every iteration's depth this way, so their "within 1 %" agree: the share of the GT pixels (not of the
estimated ones) whose estimate lies within 1 % of the GT depth, at the resolution of the level being run.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from engine.core.resample import resample_depth


class LevelGT:
    """Per-view GT depth (at the working resolution, None where a view has none), resampled on demand to a
    coarser level's shape (cached: one resampling per view and level)."""

    def __init__(self, gt_depths: list[np.ndarray | None]):
        self.gt_depths = gt_depths
        self._cache: dict[tuple[int, tuple[int, int]], np.ndarray] = {}

    def at(self, view: int, shape: tuple[int, int]) -> np.ndarray | None:
        """(H, W) float32 GT depth of ``view`` at ``shape`` (0 = none), or None without GT."""
        gt = self.gt_depths[view] if view < len(self.gt_depths) else None
        if gt is None or gt.shape == shape:
            return gt
        key = (view, shape)
        if key not in self._cache:
            self._cache[key] = resample_depth(gt, (shape[1], shape[0]))
        return self._cache[key]


@dataclasses.dataclass(frozen=True)
class DepthError:
    """A depth map's error against GT.

    Attributes:
        rel: (H, W) |z - z_gt| / z_gt (a fraction), NaN where the estimate or the GT is missing.
        within: pixels whose estimate is within ``tolerance`` of the GT depth.
        gt_pixels: pixels that have GT (the denominator: a missing estimate counts as a miss).
    """

    rel: np.ndarray
    within: int
    gt_pixels: int

    @property
    def within_pct(self) -> float:
        """Percent of the GT pixels within the tolerance."""
        return 100.0 * self.within / max(1, self.gt_pixels)


def depth_error(depth: np.ndarray, gt: np.ndarray, tolerance: float = 0.01) -> DepthError:
    """Relative error of ``depth`` against ``gt`` (both (H, W), camera-frame z, 0 = none) and the count of
    GT pixels within ``tolerance`` (0.01 = the 1 % of Kuhn et al. 2020's depth tables)."""
    has_gt = gt > 0
    both = has_gt & (depth > 0)
    rel = np.where(both, np.abs(depth - gt) / np.where(has_gt, gt, 1.0), np.nan)
    return DepthError(rel, int((rel[both] < tolerance).sum()), int(has_gt.sum()))
