"""Evaluation settings (``EvaluationOptions``): tolerances, voxel grid and the ETH3D scanner beam."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from engine.errors import OptionsError
from engine.options import Options, check, option


@dataclasses.dataclass
class EvaluationOptions(Options):
    """ETH3D evaluation parameters (SPEC.md §12 ``eval``); lengths in model units (metres for ETH3D)."""

    tolerances: tuple[float, ...] = option((0.01, 0.02, 0.05, 0.1, 0.2, 0.5), "distance tolerances",
                                           metavar="T1,T2,...")
    voxel_size: float = option(0.01, "voxel size of the two density-normalising grids", metavar="LENGTH")
    beam_start_radius: float = option(0.001125, "ETH3D scanner beam radius at the scanner", metavar="LENGTH")
    beam_divergence_halfangle_deg: float = option(0.011, "ETH3D scanner beam divergence half-angle",
                                                  metavar="DEGREES")

    def validate(self) -> EvaluationOptions:
        super().validate()
        tol = tuple(self.tolerances)
        check(len(tol) > 0, "tolerances", tol, "give at least one tolerance")
        check(all(isinstance(t, (int, float)) and math.isfinite(t) and t > 0 for t in tol), "tolerances", tol,
              "every tolerance must be a positive finite number")
        check(math.isfinite(self.voxel_size) and self.voxel_size > 0, "voxel_size", self.voxel_size,
              "must be positive")
        check(self.beam_start_radius >= 0, "beam_start_radius", self.beam_start_radius, "must be >= 0")
        check(0 <= self.beam_divergence_halfangle_deg < 90, "beam_divergence_halfangle_deg",
              self.beam_divergence_halfangle_deg, "must be in [0, 90)")
        return self

    def sorted_tolerances(self) -> np.ndarray:
        return np.array(sorted(set(float(t) for t in self.tolerances)), np.float64)



def parse_tolerances(text: str) -> tuple[float, ...]:
    """'0.01,0.02' -> (0.01, 0.02); a clear error for anything else."""

    parts = [p.strip() for p in str(text).split(",") if p.strip()]
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        raise OptionsError(f"option tolerances={text!r}: not a comma-separated list of numbers") from None
    EvaluationOptions(tolerances=values).validate()
    return values

