"""Scores per tolerance (``EvaluationResult``) and how they combine into F1."""

from __future__ import annotations

import dataclasses
import math

import numpy as np


@dataclasses.dataclass
class EvaluationResult:
    """Scores per tolerance (percent, 0-100), tolerances ascending.

    Attributes:
        tolerances, accuracy, completeness, f1: lists of equal length.
        num_reconstruction, num_ground_truth: point counts used.
        unobserved: per tolerance, the percentage of reconstructed points that were neither accurate
            nor inaccurate (ignored by accuracy).
        notes: one-line explanations of degenerate results (empty cloud, no overlap, ...).
    """

    tolerances: list[float]
    accuracy: list[float]
    completeness: list[float]
    f1: list[float]
    num_reconstruction: int = 0
    num_ground_truth: int = 0
    unobserved: list[float] = dataclasses.field(default_factory=list)
    notes: list[str] = dataclasses.field(default_factory=list)

    def to_dict(self) -> dict[str, list[float]]:
        """The ``eval`` block of metrics.json."""
        return {"tolerances": list(self.tolerances), "accuracy": list(self.accuracy),
                "completeness": list(self.completeness), "f1": list(self.f1)}

    def at(self, tolerance: float) -> dict[str, float]:
        """Scores at one tolerance (must be one of ``tolerances``)."""
        i = int(np.argmin(np.abs(np.array(self.tolerances) - tolerance)))
        if not math.isclose(self.tolerances[i], tolerance, rel_tol=1e-9):
            raise KeyError(f"tolerance {tolerance} was not evaluated (have {self.tolerances})")
        return {"accuracy": self.accuracy[i], "completeness": self.completeness[i], "f1": self.f1[i]}

    def format_table(self) -> str:
        lines = [f"{'tolerance':>10} {'accuracy %':>11} {'completeness %':>15} {'F1 %':>8}"]
        for t, a, c, f in zip(self.tolerances, self.accuracy, self.completeness, self.f1, strict=True):
            lines.append(f"{t:>10g} {a:>11.2f} {c:>15.2f} {f:>8.2f}")
        lines.append(f"({self.num_reconstruction} reconstructed points, {self.num_ground_truth} ground-truth points)")
        lines += [f"note: {n}" for n in self.notes]
        return "\n".join(lines)



def f1_score(acc: np.ndarray, comp: np.ndarray) -> np.ndarray:
    s = acc + comp
    return np.where(s > 0, 2 * acc * comp / np.where(s > 0, s, 1), 0.0)



def make_result(tol, acc, comp, n_rec, n_gt, unobserved, notes) -> EvaluationResult:
    f1 = f1_score(acc, comp)
    return EvaluationResult([float(t) for t in tol], [float(100 * a) for a in acc], [float(100 * c) for c in comp],
                            [float(100 * f) for f in f1], n_rec, n_gt, [float(100 * u) for u in unobserved], notes)



def overlap_notes(acc: np.ndarray, comp: np.ndarray, n_rec: int, tol: np.ndarray) -> list[str]:
    notes = []
    if n_rec == 0:
        notes.append("the reconstruction is empty: accuracy, completeness and F1 are 0")
    elif comp[-1] == 0:
        notes.append(f"no ground-truth point has a reconstructed point within {tol[-1]:g}: is the ground truth "
                     "from another scene, or in another coordinate frame or unit?")
    return notes

