"""numba kernels of one reference view at one level: random init, initial cost, red-black half-step
(Xu & Tao 2019 ACMM's kernels with the modifications of Kuhn et al. 2020 DeepC-MVS).

All kernels run ``prange`` over image rows; the initial cost and the half-step over a block of them
(``records.RowBlock``: ``view_pass`` splits a view into blocks so that a stop request is honoured within a
fraction of a second; every pixel's result is the same whatever the split). Per-row scratch arrays are
allocated once per row (never per pixel). Randomness is counter-based (``rng.py``): pixel (x, y) of a
half-step uses the stream ``combine(key, y * W + x)``, so results do not depend on the thread count.

The kernels take named records (``records.py``): the hypothesis maps, the cost caches, the reference
view's matching windows, the source images and the iteration's parameters. The small functions they call
take the records' arrays one by one (``geometry.relative_geometry`` and ``ncc.load_window`` define
them): src (N·(Hm+1)·(Wm+1),) f32 raveled padded source images, stride = Wm+1, plane = (Hm+1)(Wm+1), geo
(N, GEO_COLS) f64 packed geometry and sizes (``geometry.pack_geometry``), sdepth (N, Hm, Wm) f32 source
depths (geometric passes), kinv (9,) the inverse intrinsics; win (WORK_ROWS, work_width(S)) f32 and sidx
i32 (``ncc.ncc_work``) hold the pixel's window of n samples (``ncc.load_window``), mu/var its weighted
mean and variance.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from engine.patchmatch.geometry import (
    GEO_A,
    GEO_B,
    GEO_H,
    GEO_W,
    perturb_normal,
    plane_vector,
    random_normal,
    ray,
    reprojection_error,
)
from engine.patchmatch.ncc import load_window, ncc_cost, ncc_work
from engine.patchmatch.propagation import gather_candidates
from engine.patchmatch.rng import combine, uniform
from engine.patchmatch.view_selection import view_weights

# columns of the half-step's counts (H, N_COUNTS): NCC windows evaluated for the view-selection rows, the
# current hypothesis, the remaining candidates and the refinement hypotheses; pixels updated; pixels the active
# set left alone
CNT_ROWS, CNT_CURRENT, CNT_REMAINING, CNT_REFINE, CNT_PIXELS, CNT_SKIPPED = range(6)
N_COUNTS = 6
BIG = 1e30
# draw of a pixel's stream that decides whether a quiet pixel is updated anyway (the other draws of a half-step
# are below 300: view weights 0.., refinement 100.., normal perturbation 200..)
ACTIVE_DRAW = 1 << 16
# active set: a replaced hypothesis has moved when its depth moves by more than params.change_depth (relative) or
# its normal turns by more than 5 degrees; smaller moves (most replacements late in a pass are the refinement's
# small perturbations) change a neighbour's propagated depth 13 px away by well under 1 % and wake no neighbour
ACTIVE_NORMAL_COS = math.cos(math.radians(5.0))


@njit(cache=True, fastmath=True, _nrt=False, inline="always")
def photometric_cost(src, stride, plane, geo, j, win, n, mu, var, x, y, m0, m1, m2, min_var, sidx):
    """m_j of the plane with vector m = (m0, m1, m2) (see geometry.plane_vector) at ref pixel (x, y).
    Inlined where it is called: one call (and argument list) per NCC window fewer."""
    h00 = np.float32(geo[j, GEO_A] - geo[j, GEO_B] * m0)
    h01 = np.float32(geo[j, GEO_A + 1] - geo[j, GEO_B] * m1)
    h02 = np.float32(geo[j, GEO_A + 2] - geo[j, GEO_B] * m2)
    h10 = np.float32(geo[j, GEO_A + 3] - geo[j, GEO_B + 1] * m0)
    h11 = np.float32(geo[j, GEO_A + 4] - geo[j, GEO_B + 1] * m1)
    h12 = np.float32(geo[j, GEO_A + 5] - geo[j, GEO_B + 1] * m2)
    h20 = np.float32(geo[j, GEO_A + 6] - geo[j, GEO_B + 2] * m0)
    h21 = np.float32(geo[j, GEO_A + 7] - geo[j, GEO_B + 2] * m1)
    h22 = np.float32(geo[j, GEO_A + 8] - geo[j, GEO_B + 2] * m2)
    return ncc_cost(src, j * plane, stride, int(geo[j, GEO_W]), int(geo[j, GEO_H]), win, n, mu, var, x, y,
                    h00, h01, h02, h10, h11, h12, h20, h21, h22, np.float32(min_var), sidx)


@njit(cache=True, _nrt=False)
def geometric_cost(geo, sdepth, j, x, y, z, gmax):
    """Truncated forward-backward reprojection error g_j (px) of depth z at (x, y) (Xu & Tao 2019 ACMM's
    geometric consistency term)."""
    e = reprojection_error(geo, j, sdepth, x, y, z)
    if e < 0.0 or e > gmax:
        return gmax
    return e


# An early exit needs partial * (1 - EXIT_MARGIN) >= limit: the partial sum is taken in another order
# than the full sum it stands for, and n <= 32 non-negative float64 terms summed in two orders differ
# by far less than 1e-12 relatively.
EXIT_MARGIN = 1e-12


@njit(cache=True, _nrt=False)
def view_order(v, order):
    """Indices of the views with v_j > 0, largest weight first (ties: lower index first), into
    ``order`` (N,); returns their count."""
    n = 0
    for j in range(v.shape[0]):
        vj = v[j]
        if vj <= 0.0:
            continue
        pos = n
        while pos > 0 and v[order[pos - 1]] < vj:
            order[pos] = order[pos - 1]
            pos -= 1
        order[pos] = j
        n += 1
    return n


@njit(cache=True, _nrt=False, inline="always")
def aggregated_cost(src, stride, plane, geo, sdepth, kinv, win, n, mu, var, x, y, rp, z, nx, ny, nz, v, vsum, order,
                    n_sel, terms, geom, lam, gmax, min_var, threshold, R, k, sidx):
    """Σ_j v_j (m_j + λ g_j) / Σ_j v_j for hypothesis (z, n) at (x, y); BIG once it is proven >= ``threshold``.

    Row k of ``R`` (K, N) holds the m_j known already (NaN = unknown; the ones evaluated here are added).
    The result equals summing the terms in view order and returning BIG when that sum reaches
    ``threshold · vsum`` (all terms are >= 0, so a partial sum only grows): the known terms (and in
    geometric passes the geometric parts, which need no image window) are summed first, then the
    missing m_j are evaluated in ``order`` (the n_sel views with v_j > 0, heaviest first, see
    :func:`view_order`) so that a losing hypothesis is usually rejected after one or two windows; the
    terms of a hypothesis that survives are summed again in view order, so its cost is bit-identical to
    the plain sum. ``terms`` is scratch (N,)."""
    m0, m1, m2, ok = plane_vector(kinv, rp, z, nx, ny, nz)
    if not ok:
        return BIG
    limit = threshold * vsum
    # ``partial`` bounds the sum from below: first the known costs (free), then the geometric terms
    # (no image window, but a read of the source depth at a point anywhere in the source for a random
    # depth: a wrong depth usually exits at the first view), then the missing windows
    partial = 0.0
    for i in range(n_sel):
        j = order[i]
        terms[j] = 0.0
        if not math.isnan(R[k, j]):
            partial += v[j] * R[k, j]
    if partial * (1.0 - EXIT_MARGIN) >= limit:
        return BIG
    if geom:
        for i in range(n_sel):
            j = order[i]
            g = lam * geometric_cost(geo, sdepth, j, x, y, z, gmax)
            terms[j] = g
            partial += v[j] * g
            if partial * (1.0 - EXIT_MARGIN) >= limit:
                return BIG
    for i in range(n_sel):
        j = order[i]
        if not math.isnan(R[k, j]):
            continue
        cost = photometric_cost(src, stride, plane, geo, j, win, n, mu, var, x, y, m0, m1, m2, min_var, sidx)
        R[k, j] = cost
        partial += v[j] * cost
        if partial * (1.0 - EXIT_MARGIN) >= limit:
            return BIG
    acc = 0.0
    for j in range(v.shape[0]):
        if v[j] > 0.0:
            acc += v[j] * (R[k, j] + terms[j])
    if acc >= limit:
        return BIG
    return acc / vsum


@njit(cache=True, _nrt=False)
def n_known(R, k):
    """Number of entries of row k of ``R`` (K, N) that are not NaN."""
    n = 0
    for j in range(R.shape[1]):
        if not math.isnan(R[k, j]):
            n += 1
    return n


@njit(cache=True, _nrt=False)
def n_known_px(P, y, x):
    """Number of views whose cost of pixel (x, y)'s stored hypothesis is cached in ``P`` (H, W, N)."""
    n = 0
    for j in range(P.shape[2]):
        if not math.isnan(P[y, x, j]):
            n += 1
    return n


