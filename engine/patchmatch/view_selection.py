"""Multi-hypothesis joint view selection (Xu & Tao 2019 ACMM, with the constants of its code).

From the photometric cost rows M[k, j] of the best K_vs candidates, each source view gets a weight
ω_j (many good costs -> Gaussian of the good costs; few bad costs -> a small constant; else 0),
multiplied by a neighbourhood prior from the selected-view masks of the 4-neighbours. The final
weights are Monte-Carlo counts (15 draws from ω normalised) or ω itself (deterministic variant).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from engine.patchmatch.rng import uniform

FLT_EPSILON = 1.1920929e-07


@njit(cache=True, _nrt=False)
def view_weights(M: np.ndarray, n_rows: int, n_views: int, Sel: np.ndarray, x: int, y: int,
                 tau_g: float, tau_bad: float, beta: float, beta_fb: float, n_good_gt: int, n_bad_lt: int,
                 prior_in: float, prior_out: float, deterministic: bool, mc_samples: int,
                 key: np.uint64, draw: int, omega: np.ndarray, v: np.ndarray) -> float:
    """Fill ``v`` (n_views,) with view weights for pixel (x, y); return their sum (0 = degenerate).

    ``M`` (K_vs, N): rows beyond ``n_rows`` are treated as cost 2 (missing candidates count as bad
    matches). ``omega`` is scratch (N,). Monte-Carlo draws use ``draw .. draw + mc_samples - 1``.
    """
    h, w = Sel.shape
    k_rows = M.shape[0]
    n_missing = k_rows - n_rows
    # 2.0 > tau_bad always (tau_bad <= 2 is validated) unless tau_bad == 2
    missing_bad = n_missing if 2.0 > tau_bad else 0
    total = 0.0
    for j in range(n_views):
        good = 0
        bad = missing_bad
        s = 0.0
        for k in range(n_rows):
            c = M[k, j]
            if c < tau_g:
                good += 1
                s += math.exp(-c * c / (2.0 * beta * beta))
            if c > tau_bad:
                bad += 1
        if good > n_good_gt and bad < n_bad_lt:
            om = s / good
        elif bad < n_bad_lt:
            om = math.exp(-tau_g * tau_g / (2.0 * beta_fb * beta_fb))
        else:
            om = 0.0
        if om > 0.0:
            bit = np.uint32(1) << np.uint32(j)
            prior = 0.0
            if y > 0:
                prior += prior_in if (Sel[y - 1, x] & bit) != 0 else prior_out
            if y < h - 1:
                prior += prior_in if (Sel[y + 1, x] & bit) != 0 else prior_out
            if x > 0:
                prior += prior_in if (Sel[y, x - 1] & bit) != 0 else prior_out
            if x < w - 1:
                prior += prior_in if (Sel[y, x + 1] & bit) != 0 else prior_out
            om *= prior
        omega[j] = om
        total += om
    if total <= 0.0:
        for j in range(n_views):
            v[j] = 0.0
        return 0.0
    if deterministic:
        for j in range(n_views):
            v[j] = omega[j]
        return total
    for j in range(n_views):
        v[j] = 0.0
    inv = 1.0 / total
    last = 0
    for j in range(n_views):
        if omega[j] > 0.0:
            last = j
    for s in range(mc_samples):
        u = uniform(key, draw + s) - FLT_EPSILON
        cdf = 0.0
        pick = last  # rounding at the end of the cdf: fall back to the last non-zero view
        for j in range(n_views):
            cdf += omega[j] * inv
            if omega[j] > 0.0 and cdf > u:
                pick = j
                break
        v[pick] += 1.0
    return float(mc_samples)
