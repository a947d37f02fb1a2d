"""Depth-map fusion into one point cloud, as COLMAP's StereoFusion (Schönberger et al., ECCV 2016, §5).

Algorithm (COLMAP ``src/colmap/mvs/fusion.cc``), run sequentially so that the output is
deterministic:

1. Views are visited starting at view 0; the next view is the first one in the current view's
   overlap list that is not fused yet, else the lowest-index unfused view.
2. Every not-yet-consumed pixel of the current view (row-major) seeds a traversal: a LIFO stack
   of (view, row, col, level). A popped pixel with depth > 0 that is not consumed is accepted if
   (level 0) it is the seed, or (level > 0) the SEED point projects into its view with relative
   depth error <= ``max_depth_error``, reprojection error <= ``max_reproj_error`` px, and its
   world normal is within ``max_normal_error`` degrees of the seed normal. An accepted pixel is
   consumed, and (below ``max_traversal_depth``) its 3-D point is projected into every overlapping
   view that is not fused yet; the nearest pixel there is pushed.
3. When the stack is empty (or ``max_num_pixels`` were accepted) and at least ``min_num_pixels``
   pixels were accepted, one point is emitted: component-wise medians of position, normal
   (renormalised) and colour. Pixels consumed by a seed that emits nothing stay consumed.
   With ``point_per_pixel`` (not COLMAP's), the same clusters are kept but every accepted pixel is
   emitted as its own point (its own position, normal and colour) instead of their median.

Pixel convention: pixel (row, col) is un-projected at (col, row) through the index-space
intrinsics ``Camera.K_idx``. COLMAP plugs (col, row) into its continuous K, so a
COLMAP workspace whose cameras carry K_idx reproduces our geometry exactly."""

from __future__ import annotations

import math

import numba
import numpy as np

from engine.fusion.cloud import FusedCloud, FusionView
from engine.fusion.options import FusionOptions
from engine.fusion.packing import pack_views


@numba.njit(cache=True, inline="always")
def round_half_away(x: float) -> int:
    # std::round: halves away from zero.
    if x >= 0.0:
        return int(math.floor(x + 0.5))
    return -int(math.floor(-x + 0.5))



@numba.njit(cache=True, nogil=True)
def median_inplace(buf: np.ndarray, n: int, scratch: np.ndarray) -> float:
    """Median of buf[:n] (mean of the two middle values for even n), as COLMAP's Median().

    For n <= 32 (all clusters but a few of the largest) without sorting: the sorted position of buf[i]
    is its rank, the number of values below it plus the equal ones before it. Ranks are distinct, so
    the values of rank n // 2 (and n // 2 - 1) are the middle of the sorted sequence. The double loop
    has no data-dependent branch, which beats an insertion sort of the typical 3-20 values (it spent
    a quarter of the fusion time mispredicting)."""
    mid = n // 2
    if n <= 32:
        lo = 0.0
        hi = 0.0
        for i in range(n):
            v = buf[i]
            r = 0
            for j in range(n):
                r += (buf[j] < v) | ((buf[j] == v) & (j < i))
            if r == mid:
                hi = v
            elif r == mid - 1:
                lo = v
        if n % 2 == 1:
            return hi
        return 0.5 * hi + 0.5 * lo
    for i in range(n):
        scratch[i] = buf[i]
    s = np.sort(scratch[:n])
    if n % 2 == 1:
        return s[mid]
    return 0.5 * s[mid] + 0.5 * s[mid - 1]



@numba.njit(cache=True, nogil=True, inline="always")
def _backproject(Kinv, Rt, tvec, k, row, col, d):
    # X = R^T (d K^-1 [col, row, 1] - t)
    cx_ = d * (Kinv[k, 0, 0] * col + Kinv[k, 0, 1] * row + Kinv[k, 0, 2]) - tvec[k, 0]
    cy_ = d * (Kinv[k, 1, 0] * col + Kinv[k, 1, 1] * row + Kinv[k, 1, 2]) - tvec[k, 1]
    cz_ = d * (Kinv[k, 2, 0] * col + Kinv[k, 2, 1] * row + Kinv[k, 2, 2]) - tvec[k, 2]
    x = Rt[k, 0, 0] * cx_ + Rt[k, 0, 1] * cy_ + Rt[k, 0, 2] * cz_
    y = Rt[k, 1, 0] * cx_ + Rt[k, 1, 1] * cy_ + Rt[k, 1, 2] * cz_
    z = Rt[k, 2, 0] * cx_ + Rt[k, 2, 1] * cy_ + Rt[k, 2, 2] * cz_
    return x, y, z