@njit(cache=True, _nrt=False)
def current_cost(src, stride, plane, geo, sdepth, kinv, win, n, mu, var, x, y, rp, z, nx, ny, nz, v, vsum, geom, lam,
                 gmax, min_var, P, sidx):
    """Σ_j v_j (m_j + λ g_j) / Σ_j v_j of the stored hypothesis (z, n) at (x, y), BIG if it has no plane.

    ``P[y, x]`` (N,) caches m_j of this hypothesis (NaN = not evaluated yet): cached views are not
    evaluated again, new ones are added to the cache. Same sum, same order as :func:`aggregated_cost`."""
    m0, m1, m2, ok = plane_vector(kinv, rp, z, nx, ny, nz)
    if not ok:
        return BIG
    limit = BIG * vsum
    acc = 0.0
    for j in range(v.shape[0]):
        vj = v[j]
        if vj <= 0.0:
            continue
        cost = P[y, x, j]
        if math.isnan(cost):
            cost = photometric_cost(src, stride, plane, geo, j, win, n, mu, var, x, y, m0, m1, m2, min_var, sidx)
            P[y, x, j] = cost
        if geom:
            cost += lam * geometric_cost(geo, sdepth, j, x, y, z, gmax)
        acc += vj * cost
        if acc >= limit:
            return BIG
    return acc / vsum


