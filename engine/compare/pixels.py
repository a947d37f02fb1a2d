"""Two depth maps of one view compared pixel by pixel, against GT depth where it exists and with each other where
it does not.

Where GT exists a run is *right* at a pixel when its depth is within ``tolerance`` (1 %) of the GT depth, by the
rule of the ``depth`` metrics (:func:`engine.evaluation.depth.relative_error_map`: |z - z*| / z* < tolerance); a
missing estimate is wrong. Where GT is missing and both runs have a depth they *disagree* when
|a - b| / min(a, b) > tolerance. Maps and counts are at the maps' common size.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from engine.evaluation.depth import relative_error_map

TOLERANCE = 0.01
#: the maps a comparison draws, in the order reports show them
MAP_KINDS = ("a_right_b_wrong", "b_right_a_wrong", "both_wrong", "disagree")
MAP_TITLES = {"a_right_b_wrong": "A right, B wrong", "b_right_a_wrong": "B right, A wrong",
              "both_wrong": "both wrong", "disagree": "disagree (no GT)"}
#: every pixel's case, one each (:func:`case_codes`): the four GT cases, then the no-GT ones; a pixel no run has a
#: depth at and no GT is none of them (code 0)
CASES = ("both_right", "a_right_b_wrong", "b_right_a_wrong", "both_wrong", "agree", "disagree", "only_a", "only_b")
CASE_TITLES = {"both_right": "both right", **MAP_TITLES, "agree": "agree (no GT)", "disagree": "disagree (no GT)",
               "only_a": "only A has depth (no GT)", "only_b": "only B has depth (no GT)"}
#: the cases where the runs differ (PixelCounts.shares' "difference")
DIFFERENT = ("a_right_b_wrong", "b_right_a_wrong", "disagree")


@dataclasses.dataclass
class PixelCounts:
    """Pixel counts of one view or of several (``+`` adds them).

    Attributes:
        gt: pixels with GT depth; a_right, b_right: of those, where A (B) is within the tolerance;
            both_right, a_right_b_wrong, b_right_a_wrong, both_wrong: the four cases (they sum to ``gt``).
        no_gt: pixels without GT where both runs have a depth; disagree: of those, where they differ by more than
            the tolerance. only_a, only_b: pixels without GT where only A (B) has a depth.
    """

    gt: int = 0
    a_right: int = 0
    b_right: int = 0
    both_right: int = 0
    a_right_b_wrong: int = 0
    b_right_a_wrong: int = 0
    both_wrong: int = 0
    no_gt: int = 0
    disagree: int = 0
    only_a: int = 0
    only_b: int = 0

    def __add__(self, other: PixelCounts) -> PixelCounts:
        return PixelCounts(*(getattr(self, f.name) + getattr(other, f.name) for f in dataclasses.fields(self)))

    def shares(self) -> dict[str, float]:
        """Percentages: the GT cases of the GT pixels, ``disagree`` of ``no_gt`` (NaN over an empty set), and
        ``difference``: the pixels where the runs differ (one right and the other not, or disagreeing) of all
        pixels either kind counts."""

        def pct(count: int, total: int) -> float:
            return 100.0 * count / total if total else float("nan")

        out = {k: pct(getattr(self, k), self.gt) for k in ("a_right", "b_right", "both_right", "a_right_b_wrong",
                                                           "b_right_a_wrong", "both_wrong")}
        out["disagree"] = pct(self.disagree, self.no_gt)
        out["difference"] = pct(self.a_right_b_wrong + self.b_right_a_wrong + self.disagree, self.gt + self.no_gt)
        return out


def compare_pixels(depth_a: np.ndarray, depth_b: np.ndarray, gt_depth: np.ndarray | None,
                   tolerance: float = TOLERANCE) -> tuple[PixelCounts, dict[str, np.ndarray]]:
    """Counts and (H, W) bool maps (every name of :data:`CASES`; :data:`MAP_KINDS` are those reports draw) of two
    depth maps of one view.

    Args:
        depth_a, depth_b: (H, W) camera-frame depth of runs A and B, 0 = none, same size.
        gt_depth: (H, W) GT depth at that size (0 = unknown), or None when the view has none.
        tolerance: relative depth tolerance (0.01 = 1 %).
    """
    a = np.asarray(depth_a, np.float64)
    b = np.asarray(depth_b, np.float64)
    if a.shape != b.shape:
        raise ValueError(f"depth maps {a.shape} and {b.shape} differ in shape")
    gt = np.zeros(a.shape) if gt_depth is None else gt_depth
    has_gt, rel_a = relative_error_map(a, gt)
    _, rel_b = relative_error_map(b, gt)
    with np.errstate(invalid="ignore"):
        right_a, right_b = rel_a < tolerance, rel_b < tolerance  # NaN (no estimate) compares False: wrong
    valid_a = np.isfinite(a) & (a > 0) & ~has_gt
    valid_b = np.isfinite(b) & (b > 0) & ~has_gt
    both = valid_a & valid_b
    disagree = np.zeros(a.shape, bool)
    disagree[both] = np.abs(a[both] - b[both]) / np.minimum(a[both], b[both]) > tolerance
    maps = {"a_right_b_wrong": right_a & ~right_b, "b_right_a_wrong": right_b & ~right_a,
            "both_wrong": has_gt & ~right_a & ~right_b, "disagree": disagree,
            "both_right": right_a & right_b, "agree": both & ~disagree, "only_a": valid_a & ~valid_b,
            "only_b": valid_b & ~valid_a}
    counts = PixelCounts(
        gt=int(has_gt.sum()), a_right=int(right_a.sum()), b_right=int(right_b.sum()),
        both_right=int(maps["both_right"].sum()), a_right_b_wrong=int(maps["a_right_b_wrong"].sum()),
        b_right_a_wrong=int(maps["b_right_a_wrong"].sum()), both_wrong=int(maps["both_wrong"].sum()),
        no_gt=int(both.sum()), disagree=int(disagree.sum()), only_a=int(maps["only_a"].sum()),
        only_b=int(maps["only_b"].sum()))
    return counts, maps


def case_codes(maps: dict[str, np.ndarray]) -> np.ndarray:
    """(H, W) uint8: at each pixel 1 + the index in :data:`CASES` of its case (the maps of :func:`compare_pixels`,
    which never overlap), 0 where it has none."""
    codes = np.zeros(maps[CASES[0]].shape, np.uint8)
    for code, case in enumerate(CASES, start=1):
        codes[maps[case]] = code
    return codes