@numba.njit(cache=True, nogil=True, error_model="numpy")
def _fuse_kernel(dep, nrm, rgb, conf, offsets, widths, heights, P, Kinv, Rt, tvec, ov_ptr, ov_idx,
                 max_reproj_sq, max_depth_err, min_cos, min_px, max_px, max_trav, per_pixel):
    """COLMAP's traversal with two equivalent reorganisations for speed (memory traffic dominates):

    - ``dep`` is a private copy of the depths whose sign marks consumed pixels (d < 0), so one read answers
      "valid and not consumed" (consumption is permanent and depths never change sign otherwise);
    - the depth and reprojection checks against the seed depend only on (seed, pixel), so they are
      done before pushing, using the seed's projection into every view computed once per seed;
      a failing pixel would have been rejected at pop time without side effects. The consumed
      test and the normal check stay at pop time, so the accepted sequence is COLMAP's.
    """
    n_views = len(widths)
    total = dep.shape[0]
    n_valid = 0
    for i in range(total):
        if dep[i] > 0.0:
            n_valid += 1
        else:
            dep[i] = 0.0  # NaN / negative -> invalid
    cap = n_valid + 1 if per_pixel else n_valid // max(min_px, 1) + 1
    out_xyz = np.empty((cap, 3), np.float64)
    out_nrm = np.empty((cap, 3), np.float32)
    out_rgb = np.empty((cap, 3), np.uint8)
    out_nv = np.empty(cap, np.int32)
    out_np = np.empty(cap, np.int32)
    out_conf = np.empty(cap, np.float32)
    out_src = np.empty(cap, np.int32)
    n_out = 0

    max_ov = 0
    for i in range(n_views):
        max_ov = max(max_ov, ov_ptr[i + 1] - ov_ptr[i])
    stack_cap = 1 + max_px * max(max_ov, 1)
    st_img = np.empty(stack_cap, np.int32)
    st_pix = np.empty(stack_cap, np.int64)
    st_lvl = np.empty(stack_cap, np.int32)

    # fused pixels of the current cluster, one row per attribute: x, y, z, normal x, y, z, r, g, b, view
    cluster = np.empty((10, max_px), np.float64)
    scratch = np.empty(max_px, np.float64)
    seed_u = np.empty(n_views, np.float64)  # the seed point projected into every view
    seed_v = np.empty(n_views, np.float64)
    seed_w = np.empty(n_views, np.float64)
    # The overlap lists without the views already fused (those only change between seed views), with
    # P of each entry as one row per matrix element (12, len(ov_idx)), and per-entry projections
    act_ptr = np.zeros(n_views + 1, np.int64)
    act_idx = np.empty(max(ov_idx.shape[0], 1), np.int64)
    pov = np.empty((12, max(ov_idx.shape[0], 1)), np.float64)
    pw = np.empty(max(max_ov, 1), np.float64)
    pc = np.empty(max(max_ov, 1), np.float64)
    pr = np.empty(max(max_ov, 1), np.float64)

    has_conf = conf.shape[0] == total  # else no view has confidence (see _pack): no read per fused pixel
    fused = np.zeros(n_views, np.bool_)
    stamp = np.full(n_views, -1, np.int64)
    seed_id = 0

    img = 0
    while img >= 0:
        m = 0
        for k in range(n_views):
            act_ptr[k] = m
            for oi in range(ov_ptr[k], ov_ptr[k + 1]):
                j = ov_idx[oi]
                if not fused[j]:
                    act_idx[m] = j
                    for r in range(3):
                        for cc in range(4):
                            pov[4 * r + cc, m] = P[j, r, cc]
                    m += 1
        act_ptr[n_views] = m
        W = widths[img]
        H = heights[img]
        base = offsets[img]
        for p0 in range(base, base + W * H):
            if dep[p0] <= 0.0:
                continue
            # ---- Fuse(seed) ----
            seed_id += 1
            sp = 1
            st_img[0] = img
            st_pix[0] = p0
            st_lvl[0] = 0
            n = 0
            n_vis = 0
            conf_sum = 0.0
            conf_n = 0
            rnx = 0.0
            rny = 0.0
            rnz = 0.0
            while sp > 0:
                sp -= 1
                k = st_img[sp]
                pidx = st_pix[sp]
                lvl = st_lvl[sp]
                d = dep[pidx]
                if d <= 0.0:
                    continue  # consumed meanwhile (or invalid)
                n0 = nrm[pidx, 0]
                n1 = nrm[pidx, 1]
                n2 = nrm[pidx, 2]
                wnx = Rt[k, 0, 0] * n0 + Rt[k, 0, 1] * n1 + Rt[k, 0, 2] * n2
                wny = Rt[k, 1, 0] * n0 + Rt[k, 1, 1] * n1 + Rt[k, 1, 2] * n2
                wnz = Rt[k, 2, 0] * n0 + Rt[k, 2, 1] * n1 + Rt[k, 2, 2] * n2
                if lvl > 0 and rnx * wnx + rny * wny + rnz * wnz < min_cos:
                    continue
                rel = pidx - offsets[k]
                row = rel // widths[k]
                col = rel - row * widths[k]
                x, y, z = _backproject(Kinv, Rt, tvec, k, row, col, d)
                dep[pidx] = -d  # consumed
                cluster[0, n] = x
                cluster[1, n] = y
                cluster[2, n] = z
                cluster[3, n] = wnx
                cluster[4, n] = wny
                cluster[5, n] = wnz
                cluster[6, n] = rgb[pidx, 0]
                cluster[7, n] = rgb[pidx, 1]
                cluster[8, n] = rgb[pidx, 2]
                cluster[9, n] = k
                if has_conf:
                    c = conf[pidx]
                    if not math.isnan(c):
                        conf_sum += c
                        conf_n += 1
                if stamp[k] != seed_id:
                    stamp[k] = seed_id
                    n_vis += 1
                if lvl == 0:
                    rnx = wnx
                    rny = wny
                    rnz = wnz
                    for j in range(n_views):
                        if fused[j]:
                            continue  # never pushed to
                        sw = P[j, 2, 0] * x + P[j, 2, 1] * y + P[j, 2, 2] * z + P[j, 2, 3]
                        seed_u[j] = (P[j, 0, 0] * x + P[j, 0, 1] * y + P[j, 0, 2] * z + P[j, 0, 3]) / sw
                        seed_v[j] = (P[j, 1, 0] * x + P[j, 1, 1] * y + P[j, 1, 2] * z + P[j, 1, 3]) / sw
                        seed_w[j] = sw
                n += 1
                if n >= max_px:
                    break
                if lvl >= max_trav - 1:
                    continue
                o0 = act_ptr[k]
                m_ov = act_ptr[k + 1] - o0
                # Project into every overlapping view first: a branch-free loop over contiguous rows of
                # ``pov`` (SIMD); the checks below then read the results.
                for t in range(m_ov):
                    oi = o0 + t
                    qw = pov[8, oi] * x + pov[9, oi] * y + pov[10, oi] * z + pov[11, oi]
                    iw = 1.0 / qw
                    pw[t] = qw
                    pc[t] = (pov[0, oi] * x + pov[1, oi] * y + pov[2, oi] * z + pov[3, oi]) * iw
                    pr[t] = (pov[4, oi] * x + pov[5, oi] * y + pov[6, oi] * z + pov[7, oi]) * iw
                for t in range(m_ov):
                    j = act_idx[o0 + t]
                    if pw[t] <= 0.0:
                        continue  # behind view j: its depth check would reject it anyway
                    fc = pc[t]
                    fr = pr[t]
                    if not (fc > -1.0 and fr > -1.0 and fc < widths[j] and fr < heights[j]):
                        continue
                    nc = round_half_away(fc)
                    nr = round_half_away(fr)
                    if nc < 0 or nr < 0 or nc >= widths[j] or nr >= heights[j]:
                        continue
                    # Checks against the seed point (COLMAP does them at pop time; same outcome). The
                    # reprojection check needs no memory read, so it goes before the depth lookup.
                    du = seed_u[j] - nc
                    dv = seed_v[j] - nr
                    if du * du + dv * dv > max_reproj_sq:
                        continue
                    q = offsets[j] + nr * widths[j] + nc
                    dq = dep[q]
                    if dq <= 0.0:
                        continue  # invalid or consumed: it would be skipped at pop time
                    if abs((seed_w[j] - dq) / dq) > max_depth_err:
                        continue
                    st_img[sp] = j
                    st_pix[sp] = q
                    st_lvl[sp] = lvl + 1
                    sp += 1
            if n < min_px or n == 0:
                continue
            mnx = median_inplace(cluster[3], n, scratch)
            mny = median_inplace(cluster[4], n, scratch)
            mnz = median_inplace(cluster[5], n, scratch)
            norm = math.sqrt(mnx * mnx + mny * mny + mnz * mnz)
            if norm < 1.1920929e-07:  # FLT_EPSILON, as COLMAP
                continue
            mean_conf = conf_sum / conf_n if conf_n > 0 else np.nan
            if per_pixel:
                for q in range(n):
                    for a in range(3):
                        out_xyz[n_out, a] = cluster[a, q]
                        out_nrm[n_out, a] = cluster[3 + a, q]
                        out_rgb[n_out, a] = np.uint8(cluster[6 + a, q])
                    out_nv[n_out] = n_vis
                    out_np[n_out] = n
                    out_conf[n_out] = mean_conf
                    out_src[n_out] = np.int32(cluster[9, q])
                    n_out += 1
                continue
            out_xyz[n_out, 0] = median_inplace(cluster[0], n, scratch)
            out_xyz[n_out, 1] = median_inplace(cluster[1], n, scratch)
            out_xyz[n_out, 2] = median_inplace(cluster[2], n, scratch)
            out_nrm[n_out, 0] = mnx / norm
            out_nrm[n_out, 1] = mny / norm
            out_nrm[n_out, 2] = mnz / norm
            out_rgb[n_out, 0] = min(255, round_half_away(median_inplace(cluster[6], n, scratch)))
            out_rgb[n_out, 1] = min(255, round_half_away(median_inplace(cluster[7], n, scratch)))
            out_rgb[n_out, 2] = min(255, round_half_away(median_inplace(cluster[8], n, scratch)))
            out_nv[n_out] = n_vis
            out_np[n_out] = n
            out_conf[n_out] = mean_conf
            out_src[n_out] = img
            n_out += 1
        fused[img] = True
        # Next view: first unfused view in this view's overlap list, else the lowest unfused index.
        nxt = -1
        for oi in range(ov_ptr[img], ov_ptr[img + 1]):
            if not fused[ov_idx[oi]]:
                nxt = ov_idx[oi]
                break
        if nxt < 0:
            for j in range(n_views):
                if not fused[j]:
                    nxt = j
                    break
        img = nxt
    return (out_xyz[:n_out].copy(), out_nrm[:n_out].copy(), out_rgb[:n_out].copy(), out_nv[:n_out].copy(),
            out_conf[:n_out].copy(), out_src[:n_out].copy(), out_np[:n_out].copy())