@njit(cache=True, _nrt=False, inline="always")
def cached_rows(R, cand_s, n_cand, n_old, x, y, pat, VER, RS, RT, RC):
    """Fill the cost rows R (K, N) of pixel (x, y)'s ``n_cand`` candidates (pattern samples ``cand_s``) from
    its row cache (``records.CostCaches``: RS, RC its previous update's ``n_old`` samples and cost rows, RT the
    half-step that wrote them): a candidate proposed again by the same sample of a pixel whose last change
    (VER, the half-step of it) came before that is the same hypothesis, so its costs are (NaN = unknown).
    The sample's pixel has the other colour, so it never changes in the half-step that writes the rows."""
    for k in range(n_cand):
        sk = cand_s[k]
        # the sample's slot (samples are unique in a list, and lists keep their order mostly)
        r = -1
        if k < n_old and RS[y, x, k] == sk:
            r = k
        else:
            for i in range(n_old):
                if RS[y, x, i] == sk:
                    r = i
                    break
        if r >= 0 and VER[y + pat[sk, 1], x + pat[sk, 0]] >= RT[y, x]:
            r = -1
        for j in range(R.shape[1]):
            R[k, j] = RC[y, x, r, j] if r >= 0 else np.nan


@njit(cache=True, _nrt=False, inline="always")
def moved_plane(z, nx, ny, nz, z0, n0x, n0y, n0z, tol):
    """Whether hypothesis (z, n) differs from (z0, n0) by more than ``tol`` in relative depth or by more than
    5 degrees in normal (ACTIVE_NORMAL_COS): a change that wakes the active set."""
    if abs(z - z0) > tol * max(z, z0):
        return True
    return nx * n0x + ny * n0y + nz * n0z < ACTIVE_NORMAL_COS


@njit(cache=True, _nrt=False)
def neighbourhood_changed(CH, pat, x, y):
    """Whether a pixel that pixel (x, y)'s update reads changed its hypothesis in its last update: a sample of
    the pattern ``pat`` (P, 2) (its candidates) or a 4-neighbour (the view-selection prior), per ``CH`` (H, W)
    u8 (``records.CostCaches.changed``). All of them have the other colour, so in a half-step their last update
    is the previous half-step, which the pixel's previous update did not see yet."""
    h, w = CH.shape
    n_pat = pat.shape[0]
    for s in range(n_pat + 4):
        if s < n_pat:
            qx = x + pat[s, 0]
            qy = y + pat[s, 1]
        else:  # the 4-neighbours (0, -1), (0, 1), (-1, 0), (1, 0)
            i = s - n_pat
            d = 1 if i % 2 else -1
            qx = x + (d if i >= 2 else 0)
            qy = y + (0 if i >= 2 else d)
        if qx >= 0 and qy >= 0 and qx < w and qy < h and CH[qy, qx] != 0:
            return True
    return False


