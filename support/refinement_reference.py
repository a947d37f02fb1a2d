"""Plain-numpy references of the refinement's kernels (Rossi et al. 2020), used by their tests."""

from __future__ import annotations

import numpy as np

from engine.refinement.energy import ScaleProblem
from engine.refinement.graph import SimilarityGraph, window_offsets


def _box_sum(a: np.ndarray, size: int) -> np.ndarray:
    """Sum over size x size boxes of the last two axes ('valid' mode) via an integral image."""
    s = np.cumsum(np.cumsum(a, axis=-2, dtype=np.float64), axis=-1)
    s = np.pad(s, [(0, 0)] * (a.ndim - 2) + [(1, 0), (1, 0)])
    return s[..., size:, size:] - s[..., :-size, size:] - s[..., size:, :-size] + s[..., :-size, :-size]


def energy_terms_reference(problem: ScaleProblem, d: np.ndarray, u: np.ndarray) -> dict[str, float]:
    """Plain-numpy twin of :func:`engine.refinement.energy.energy_terms`."""
    d = np.asarray(d, np.float64).ravel()
    u = np.asarray(u, np.float64).reshape(-1, 2)
    g = problem.graph
    n = problem.size
    w = g.weights.astype(np.float64)
    nb = g.neighbors
    delta = g.offsets.astype(np.float64)
    data = problem.lambda_data / n * float(np.sum(problem.fidelity * np.abs(d - problem.data)))
    res = w * (d[:, None] - d[nb] - np.einsum("ic,ikc->ik", u, delta))
    plane = problem.lambda_reg / n * float(np.sum(np.sqrt(np.sum(res * res, axis=1))))
    tv = problem.lambda_reg * problem.gamma / n * float(
        np.sum(w * np.linalg.norm(u[:, None, :] - u[nb], axis=-1)))
    return {"data": data, "plane": plane, "orientation": tv, "total": data + plane + tv}



def similarity_graph_reference(gray: np.ndarray, window: int = 9, patch: int = 3, sigma_int: float = 0.07,
                               sigma_spa: float = 3.0, degree: int = 20) -> SimilarityGraph:
    """Plain-numpy twin of :func:`engine.refinement.graph.similarity_graph`.

    Shifted difference maps, a box filter and top-k instead of the kernel's per-pixel loops.
    """
    gray = np.asarray(gray, np.float64)
    h, w = gray.shape
    rw, rp = window // 2, patch // 2
    offs = window_offsets(window)
    pad = np.pad(gray, rw + rp, mode="edge")
    centre = pad[rw:rw + h + 2 * rp, rw:rw + w + 2 * rp]
    rows = np.arange(h)[:, None]
    cols = np.arange(w)[None, :]
    logw = np.empty((len(offs), h, w), np.float32)
    for n, (dy, dx) in enumerate(offs):
        shifted = pad[rw + dy:rw + dy + h + 2 * rp, rw + dx:rw + dx + w + 2 * rp]
        pd = _box_sum((shifted - centre) ** 2, patch)
        lw = -pd / (2 * sigma_int ** 2) - (dy * dy + dx * dx) / (2 * sigma_spa ** 2)
        inside = (rows + dy >= 0) & (rows + dy < h) & (cols + dx >= 0) & (cols + dx < w)
        logw[n] = np.where(inside, lw, -np.inf)
    k = min(degree, len(offs))
    # Top-k along the candidate axis; ties resolved by argpartition (weights are what matter).
    top = np.argpartition(-logw, k - 1, axis=0)[:k] if k < len(offs) else np.arange(len(offs))[:, None, None] \
        + np.zeros((1, h, w), np.int64)
    top_logw = np.take_along_axis(logw, top, axis=0)
    wh = np.exp(top_logw.astype(np.float64))  # exp(-inf) = 0 for outside candidates
    total = wh.sum(axis=0)
    weights = wh / np.maximum(total, 1e-12)
    dy = offs[top, 0]
    dx = offs[top, 1]
    i_lin = (rows * w + cols)[None]
    j_lin = i_lin + dy * w + dx
    j_lin = np.where(wh > 0, j_lin, i_lin)
    weights = np.where(wh > 0, weights, 0.0)
    # Sort slots by weight (largest first) so the layout does not depend on argpartition internals.
    order = np.argsort(-weights, axis=0, kind="stable")
    weights = np.take_along_axis(weights, order, axis=0)
    j_lin = np.take_along_axis(j_lin, order, axis=0)
    return SimilarityGraph(h, w, np.ascontiguousarray(j_lin.reshape(k, -1).T, dtype=np.int32),
                           np.ascontiguousarray(weights.reshape(k, -1).T, dtype=np.float32))



def dual_step_reference(d_bar, u_bar, neighbors, weights, offsets, sigma_p, sigma_q, gamma, p, q) -> None:
    """Plain-numpy twin of ``engine.refinement.primal_dual.dual_step`` (updates p, q in place)."""
    j = neighbors
    delta = offsets.astype(np.float64)
    r = weights * (d_bar[:, None] - d_bar[j] - np.einsum("ic,ikc->ik", u_bar, delta))
    p += sigma_p[:, None] * r
    norm = np.linalg.norm(p, axis=1, keepdims=True)
    p /= np.maximum(norm, 1.0)
    if gamma > 0:
        active = (weights > 0)[..., None]
        qn = q + sigma_q * (u_bar[:, None, :] - u_bar[j])
        qn /= np.maximum(np.linalg.norm(qn, axis=2, keepdims=True), 1.0)
        q[...] = np.where(active, qn, q)



def primal_step_reference(d, u, d_bar, u_bar, p, q, neighbors, weights, offsets, tau_d, tau_u, data, shrink,
                          d_min, d_max, gamma) -> None:
    """Plain-numpy twin of ``engine.refinement.primal_dual.primal_step``.

    Scatters with np.add.at instead of the CSR transpose.
    """
    j = neighbors
    delta = offsets.astype(np.float64)
    wp = weights * p
    gd = wp.sum(1)
    np.add.at(gd, j.ravel(), -wp.ravel())
    gu = -np.einsum("ik,ikc->ic", wp, delta) + gamma * np.einsum("ik,ikc->ic", weights, q)
    wq = gamma * weights[..., None] * q
    np.add.at(gu, j.ravel(), -wq.reshape(-1, 2))
    v = d - tau_d * gd
    t = tau_d * shrink
    v = np.where(v > data + t, v - t, np.where(v < data - t, v + t, data))
    v = np.clip(v, d_min, d_max)
    a = u - tau_u * gu
    d_bar[:] = 2 * v - d
    u_bar[:] = 2 * a - u
    d[:] = v
    u[:] = a
