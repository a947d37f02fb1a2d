"""Evaluation settings (``EvaluationOptions``): tolerances, voxel grid and the ETH3D scanner beam."""

from __future__ import annotations

import dataclasses

import numpy as np

from engine.core.errors import OptionsError
from engine.core.options import Options, option


@dataclasses.dataclass
class EvaluationOptions(Options):
    """ETH3D evaluation parameters, as the ETH3D evaluation program sets them; lengths in model units (metres)."""

    tolerances: tuple[float, ...] = option((0.01, 0.02, 0.05, 0.1, 0.2, 0.5), "distance tolerances", unit="m",
                                           source="ETH3D", above=0, nonempty=True, metavar="T1,T2,...")
    voxel_size: float = option(0.01, "voxel size of the two density-normalising grids", unit="m", source="ETH3D",
                               above=0, metavar="LENGTH")
    beam_start_radius: float = option(0.001125, "scanner beam radius at the scanner", unit="m", source="ETH3D", low=0,
                                      metavar="LENGTH")
    beam_divergence_halfangle_deg: float = option(0.011, "scanner beam divergence half-angle", unit="degrees",
                                                  source="ETH3D", low=0, below=90, metavar="DEGREES")

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