@njit(cache=True, _nrt=False, inline="always")
def refinement_hypotheses(pk, rp, zb, nbx, nby, nbz, zmin, zmax, eps, retries, all8, hz, hn):
    """The local refinement's hypotheses around the best one (zb, nb) into ``hz`` (8,) and ``hn`` (8, 3); returns
    their count. Combinations of the current, a perturbed (relative depth ±eps, normal angles ±eps·π/2 with
    ``retries`` halvings, Schönberger et al. 2016 COLMAP) and a random depth / normal, drawn from the pixel's
    stream ``pk``: ACMM's five (Xu & Tao 2019, perturbation ε of Kuhn et al. 2020) or, with ``all8``, all eight."""
    z_rnd = zmin + (zmax - zmin) * uniform(pk, 100)
    z_prt = zb * (1.0 - eps + 2.0 * eps * uniform(pk, 101))
    rnx, rny, rnz, draw = random_normal(pk, 102, rp)
    pnx, pny, pnz, draw = perturb_normal(pk, 200, rp, nbx, nby, nbz, eps, retries)
    n_h = 0
    if all8:
        for dz in range(3):
            zz = zb if dz == 0 else (z_prt if dz == 1 else z_rnd)
            for dn in range(3):
                if dz == 0 and dn == 0:
                    continue
                hz[n_h] = zz
                if dn == 0:
                    hn[n_h, 0] = nbx
                    hn[n_h, 1] = nby
                    hn[n_h, 2] = nbz
                elif dn == 1:
                    hn[n_h, 0] = pnx
                    hn[n_h, 1] = pny
                    hn[n_h, 2] = pnz
                else:
                    hn[n_h, 0] = rnx
                    hn[n_h, 1] = rny
                    hn[n_h, 2] = rnz
                n_h += 1
    else:
        # ACMM order: (z_rnd, n), (z, n_rnd), (z_rnd, n_rnd), (z, n_prt), (z_prt, n)
        hz[0] = z_rnd
        hn[0, 0] = nbx
        hn[0, 1] = nby
        hn[0, 2] = nbz
        hz[1] = zb
        hn[1, 0] = rnx
        hn[1, 1] = rny
        hn[1, 2] = rnz
        hz[2] = z_rnd
        hn[2, 0] = rnx
        hn[2, 1] = rny
        hn[2, 2] = rnz
        hz[3] = zb
        hn[3, 0] = pnx
        hn[3, 1] = pny
        hn[3, 2] = pnz
        hz[4] = z_prt
        hn[4, 0] = nbx
        hn[4, 1] = nby
        hn[4, 2] = nbz
        n_h = 5
    return n_h


@njit(cache=True, _nrt=False, inline="always")
def box_bounds(params, h, w):
    """(x0, y0, x1, y1): the pixels [x0, x1) x [y0, y1) of an (h, w) map a kernel updates (``KernelParams.box_*``;
    the whole map by default)."""
    x1 = w if params.box_x1 < 0 else min(params.box_x1, w)
    y1 = h if params.box_y1 < 0 else min(params.box_y1, h)
    return max(params.box_x0, 0), max(params.box_y0, 0), x1, y1


@njit(cache=True, _nrt=False, inline="always")
def row_span(params, y, x_lo, x_hi):
    """[a, b): the pixels of row ``y`` within [x_lo, x_hi) a kernel updates: all of them, or with
    ``params.box_r`` >= 0 those within L1 distance box_r of (box_cx, box_cy) (a == b: none)."""
    if params.box_r < 0:
        return x_lo, x_hi
    d = params.box_r - abs(y - params.box_cy)
    if d < 0:
        return x_lo, x_lo
    a = min(max(x_lo, params.box_cx - d), x_hi)
    return a, max(a, min(x_hi, params.box_cx + d + 1))


@njit(cache=True, parallel=True)
def random_init_kernel(depth, normal, kinv, zmin, zmax, key, only_invalid):
    """Random hypotheses (the random initialisation of ACMM and COLMAP): depth (H, W) f32 ~ U[zmin, zmax],
    normal (H, W, 3) f32 a Marsaglia sample facing the camera (kinv (9,) f64 K⁻¹); in place.

    With ``only_invalid`` only pixels with depth <= 0 are drawn (holes after upsampling)."""
    h, w = depth.shape
    for y in prange(h):
        for x in range(w):
            if only_invalid and depth[y, x] > 0.0:
                continue
            pk = combine(key, y * w + x)
            rp = ray(kinv, x, y)
            depth[y, x] = zmin + (zmax - zmin) * uniform(pk, 0)
            nx, ny, nz, _ = random_normal(pk, 1, rp)
            normal[y, x, 0] = nx
            normal[y, x, 1] = ny
            normal[y, x, 2] = nz


