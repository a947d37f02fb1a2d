"""Fast solver: diagonally preconditioned primal-dual (Chambolle & Pock 2011) on the energy of
Rossi et al. 2020, in numba.

E is convex in x = (d, u): divided by λ/|Ω| it reads

    E' = μ Σ_i c̃_i |d_i - d̄_i| + ι_[d_min, d_max](d) + Σ_i |(A1 x)_i|₂ + Σ_{i,k} |(A2 x)_{ik}|₂,
    (A1 x)_{ik} = w_ik (d_i - d_j - u_i·δ_ik),   (A2 x)_{ik} = γ w_ik (u_i - u_j) ∈ R²,

with μ = λ_d / λ, j = N(i)_k and δ_ik = x_i - x_j. Duals p_i ∈ R^K (|p_i| <= 1) and q_ik ∈ R² (|q_ik| <= 1).
One iteration: p, q <- proj(p, q + Σ A x̄); x+ <- prox_{T G}(x - T Aᵀ(p, q)); x̄ = 2 x+ - x. The step sizes
are the α = 1 diagonal preconditioners of Pock & Chambolle (ICCV 2011): T_j = 1/Σ_i |A_ij| per primal
variable, Σ = 1/(largest row sum) per dual block (so the prox of a block stays a ball projection).
The prox of G is per pixel: shrink d towards d̄ by T_d μ c̃, then clamp to the box (exact for 1-D).
Aᵀ needs the incoming edges of each pixel: a CSR transpose of the graph built once per scale.
"""

from __future__ import annotations

import numba
import numpy as np

from engine.core.interrupt import check_interrupt
from engine.refinement.energy import ScaleProblem


@numba.njit(parallel=True, cache=True, fastmath=True)
def dual_step(d_bar, u_bar, neighbors, weights, offsets, sigma_p, sigma_q, gamma, p, q):
    n, k_max = neighbors.shape
    for i in numba.prange(n):
        sq = 0.0
        for k in range(k_max):
            j = neighbors[i, k]
            w = weights[i, k]
            r = w * (d_bar[i] - d_bar[j] - u_bar[i, 0] * offsets[i, k, 0] - u_bar[i, 1] * offsets[i, k, 1])
            v = p[i, k] + sigma_p[i] * r
            p[i, k] = v
            sq += v * v
            if w > 0 and gamma > 0:
                # Σ for this block is sigma_q/(γ w): the step is sigma_q times the difference of u.
                a = q[i, k, 0] + sigma_q * (u_bar[i, 0] - u_bar[j, 0])
                b = q[i, k, 1] + sigma_q * (u_bar[i, 1] - u_bar[j, 1])
                m = np.sqrt(a * a + b * b)
                if m > 1.0:
                    a /= m
                    b /= m
                q[i, k, 0] = a
                q[i, k, 1] = b
        if sq > 1.0:
            s = 1.0 / np.sqrt(sq)
            for k in range(k_max):
                p[i, k] *= s


@numba.njit(parallel=True, cache=True, fastmath=True)
def primal_step(d, u, d_bar, u_bar, p, q, weights, offsets, in_ptr, in_src, in_slot, tau_d, tau_u,
                 data, shrink, d_min, d_max, gamma):
    n, k_max = weights.shape
    for i in numba.prange(n):
        gd = 0.0
        gu0 = 0.0
        gu1 = 0.0
        for k in range(k_max):
            w = weights[i, k]
            wp = w * p[i, k]
            gd += wp
            gu0 += gamma * w * q[i, k, 0] - wp * offsets[i, k, 0]
            gu1 += gamma * w * q[i, k, 1] - wp * offsets[i, k, 1]
        for e in range(in_ptr[i], in_ptr[i + 1]):
            src = in_src[e]
            k = in_slot[e]
            w = weights[src, k]
            gd -= w * p[src, k]
            gu0 -= gamma * w * q[src, k, 0]
            gu1 -= gamma * w * q[src, k, 1]
        v = d[i] - tau_d[i] * gd
        t = tau_d[i] * shrink[i]
        if v > data[i] + t:
            v -= t
        elif v < data[i] - t:
            v += t
        else:
            v = data[i]
        v = min(max(v, d_min), d_max)
        d_bar[i] = 2.0 * v - d[i]
        d[i] = v
        a = u[i, 0] - tau_u[i, 0] * gu0
        b = u[i, 1] - tau_u[i, 1] * gu1
        u_bar[i, 0] = 2.0 * a - u[i, 0]
        u_bar[i, 1] = 2.0 * b - u[i, 1]
        u[i, 0] = a
        u[i, 1] = b


