"""The refinement energy of one pyramid scale (Rossi et al. 2020).

    E(d, u) = (λ_d/|Ω|) Σ_i c̃_i |d_i - d̄_i|
            + (λ/|Ω|) [ Σ_i ( Σ_{j∈N(i)} w_ij² (d_i - d_j - u_i·(x_i - x_j))² )^½ + γ Σ_i Σ_{j∈N(i)} w_ij |u_i - u_j| ]

d = inverse depth (1/model units), u = its image-plane gradient per pixel (1/(units·px)), d̄ = input
inverse depth (0 = none), c̃ = confidence, zero where the input has no depth inside the range.
"""

from __future__ import annotations

import dataclasses

import numba
import numpy as np

from engine.refinement.graph import SimilarityGraph


@dataclasses.dataclass(eq=False)
class ScaleProblem:
    """Everything the energy of one scale needs (flattened over the H*W pixels).

    Attributes:
        graph: the similarity graph of this scale.
        data: (N,) float32 input inverse depth d̄ (0 where none).
        fidelity: (N,) float32 c̃_i >= 0.
        d_min, d_max: box for d (1/z_max, 1/z_min).
        lambda_data, lambda_reg, gamma: energy weights.
    """

    graph: SimilarityGraph
    data: np.ndarray
    fidelity: np.ndarray
    d_min: float
    d_max: float
    lambda_data: float = 1.0
    lambda_reg: float = 7.5
    gamma: float = 5.5

    @property
    def size(self) -> int:
        return self.graph.height * self.graph.width


@numba.njit(parallel=True, cache=True)
def _energy_kernel(d, u, data, fidelity, neighbors, weights, offsets):
    """Unweighted sums (Σ c̃|d - d̄|, Σ_i |plane residuals_i|, Σ w |u_i - u_j|) in float64."""
    n, k_max = neighbors.shape
    s_data = 0.0
    s_plane = 0.0
    s_tv = 0.0
    for i in numba.prange(n):
        s_data += fidelity[i] * abs(d[i] - data[i])
        sq = 0.0
        tv = 0.0
        for k in range(k_max):
            j = neighbors[i, k]
            w = weights[i, k]
            r = w * (d[i] - d[j] - u[i, 0] * offsets[i, k, 0] - u[i, 1] * offsets[i, k, 1])
            sq += r * r
            a = u[i, 0] - u[j, 0]
            b = u[i, 1] - u[j, 1]
            tv += w * np.sqrt(a * a + b * b)
        s_plane += np.sqrt(sq)
        s_tv += tv
    return s_data, s_plane, s_tv


def energy_terms(problem: ScaleProblem, d: np.ndarray, u: np.ndarray) -> dict[str, float]:
    """The three terms (already weighted) and their sum, float64; d (N,) and u (N, 2) (numba)."""
    g = problem.graph
    n = problem.size
    s_data, s_plane, s_tv = _energy_kernel(
        np.ascontiguousarray(d, np.float64).ravel(), np.ascontiguousarray(u, np.float64).reshape(-1, 2),
        np.asarray(problem.data, np.float64), np.asarray(problem.fidelity, np.float64), g.neighbors,
        g.weights.astype(np.float64), g.offsets)
    data = problem.lambda_data / n * s_data
    plane = problem.lambda_reg / n * s_plane
    tv = problem.lambda_reg * problem.gamma / n * s_tv
    return {"data": data, "plane": plane, "orientation": tv, "total": data + plane + tv}


def energy(problem: ScaleProblem, d: np.ndarray, u: np.ndarray) -> float:
    """E(d, u) of Rossi et al. 2020 in float64; d (N,) inverse depth, u (N, 2)."""
    return energy_terms(problem, d, u)["total"]