@njit(cache=True, parallel=True)
def init_cost_kernel(maps, view_costs, store, known, known_wset, ref, sources, params, block):
    """Cost and selected views of the stored hypotheses (the top-k rule of Xu & Tao 2019 ACMM's initial cost).

    k = min(#{m_j < 2}, top_k); cost = mean of the k smallest m_j (+ λ · mean g_j over the selected
    views in geometric passes); selected_views = {j : m_j <= k-th smallest}; k = 0 gives cost 2 (+ λ·δ) and
    no view. Writes ``maps`` (:class:`records.HypothesisMaps`) cost and selected_views inside ``params``' box
    (:func:`box_bounds`). With ``store`` the m_j go to ``view_costs`` (H, W, N) f32, the half-steps' cache (NaN
    where the hypothesis has no plane).
    ``known`` (H, W, N) f32 holds m_j of the same hypotheses from an earlier pass over the same images (NaN =
    not evaluated), valid where that pass matched pixel (x, y) with the same window set, ``known_wset``
    (H, W) u8; shape (1, 1, 1) for none. Those are not evaluated again. ``ref``: :class:`records.ReferenceWindows`,
    ``sources``: :class:`records.SourceImages`, ``params``: :class:`records.KernelParams`, ``block``: the rows
    (:class:`records.RowBlock`); every pixel is independent of the others."""
    # the records' fields as locals: the loops below read exactly what they read as separate arguments
    Z, Nrm, C, Sel = maps.depth, maps.normal, maps.cost, maps.selected_views
    P = view_costs
    kinv, img, offs, sig, mode = ref.kinv, ref.image, ref.offsets, ref.sigmas, ref.weighting
    mu_a, var_a = ref.mean, ref.variance
    ox, oy, wset, ns = ref.offset_x, ref.offset_y, ref.window_set, ref.n_samples
    src, stride, plane, geo, sdepth = sources.pixels, sources.stride, sources.plane, sources.geometry, sources.depth
    h, w = Z.shape
    n_views = geo.shape[0]
    top_k = params.top_k
    geom = params.geometric
    lam = params.geom_lambda
    gmax = params.geom_max
    min_var = params.min_var
    have_known = known.shape[0] == h and known.shape[1] == w and known.shape[2] == n_views
    x_lo, y_lo, x_hi, y_hi = box_bounds(params, h, w)
    for y in prange(max(y_lo, block.start), min(y_hi, block.stop)):  # the box's rows within the block
        costs = np.empty(n_views, np.float64)
        order = np.empty(n_views, np.float64)
        win, sidx = ncc_work(ox.shape[1])
        a, b = row_span(params, y, x_lo, x_hi)
        for x in range(a, b):
            reuse = have_known and known_wset[y, x] == wset[y, x]
            z = Z[y, x]
            rp = ray(kinv, x, y)
            n = load_window(win, img, offs, sig, mode, ox, oy, wset, ns, x, y)
            nx = Nrm[y, x, 0]
            ny = Nrm[y, x, 1]
            nz = Nrm[y, x, 2]
            m0, m1, m2, ok = plane_vector(kinv, rp, z, nx, ny, nz)
            n_ok = 0
            for j in range(n_views):
                if ok and z > 0.0:
                    if reuse and not math.isnan(known[y, x, j]):
                        costs[j] = known[y, x, j]
                    else:
                        costs[j] = photometric_cost(src, stride, plane, geo, j, win, n, mu_a[y, x], var_a[y, x], x,
                                                    y, m0, m1, m2, min_var, sidx)
                    if store:
                        P[y, x, j] = costs[j]
                else:
                    costs[j] = 2.0
                    if store:
                        P[y, x, j] = np.nan
                order[j] = costs[j]
                if costs[j] < 2.0:
                    n_ok += 1
            k = min(n_ok, top_k)
            if k == 0:
                C[y, x] = 2.0 + (lam * gmax if geom else 0.0)
                Sel[y, x] = 0
                continue
            order.sort()
            kth = order[k - 1]
            total = 0.0
            for i in range(k):
                total += order[i]
            mask = np.uint32(0)
            gsum = 0.0
            gcount = 0
            for j in range(n_views):
                if costs[j] <= kth:
                    mask |= np.uint32(1) << np.uint32(j)
                    if geom:
                        gsum += geometric_cost(geo, sdepth, j, x, y, z, gmax)
                        gcount += 1
            cost = total / k
            if geom and gcount > 0:
                cost += lam * gsum / gcount
            C[y, x] = cost
            Sel[y, x] = mask