@numba.njit(cache=True)
def _fill_transpose(neighbors, weights, in_ptr, in_src, in_slot):
    """Incoming edges of every pixel (CSR, sources in increasing order); serial counting sort."""
    fill = in_ptr[:-1].copy()
    n, k_max = neighbors.shape
    for i in range(n):
        for k in range(k_max):
            if weights[i, k] > 0:
                j = neighbors[i, k]
                in_src[fill[j]] = i
                in_slot[fill[j]] = k
                fill[j] += 1


def preconditioners(problem: ScaleProblem) -> dict[str, np.ndarray]:
    """Step sizes (α = 1 diagonal preconditioning) and the CSR transpose of the graph."""
    g = problem.graph
    n, k = g.neighbors.shape
    w = g.weights.astype(np.float32)
    delta = np.abs(g.offsets).astype(np.float32)
    gamma = problem.gamma
    active = w.ravel() > 0
    targets = g.neighbors.ravel()[active]
    in_ptr = np.concatenate([[0], np.cumsum(np.bincount(targets, minlength=n))]).astype(np.int64)
    in_src = np.empty(in_ptr[-1], np.int32)
    in_slot = np.empty(in_ptr[-1], np.int32)
    _fill_transpose(g.neighbors, g.weights, in_ptr, in_src, in_slot)
    w_in = np.bincount(targets, weights=w.ravel()[active], minlength=n)
    w_out = w.sum(1)
    col_d = w_out + w_in
    col_u = np.einsum("ik,ikc->ic", w, delta) + gamma * (w_out + w_in)[:, None]
    row_p = (w * (2.0 + delta.sum(2))).max(1)
    big = 1e6  # variables / rows untouched by any edge: any step is exact
    return {
        "tau_d": np.where(col_d > 0, 1.0 / np.maximum(col_d, 1e-30), big).astype(np.float32),
        "tau_u": np.where(col_u > 0, 1.0 / np.maximum(col_u, 1e-30), big).astype(np.float32),
        "sigma_p": np.where(row_p > 0, 1.0 / np.maximum(row_p, 1e-30), 0.0).astype(np.float32),
        "in_ptr": in_ptr, "in_src": in_src, "in_slot": in_slot,
        "offsets": g.offsets,
    }


def solve_primal_dual(problem: ScaleProblem, d0: np.ndarray, u0: np.ndarray,
                      iters: int, balance: float = 0.05) -> tuple[np.ndarray, np.ndarray, int]:
    """Minimise E from (d0 (N,), u0 (N, 2)) with ``iters`` primal-dual iterations; float32 state.

    ``balance`` scales primal steps up and dual steps down by θ = balance · median(d̄) (kept τσ, so
    convergence holds for any θ > 0): the duals live in unit balls while d lives on the scale of the
    inverse depths, so θ proportional to that scale makes the speed independent of the scene's units.

    Returns (d, u, iterations done).
    """
    pre = preconditioners(problem)
    g = problem.graph
    n, k = g.neighbors.shape
    d = np.clip(np.asarray(d0, np.float32).ravel(), problem.d_min, problem.d_max).astype(np.float32)
    u = np.ascontiguousarray(np.asarray(u0, np.float32).reshape(-1, 2))
    d_bar, u_bar = d.copy(), u.copy()
    p = np.zeros((n, k), np.float32)
    q = np.zeros((n, k, 2), np.float32)
    data = np.asarray(problem.data, np.float32)
    shrink = (problem.lambda_data / problem.lambda_reg * np.asarray(problem.fidelity, np.float64)).astype(np.float32)
    weights = np.ascontiguousarray(g.weights, np.float32)
    neighbors = np.ascontiguousarray(g.neighbors, np.int32)
    offsets = pre["offsets"]
    observed = problem.data[problem.fidelity > 0]
    theta = balance * float(np.median(observed)) if observed.size else balance * problem.d_max
    sigma_p = (pre["sigma_p"] / theta).astype(np.float32)
    sigma_q = np.float32(0.5 / theta)
    tau_d = (pre["tau_d"] * theta).astype(np.float32)
    tau_u = (pre["tau_u"] * theta).astype(np.float32)
    for _ in range(iters):
        check_interrupt()  # between kernels (engine/core/interrupt.py)
        dual_step(d_bar, u_bar, neighbors, weights, offsets, sigma_p, sigma_q, np.float32(problem.gamma), p, q)
        primal_step(d, u, d_bar, u_bar, p, q, weights, offsets, pre["in_ptr"], pre["in_src"], pre["in_slot"],
                     tau_d, tau_u, data, shrink, np.float32(problem.d_min),
                     np.float32(problem.d_max), np.float32(problem.gamma))
    return d, u, iters
