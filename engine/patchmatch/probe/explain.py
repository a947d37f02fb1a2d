"""Why one pixel's hypothesis changed in one half-step: every candidate the half-step kernel weighs, its
per-view costs, the view weights that aggregated them and the rule that decided (the pixel probe,
``probe.py``).

:func:`explain_pixel` follows ``kernels.half_step_kernel`` for one pixel, from the maps the kernel starts from
and the same random stream, calling the kernel's own numba functions (candidate gathering, view weights,
photometric and geometric costs, refinement hypotheses) from Python: candidates, view weights and decisions
are those of the kernel. Unlike the kernel it evaluates every view of every candidate (the kernel stops
summing a losing candidate early and caches rows), so the costs it reports are complete; the decision uses
the kernel's comparisons (a candidate evaluated after the view-selection rows counts as losing once its
weighted sum reaches the best cost so far). It runs only for probed pixels, outside the hot loop (Xu & Tao
2019 ACMM's half-step with Kuhn et al. 2020 DeepC-MVS's pattern and perturbation).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from engine.patchmatch.geometry import plane_vector, ray
from engine.patchmatch.kernels import BIG, geometric_cost, photometric_cost, refinement_hypotheses
from engine.patchmatch.ncc import load_window, ncc_work
from engine.patchmatch.propagation import gather_candidates
from engine.patchmatch.records import (
    HypothesisMaps,
    KernelParams,
    ReferenceWindows,
    SamplingPattern,
    SourceImages,
)
from engine.patchmatch.rng import combine
from engine.patchmatch.view_selection import view_weights

# the refinement's hypotheses in the order refinement_hypotheses makes them: (depth, normal) kinds, where
# "best" is the best hypothesis after propagation, "perturbed" a perturbation of it, "random" a fresh draw
ACMM5_KINDS = (("random", "best"), ("best", "random"), ("random", "random"), ("best", "perturbed"),
               ("perturbed", "best"))
ALL8_KINDS = tuple((dz, dn) for dz in ("best", "perturbed", "random") for dn in ("best", "perturbed", "random")
                   if (dz, dn) != ("best", "best"))


def refinement_origin(depth_kind: str, normal_kind: str) -> str:
    """'perturbation', 'random' or 'combination' (one perturbed and one random part) of a refinement hypothesis."""
    kinds = {depth_kind, normal_kind} - {"best"}
    if kinds == {"perturbed"}:
        return "perturbation"
    if kinds == {"random"}:
        return "random"
    return "combination"


def _f(value: float) -> float | None:
    """A cost for JSON: None for 'no plane' (the kernel's BIG) and NaN."""
    value = float(value)
    return None if not math.isfinite(value) or value >= BIG else value


class _Pixel:
    """The fixed inputs of one pixel's costs (the kernel's per-pixel locals)."""

    def __init__(self, ref: ReferenceWindows, sources: SourceImages, params: KernelParams, x: int, y: int):
        self.ref, self.sources, self.params, self.x, self.y = ref, sources, params, x, y
        self.win, self.sidx = ncc_work(ref.offset_x.shape[1])
        self.n = load_window(self.win, ref.image, ref.offsets, ref.sigmas, ref.weighting, ref.offset_x, ref.offset_y,
                             ref.window_set, ref.n_samples, x, y)
        self.mu = ref.mean[y, x]
        self.var = ref.variance[y, x]
        self.rp = ray(ref.kinv, x, y)
        self.n_views = sources.geometry.shape[0]

    def photometric(self, z: float, nx: float, ny: float, nz: float) -> np.ndarray | None:
        """(N,) m_j of hypothesis (z, n) on every view, or None when it has no plane (the kernel's BIG)."""
        m0, m1, m2, ok = plane_vector(self.ref.kinv, self.rp, z, nx, ny, nz)
        if not ok:
            return None
        s = self.sources
        return np.array([photometric_cost(s.pixels, s.stride, s.plane, s.geometry, j, self.win, self.n, self.mu,
                                          self.var, self.x, self.y, m0, m1, m2, self.params.min_var, self.sidx)
                         for j in range(self.n_views)], np.float64)

    def geometric(self, z: float) -> np.ndarray:
        """(N,) λ · min(reprojection error, δ) of depth z on every view (zeros in photometric passes)."""
        p = self.params
        if not p.geometric:
            return np.zeros(self.n_views)
        s = self.sources
        return np.array([p.geom_lambda * geometric_cost(s.geometry, s.depth, j, self.x, self.y, z, p.geom_max)
                         for j in range(self.n_views)], np.float64)


def _weighted(v: np.ndarray, m: np.ndarray, g: np.ndarray) -> float:
    """Σ_j v_j (m_j + g_j) over v_j > 0, in view order (the kernel's final sum)."""
    acc = 0.0
    for j in range(v.shape[0]):
        if v[j] > 0.0:
            acc += v[j] * (m[j] + g[j])
    return acc


def explain_pixel(maps: HypothesisMaps, view_costs: np.ndarray, ref: ReferenceWindows, sources: SourceImages,
                  pattern: SamplingPattern, key: np.uint64, params: KernelParams, cpre: np.ndarray,
                  x: int, y: int) -> dict[str, Any]:
    """The update of pixel (x, y) by the half-step about to run on ``maps`` (the kernel's arguments).

    ``view_costs`` (H, W, N) f32: the pass's cache of the stored hypothesis's m_j (NaN = not yet evaluated;
    read only). Returns ``candidates`` (list of dicts: ``origin``, ``sample`` (pattern index or None),
    ``depth``, ``normal``, ``cost`` (aggregated, None without a plane), ``photometric_cost`` (the same sum
    without the geometric term), ``view_costs`` (N m_j or None), ``geometric_costs`` (N λ·g_j or None)),
    ``winner`` (index; 0 = the current hypothesis), ``decided_by``, ``view_weights`` (N), ``selected`` (the
    source positions with v_j > 0), ``improved`` (whether the hypothesis is replaced)."""
    Z, Nrm, C, Sel = maps.depth, maps.normal, maps.cost, maps.selected_views
    h, w = Z.shape
    p = params
    px = _Pixel(ref, sources, params, x, y)
    n_views = px.n_views
    k_up, k_vs, n_reg = p.k_update, p.k_viewsel, p.n_regions
    pk = np.uint64(combine(key, y * w + x))
    cand_z = np.empty(k_up, np.float64)
    cand_n = np.empty((k_up, 3), np.float64)
    cand_c = np.empty(k_up, np.float32)
    cand_s = np.empty(k_up, np.int64)
    n_cand = gather_candidates(x, y, Z, Nrm, C, pattern.offsets, pattern.regions, n_reg, ref.kinv, p.zmin, p.zmax,
                               p.plane_propagation, k_up, np.empty(n_reg, np.float32), np.empty(n_reg, np.int64),
                               np.empty(n_reg, np.int64), cand_z, cand_n, cand_c, cand_s)
    n_vs = min(n_cand, k_vs)
    rows = [px.photometric(cand_z[k], *cand_n[k]) for k in range(n_cand)]
    for k in range(n_vs):  # the view-selection rows of a candidate without a plane are cost 2 (not 'no plane')
        if rows[k] is None:
            rows[k] = np.full(n_views, 2.0)
    M = np.empty((k_vs, n_views), np.float64)  # rows past n_vs are never read (view_weights counts them missing)
    for k in range(n_vs):
        M[k] = rows[k]
    omega = np.empty(n_views, np.float64)
    v = np.empty(n_views, np.float64)
    vsum = view_weights(M, n_vs, n_views, Sel, x, y, p.tau_good, p.tau_bad, p.beta, p.beta_fallback, p.n_good,
                        p.n_bad, p.prior_in, p.prior_out, p.deterministic, p.mc_samples, pk, 0, omega, v)
    z0 = float(Z[y, x])
    n0 = tuple(float(c) for c in Nrm[y, x])
    cached = np.array(view_costs[y, x], np.float64)
    fresh = px.photometric(z0, *n0)
    cur_m = None if fresh is None else np.where(np.isnan(cached), fresh, cached)
    if vsum <= 0.0:
        # degenerate weights: the top_k views with the lowest cost of the current hypothesis
        tmp = cur_m.copy() if cur_m is not None else np.full(n_views, 2.0)
        kth = np.sort(tmp)[min(p.top_k, n_views) - 1]
        vsum = 0.0
        for j in range(n_views):
            if tmp[j] <= kth and vsum < p.top_k:
                v[j] = 1.0
                vsum += 1.0
            else:
                v[j] = 0.0
    geom0 = px.geometric(z0)
    if cur_m is None:
        c_cur = BIG
    else:
        c_cur = _weighted(v, cur_m, geom0)
        c_cur = BIG if c_cur >= BIG * vsum else c_cur / vsum
    if c_cur >= BIG:
        c_cur = 2.0 + (p.geom_lambda * p.geom_max if p.geometric else 0.0)
    candidates = [_candidate("current", None, z0, n0, c_cur, cur_m, geom0, v, vsum)]
    bar = c_cur - p.min_improvement
    best, best_i = bar, 0
    zb, nb = z0, n0
    for k in range(n_cand):
        g = px.geometric(cand_z[k])
        m = rows[k]
        if m is None:
            cost = BIG
        elif k < n_vs:
            cost = _weighted(v, m, g) / vsum
        else:
            acc = _weighted(v, m, g)
            cost = BIG if acc >= best * vsum else acc / vsum
        full = BIG if m is None else _weighted(v, m, g) / vsum
        candidates.append(_candidate(f"pattern:{int(cand_s[k])}", int(cand_s[k]), cand_z[k], cand_n[k], full, m, g, v,
                                     vsum))
        if cost < best:
            best, best_i = cost, len(candidates) - 1
            zb, nb = float(cand_z[k]), tuple(float(c) for c in cand_n[k])
    hz = np.empty(8, np.float64)
    hn = np.empty((8, 3), np.float64)
    n_h = refinement_hypotheses(pk, px.rp, zb, nb[0], nb[1], nb[2], p.zmin, p.zmax, p.perturbation,
                                p.normal_retries, p.all8, hz, hn)
    kinds = ALL8_KINDS if p.all8 else ACMM5_KINDS
    for i in range(n_h):
        zi = hz[i]
        if not (p.zmin <= zi <= p.zmax):
            continue
        m = px.photometric(zi, *hn[i])
        g = px.geometric(zi)
        if m is None:
            cost = full = BIG
        else:
            acc = _weighted(v, m, g)
            full = acc / vsum
            cost = BIG if acc >= best * vsum else full
        cand = _candidate(refinement_origin(*kinds[i]), None, zi, hn[i], full, m, g, v, vsum)
        cand["refinement"] = {"depth": kinds[i][0], "normal": kinds[i][1]}
        candidates.append(cand)
        if cost < best:
            best, best_i = cost, len(candidates) - 1
    improved = False
    if not best < bar:
        lower = [c["cost"] for c in candidates[1:] if c["cost"] is not None and c["cost"] < c_cur]
        decided, winner = ("min_improvement" if lower else "cost"), 0
    elif params.detail_restorer and not best < float(cpre[y, x]) - p.detail_delta:
        decided, winner = "detail_restorer", 0
    else:
        decided, winner, improved = "cost", best_i, True
        if p.geometric:
            photo = [c["photometric_cost"] if c["photometric_cost"] is not None else math.inf for c in candidates]
            if int(np.argmin(photo)) != winner:
                decided = "geometric"  # without the geometric term another candidate would have had the lowest cost
    return {"candidates": candidates, "winner": winner, "decided_by": decided, "view_weights": [float(a) for a in v],
            "selected": [j for j in range(n_views) if v[j] > 0.0], "improved": improved,
            "restorer_reference": float(cpre[y, x]) if params.detail_restorer else None}


def _candidate(origin: str, sample: int | None, z: float, n, cost: float, m: np.ndarray | None, g: np.ndarray,
               v: np.ndarray, vsum: float) -> dict[str, Any]:
    photo = None if m is None else _weighted(v, m, np.zeros_like(m)) / vsum
    return {"origin": origin, "sample": sample, "depth": float(z), "normal": [float(c) for c in n],
            "cost": _f(cost), "photometric_cost": _f(photo) if photo is not None else None,
            "view_costs": None if m is None else [None if math.isnan(c) else float(c) for c in m],
            "geometric_costs": [float(c) for c in g] if np.any(g) else None}