@njit(cache=True, parallel=True)
def half_step_kernel(colour, maps, caches, Cpre, ref, sources, pattern, key, params, block, counts):
    """Update every pixel of one colour ((x + y) % 2 == colour) of ``maps`` (:class:`records.HypothesisMaps`)
    inside ``params``' box (:func:`box_bounds`) and the rows ``block`` (:class:`records.RowBlock`) in place:
    candidates from the sampling pattern, multi-hypothesis view selection, refinement (Xu & Tao 2019 ACMM, with the
    DeepC pattern and perturbation of Kuhn et al. 2020); add what it evaluated to ``counts`` (H, N_COUNTS) i64
    (columns CNT_*).

    ``caches`` (:class:`records.CostCaches`): ``view_costs`` caches m_j of each pixel's stored hypothesis
    (filled by ``init_cost_kernel``): a pixel whose hypothesis survives a half-step keeps its costs, so the
    current hypothesis is only evaluated on views not seen before. A replaced hypothesis clears them and
    stamps the pixel with the half-step (``caches.clock``, counted by the caller before the half-step's first
    block: ``caches.versions``). With
    ``caches.rows`` the candidates of each pixel's previous update and their cost rows are kept, with the
    half-step that wrote them (row_count = 0 at the start of a pass): a candidate proposed again by the same
    sample of a neighbour unchanged since (stamped earlier) is bit-identical, so are its costs (which are
    float32 values). One stamp per pixel instead of the neighbour's version per candidate: 60 B/px less
    with K = 16. A hypothesis is replaced only by one whose cost is lower by more than
    ``params.min_improvement``; in the detail restorer's passes also only by one more than
    ``params.detail_delta`` below ``Cpre`` (H, W) f32, the upsampled hypothesis's cost.
    Active set (``params.active_share`` >= 0): a pixel is updated only if its own last update or the last update
    of a pixel it reads (:func:`neighbourhood_changed`) moved a plane (:func:`moved_plane`; ``caches.changed``,
    written while ``params.track_changes``), or if its stream's draw ACTIVE_DRAW falls below the share; the others keep
    everything and are counted in CNT_SKIPPED. The draw and the map only depend on the pixel and the previous
    half-steps, so the maps do not depend on the thread count. A pixel reads only pixels of the other colour
    (samples, 4-neighbours), which no block of this half-step writes: the maps do not depend on the blocks either.
    ``ref``: :class:`records.ReferenceWindows`, ``sources``: :class:`records.SourceImages`, ``pattern``:
    :class:`records.SamplingPattern`, ``key``: the half-step's random stream (``rng.stream_key``),
    ``params``: :class:`records.KernelParams`."""
    # the records' fields as locals: the loops below read exactly what they read as separate arguments
    Z, Nrm, C, Sel = maps.depth, maps.normal, maps.cost, maps.selected_views
    P, VER, rows = caches.view_costs, caches.versions, caches.rows
    RS, RT, RC, RN = caches.row_samples, caches.row_stamps, caches.row_costs, caches.row_count
    kinv, img, offs, sig, mode = ref.kinv, ref.image, ref.offsets, ref.sigmas, ref.weighting
    mu_a, var_a = ref.mean, ref.variance
    ox, oy, wset, ns = ref.offset_x, ref.offset_y, ref.window_set, ref.n_samples
    src, stride, plane, geo, sdepth = sources.pixels, sources.stride, sources.plane, sources.geometry, sources.depth
    pat, region = pattern.offsets, pattern.regions
    h, w = Z.shape
    n_views = geo.shape[0]
    zmin = params.zmin
    zmax = params.zmax
    eps = params.perturbation
    lam = params.geom_lambda
    gmax = params.geom_max
    min_var = params.min_var
    k_vs = params.k_viewsel
    k_up = params.k_update
    plane_prop = params.plane_propagation
    geom = params.geometric
    detail = params.detail_restorer
    all8 = params.all8
    retries = params.normal_retries
    top_k = params.top_k
    n_regions = params.n_regions
    mc = params.mc_samples
    min_improvement = params.min_improvement
    CH = caches.changed
    # this half-step's stamp (counted by the caller; the clock is reset with the caches at the start of a pass)
    now = caches.clock[0]
    share = params.active_share
    active = share >= 0.0
    track = params.track_changes
    x_lo, y_lo, x_hi, y_hi = box_bounds(params, h, w)
    for y in prange(max(y_lo, block.start), min(y_hi, block.stop)):  # the box's rows within the block
        reg_cost = np.empty(n_regions, np.float32)
        reg_idx = np.empty(n_regions, np.int64)
        reg_ord = np.empty(n_regions, np.int64)
        cand_z = np.empty(k_up, np.float64)
        cand_n = np.empty((k_up, 3), np.float64)
        cand_c = np.empty(k_up, np.float32)
        cand_s = np.empty(k_up, np.int64)
        R = np.empty((k_up, n_views), np.float64)
        M = R[:k_vs]
        hrow = np.empty((1, n_views), np.float64)
        omega = np.empty(n_views, np.float64)
        v = np.empty(n_views, np.float64)
        tmp = np.empty(n_views, np.float64)
        terms = np.empty(n_views, np.float64)
        order = np.empty(n_views, np.int64)
        hz = np.empty(8, np.float64)
        hn = np.empty((8, 3), np.float64)
        win, sidx = ncc_work(ox.shape[1])
        n_rows = n_cur = n_rem = n_ref = n_px = n_skip = 0
        a, b = row_span(params, y, x_lo, x_hi)
        for x in range(a + (a + y + colour) % 2, b, 2):  # (x + y) % 2 == colour
            pk = combine(key, y * w + x)
            if track:
                # active set: a pixel whose own last update and whose neighbours' last updates changed nothing
                # would see the same candidates as in its previous update, which kept its hypothesis; only a
                # random share of them is updated (for the refinement's fresh perturbations)
                if (active and CH[y, x] == 0 and not (uniform(pk, ACTIVE_DRAW) < share)
                        and not neighbourhood_changed(CH, pat, x, y)):
                    n_skip += 1
                    continue  # hypothesis, cost, selected views and caches stay; CH[y, x] stays 0
                CH[y, x] = 0
            n_px += 1
            rp = ray(kinv, x, y)
            n = load_window(win, img, offs, sig, mode, ox, oy, wset, ns, x, y)
            mu = mu_a[y, x]
            var = var_a[y, x]
            n_cand = gather_candidates(x, y, Z, Nrm, C, pat, region, n_regions, kinv, zmin, zmax, plane_prop, k_up,
                                       reg_cost, reg_idx, reg_ord, cand_z, cand_n, cand_c, cand_s)
            n_vs = min(n_cand, k_vs)
            n_old = RN[y, x] if rows else 0
            # cost rows of the candidates: what the previous update of this pixel evaluated, if the same
            # sample's pixel has not changed since (R[k, j] NaN = unknown)
            cached_rows(R, cand_s, n_cand, n_old, x, y, pat, VER, RS, RT, RC)
            # photometric cost matrix of the best candidates over all views (drives view selection)
            for k in range(n_vs):
                missing = False
                for j in range(n_views):
                    if math.isnan(R[k, j]):
                        missing = True
                if not missing:
                    continue
                m0, m1, m2, ok = plane_vector(kinv, rp, cand_z[k], cand_n[k, 0], cand_n[k, 1], cand_n[k, 2])
                for j in range(n_views):
                    if not math.isnan(R[k, j]):
                        continue
                    if ok:
                        n_rows += 1
                        R[k, j] = photometric_cost(src, stride, plane, geo, j, win, n, mu, var, x, y, m0, m1, m2,
                                                   min_var, sidx)
                    else:
                        R[k, j] = 2.0
            vsum = view_weights(M, n_vs, n_views, Sel, x, y, params.tau_good, params.tau_bad, params.beta,
                                params.beta_fallback, params.n_good, params.n_bad, params.prior_in, params.prior_out,
                                params.deterministic, mc, pk, 0, omega, v)
            z0 = np.float64(Z[y, x])
            n0x = np.float64(Nrm[y, x, 0])
            n0y = np.float64(Nrm[y, x, 1])
            n0z = np.float64(Nrm[y, x, 2])
            n_cur -= n_known_px(P, y, x)
            if vsum <= 0.0:
                # degenerate weights: the top_k views with the lowest cost of the current hypothesis
                m0, m1, m2, ok = plane_vector(kinv, rp, z0, n0x, n0y, n0z)
                for j in range(n_views):
                    if ok:
                        if math.isnan(P[y, x, j]):
                            P[y, x, j] = photometric_cost(src, stride, plane, geo, j, win, n, mu, var, x, y, m0, m1,
                                                          m2, min_var, sidx)
                        tmp[j] = P[y, x, j]
                    else:
                        tmp[j] = 2.0
                    omega[j] = tmp[j]
                tmp.sort()
                kth = tmp[min(top_k, n_views) - 1]
                vsum = 0.0
                for j in range(n_views):
                    if omega[j] <= kth and vsum < top_k:
                        v[j] = 1.0
                        vsum += 1.0
                    else:
                        v[j] = 0.0
            # current hypothesis, full cost (the baseline all others must beat)
            c_cur = current_cost(src, stride, plane, geo, sdepth, kinv, win, n, mu, var, x, y, rp, z0, n0x, n0y, n0z,
                                 v, vsum, geom, lam, gmax, min_var, P, sidx)
            n_cur += n_known_px(P, y, x)
            n_sel = view_order(v, order)
            if c_cur >= BIG:
                c_cur = 2.0 + (lam * gmax if geom else 0.0)
            c_old = c_cur
            # a replacement must lower the cost by more than min_improvement (0 = any lower cost): below ``bar``
            bar = c_cur - min_improvement
            best = bar
            zb = z0
            nbx = n0x
            nby = n0y
            nbz = n0z
            won = False
            # candidates with a full cost row: aggregate from M
            for k in range(n_vs):
                if geom:
                    # lower bound: all photometric terms, then the geometric ones view by view
                    bound = 0.0
                    for j in range(n_views):
                        if v[j] > 0.0:
                            bound += v[j] * M[k, j]
                    losing = bound * (1.0 - EXIT_MARGIN) >= best * vsum
                    for i in range(n_sel):
                        if losing:
                            break
                        j = order[i]
                        terms[j] = lam * geometric_cost(geo, sdepth, j, x, y, cand_z[k], gmax)
                        bound += v[j] * terms[j]
                        losing = bound * (1.0 - EXIT_MARGIN) >= best * vsum
                    if losing:
                        continue
                acc = 0.0
                for j in range(n_views):
                    if v[j] > 0.0:
                        cost = M[k, j]
                        if geom:
                            cost += terms[j]
                        acc += v[j] * cost
                cost = acc / vsum
                if cost < best:
                    best = cost
                    zb = cand_z[k]
                    nbx = cand_n[k, 0]
                    nby = cand_n[k, 1]
                    nbz = cand_n[k, 2]
                    won = True
            # remaining candidates: only the selected views, early exit
            for k in range(n_vs, n_cand):
                n_rem -= n_known(R, k)
                cost = aggregated_cost(src, stride, plane, geo, sdepth, kinv, win, n, mu, var, x, y, rp, cand_z[k],
                                       cand_n[k, 0], cand_n[k, 1], cand_n[k, 2], v, vsum, order, n_sel, terms, geom,
                                       lam, gmax, min_var, best, R, k, sidx)
                n_rem += n_known(R, k)
                if cost < best:
                    best = cost
                    zb = cand_z[k]
                    nbx = cand_n[k, 0]
                    nby = cand_n[k, 1]
                    nbz = cand_n[k, 2]
                    won = True
            if rows:
                for k in range(n_cand):
                    RS[y, x, k] = cand_s[k]
                    for j in range(n_views):
                        RC[y, x, k, j] = R[k, j]  # float32 values (or NaN): exact
                RN[y, x] = n_cand
                RT[y, x] = now
            # local refinement: combinations of current, perturbed and random depth / normal
            n_h = refinement_hypotheses(pk, rp, zb, nbx, nby, nbz, zmin, zmax, eps, retries, all8, hz, hn)
            for i in range(n_h):
                zi = hz[i]
                if not (zi >= zmin and zi <= zmax):
                    continue
                for j in range(n_views):
                    hrow[0, j] = np.nan
                cost = aggregated_cost(src, stride, plane, geo, sdepth, kinv, win, n, mu, var, x, y, rp, zi, hn[i, 0],
                                       hn[i, 1], hn[i, 2], v, vsum, order, n_sel, terms, geom, lam, gmax, min_var, best,
                                       hrow, 0, sidx)
                n_ref += n_known(hrow, 0)
                if cost < best:
                    best = cost
                    zb = zi
                    nbx = hn[i, 0]
                    nby = hn[i, 1]
                    nbz = hn[i, 2]
            if not (best < bar):
                C[y, x] = c_old  # nothing won: same hypothesis, same cost; its caches stay valid
                continue
            if detail and not (best < Cpre[y, x] - params.detail_delta):
                C[y, x] = c_old  # detail restorer: keep the upsampled hypothesis
                continue
            Z[y, x] = zb
            Nrm[y, x, 0] = nbx
            Nrm[y, x, 1] = nby
            Nrm[y, x, 2] = nbz
            C[y, x] = best
            # the caches hold costs of the stored float32 hypothesis: only a change of that invalidates them
            if not (Z[y, x] == z0 and Nrm[y, x, 0] == n0x and Nrm[y, x, 1] == n0y and Nrm[y, x, 2] == n0z):
                for j in range(n_views):
                    P[y, x, j] = np.nan
                VER[y, x] = now
                if track and moved_plane(Z[y, x], Nrm[y, x, 0], Nrm[y, x, 1], Nrm[y, x, 2], z0, n0x, n0y, n0z,
                                         params.change_depth):
                    CH[y, x] = 1
            if won:
                mask = np.uint32(0)
                for j in range(n_views):
                    if v[j] > 0.0:
                        mask |= np.uint32(1) << np.uint32(j)
                Sel[y, x] = mask
        counts[y, CNT_ROWS] += n_rows
        counts[y, CNT_CURRENT] += n_cur
        counts[y, CNT_REMAINING] += n_rem
        counts[y, CNT_REFINE] += n_ref
        counts[y, CNT_PIXELS] += n_px
        counts[y, CNT_SKIPPED] += n_skip