def reprojection_limit_sq(options: FusionOptions) -> float:
    # Pixels of the seed's own view lie at exactly integer distances from the seed's projection, so
    # with a 1 px limit the accept/reject decision of its 4-neighbours would hinge on rounding noise.
    # A relative margin far above float64 noise makes "error <= limit" hold exactly as written.
    return options.max_reproj_error ** 2 * (1.0 + 1e-9) + 1e-12



def fuse(views: list[FusionView], options: FusionOptions | None = None) -> FusedCloud:
    """Fuse per-view depth/normal maps into one point cloud (Schönberger et al. 2016). Deterministic.

    Args:
        views: the views, each with its camera, maps and overlap list (indices into ``views``).
        options: thresholds; default ``FusionOptions()`` (DeepC high-res).
    Returns:
        The fused cloud (world frame), in emission order.
    """
    options = (options or FusionOptions()).validate()
    if not views:
        return FusedCloud.empty()
    packed = pack_views(list(views), options)
    xyz, nrm, rgb, nv, conf, src, npx = _fuse_kernel(
        *packed, reprojection_limit_sq(options), options.max_depth_error,
        math.cos(math.radians(options.max_normal_error)), int(options.min_num_pixels),
        int(options.max_num_pixels), int(options.max_traversal_depth), bool(options.point_per_pixel))
    return FusedCloud(xyz, nrm, rgb, nv, conf, src, npx)

