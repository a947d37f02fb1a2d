"""Sampling patterns and candidate gathering for the red-black checkerboard (Xu & Tao 2019 ACMM's
adaptive checkerboard sampling; the DeepC pattern of Kuhn et al. 2020).

A pattern is a list of offsets (dx, dy) with a region id each. In every region the in-image sample
with a valid depth and the lowest stored cost wins; the winners, ranked by their stored cost, are the
candidates. The DeepC patterns give every sample its own region (24 candidates); ACMM's has eight
regions (near "V" and far strip in each of the four directions). All offsets have odd |dx|+|dy|, so a
pixel only reads pixels of the other colour (race-free, deterministic).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from engine.patchmatch.geometry import propagate_depth, ray

DEEPC_DISTANCES = (3, 5, 7, 9, 11, 13)
DEEPC_FAR_DISTANCES = (3, 7, 11, 15, 19, 23)


def _rotations(dx: int, dy: int) -> list[tuple[int, int]]:
    """The 'up' offset (dx, dy) (dy < 0) turned to up, down, left, right."""
    return [(dx, dy), (dx, -dy), (dy, dx), (-dy, dx)]


def sampling_pattern(name: str) -> tuple[np.ndarray, np.ndarray]:
    """Offsets (P, 2) int32 and region ids (P,) int32 of a named pattern.

    'deepc': distances 3,5,...,13 on the four axes (24 regions of one sample).
    'deepc_far': distances 3,7,...,23 (24 regions).
    'acmm': for each direction a near 'V' of 7 samples {(0,-1), (±1,-2), (±2,-3), (±3,-4)} (the
    intended opposite-colour set, not the released code's same-colour one) and a far strip
    (0, -3-2k), k = 0..10; 8 regions, each picks its minimum-cost sample (right_far fixed too).
    """
    offsets: list[tuple[int, int]] = []
    regions: list[int] = []
    if name in ("deepc", "deepc_far"):
        dists = DEEPC_DISTANCES if name == "deepc" else DEEPC_FAR_DISTANCES
        for direction in range(4):
            for d in dists:
                offsets.append(_rotations(0, -d)[direction])
                regions.append(len(regions))
    elif name == "acmm":
        near = [(0, -1), (-1, -2), (1, -2), (-2, -3), (2, -3), (-3, -4), (3, -4)]
        far = [(0, -3 - 2 * k) for k in range(11)]
        for direction in range(4):
            for dx, dy in near:
                offsets.append(_rotations(dx, dy)[direction])
                regions.append(2 * direction)
            for dx, dy in far:
                offsets.append(_rotations(dx, dy)[direction])
                regions.append(2 * direction + 1)
    else:
        raise ValueError(f"unknown sampling pattern {name!r}")
    offs = np.array(offsets, np.int32)
    assert np.all((np.abs(offs).sum(axis=1) % 2) == 1), "pattern offsets must reach the other colour"
    return offs, np.array(regions, np.int32)


@njit(cache=True, _nrt=False)
def gather_candidates(x: int, y: int, Z: np.ndarray, Nrm: np.ndarray, C: np.ndarray, pat: np.ndarray,
                      region: np.ndarray, n_regions: int, kinv: np.ndarray, zmin: float, zmax: float,
                      plane: bool, k_max: int, reg_cost: np.ndarray, reg_idx: np.ndarray,
                      reg_ord: np.ndarray, cand_z: np.ndarray, cand_n: np.ndarray, cand_c: np.ndarray,
                      cand_s: np.ndarray) -> int:
    """Fill up to ``k_max`` candidate hypotheses for pixel (x, y), best stored cost first.

    Scratch ``reg_cost`` (f32), ``reg_idx``, ``reg_ord`` (i64) have length >= n_regions;
    outputs ``cand_z`` (K,), ``cand_n`` (K, 3), ``cand_c`` (K,) (the sample's stored cost) and ``cand_s``
    (K,) (the sample's index in the pattern). Candidates whose propagated depth leaves [zmin, zmax] are
    dropped. Returns the number of candidates. Ties keep pattern order.
    """
    h, w = Z.shape
    for r in range(n_regions):
        reg_cost[r] = np.inf
        reg_idx[r] = -1
    for s in range(pat.shape[0]):
        qx = x + pat[s, 0]
        qy = y + pat[s, 1]
        if qx < 0 or qy < 0 or qx >= w or qy >= h:
            continue
        if Z[qy, qx] <= 0.0:
            continue
        c = C[qy, qx]
        r = region[s]
        if c < reg_cost[r]:
            reg_cost[r] = c
            reg_idx[r] = s
    # rank the regions' winners by stored cost (stable insertion sort of region indices: moving one
    # integer per step instead of a whole candidate), then propagate down the ranking until k_max
    # candidates fall inside [zmin, zmax]: the same list as dropping first, without the depths of the
    # samples ranked below the k_max-th
    n_ranked = 0
    for r in range(n_regions):
        if reg_idx[r] < 0:
            continue
        c = reg_cost[r]
        pos = n_ranked
        while pos > 0 and reg_cost[reg_ord[pos - 1]] > c:
            reg_ord[pos] = reg_ord[pos - 1]
            pos -= 1
        reg_ord[pos] = r
        n_ranked += 1
    rp = ray(kinv, x, y)
    n = 0
    for i in range(n_ranked):
        if n >= k_max:
            break
        r = reg_ord[i]
        s = reg_idx[r]
        qx = x + pat[s, 0]
        qy = y + pat[s, 1]
        z = propagate_depth(Z[qy, qx], Nrm[qy, qx, 0], Nrm[qy, qx, 1], Nrm[qy, qx, 2], ray(kinv, qx, qy), rp, plane)
        if not (z >= zmin and z <= zmax):
            continue
        cand_c[n] = reg_cost[r]
        cand_s[n] = s
        cand_z[n] = z
        cand_n[n, 0] = Nrm[qy, qx, 0]
        cand_n[n, 1] = Nrm[qy, qx, 1]
        cand_n[n, 2] = Nrm[qy, qx, 2]
        n += 1
    return n
