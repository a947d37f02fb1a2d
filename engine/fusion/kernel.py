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



@numba.njit(cache=True, nogil=True)
def sanitize_depth(dep: np.ndarray) -> int:
    """Zero every depth that is not > 0 (NaN, negative) in place; returns how many stay valid."""
    n_valid = 0
    for i in range(dep.shape[0]):
        if dep[i] > 0.0:
            n_valid += 1
        else:
            dep[i] = 0.0
    return n_valid


# The traversal's scalars between calls of the kernel (``FusionState.si`` and ``.sf``).
IMG, P0, PHASE, IN_SEED, SP, N, N_VIS, CONF_N, SEED_ID, N_OUT, TICK = range(11)
CONF_SUM, RNX, RNY, RNZ = range(4)
NEED_ROOM = -2  # the kernel's answer when the output arrays are full
ST_IMG, FUSED = 2, 17  # the stack's views and the per-view fused flags in work_arrays()


@numba.njit(cache=True, nogil=True, error_model="numpy")
def fuse_kernel(maps, geometry, work, out, max_reproj_sq, max_depth_err, min_cos, min_px, max_px, max_trav,
                 per_pixel, has_conf):
    """COLMAP's traversal with two equivalent reorganisations for speed (memory traffic dominates):

    - ``dep`` is a private copy of the depths whose sign marks consumed pixels (d < 0), so one read answers
      "valid and not consumed" (consumption is permanent and depths never change sign otherwise);
    - the depth and reprojection checks against the seed depend only on (seed, pixel), so they are
      done before pushing, using the seed's projection into every view computed once per seed;
      a failing pixel would have been rejected at pop time without side effects. The consumed
      test and the normal check stay at pop time, so the accepted sequence is COLMAP's.

    Views live in slots: view k's pixel p is at ``base[k] + p`` of the map arrays, ``base[k] < 0`` when k is not
    resident (``engine.fusion.cached``; with every view packed in memory all are). A push into a non-resident
    view skips the depth checks and marks the entry (``st_chk`` 0): they are done when it is popped, which
    rejects the same pixels (a pixel's |depth| and the seed's projection do not change while the seed's stack
    lives, a consumed pixel stays consumed). A pop from a non-resident view puts the entry back, stores the
    traversal in ``work`` and returns that view; called again once it is resident, the kernel goes on where it
    stopped. The points go into ``out`` from ``si[N_OUT]`` on; when a cluster does not fit, the kernel returns
    ``NEED_ROOM`` with the cluster pending (the caller takes the points and resets ``si[N_OUT]``). Returns -1 when
    done, the view it needs, or ``NEED_ROOM``.
    """
    dep, nrm, rgb, conf, base, used = maps
    widths, heights, P, Kinv, Rt, tvec, ov_ptr, ov_idx = geometry
    (si, sf, st_img, st_pix, st_lvl, st_chk, cluster, scratch, seed_u, seed_v, seed_w, act_ptr, act_idx, pov,
     pw, pc, pr, fused, stamp) = work
    out_xyz, out_nrm, out_rgb, out_nv, out_np, out_conf, out_src = out
    n_views = len(widths)
    img = si[IMG]
    p0 = si[P0]
    phase = si[PHASE]  # 0: the seed view's overlap lists are not built yet
    in_seed = si[IN_SEED] != 0
    sp = si[SP]
    n = si[N]
    n_vis = si[N_VIS]
    conf_n = si[CONF_N]
    seed_id = si[SEED_ID]
    n_out = si[N_OUT]
    tick = si[TICK]
    conf_sum = sf[CONF_SUM]
    rnx = sf[RNX]
    rny = sf[RNY]
    rnz = sf[RNZ]
    need = -1

    while img >= 0:
        if phase == 0:
            if base[img] < 0:
                need = img
                break
            # The overlap lists without the views already fused (those only change between seed views), with
            # P of each entry as one row per matrix element (12, len(ov_idx)), and per-entry projections
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
            p0 = 0
            phase = 1
        n_px = widths[img] * heights[img]
        while p0 < n_px:
            if not in_seed:
                if base[img] < 0:
                    need = img
                    break
                if dep[base[img] + p0] <= 0.0:
                    p0 += 1
                    continue
                # ---- Fuse(seed) ----
                in_seed = True
                seed_id += 1
                sp = 1
                st_img[0] = img
                st_pix[0] = p0
                st_lvl[0] = 0
                st_chk[0] = 1
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
                bk = base[k]
                if bk < 0:
                    sp += 1  # popped again once view k is loaded
                    need = k
                    break
                used[k] = tick  # the least recently used view is evicted first (engine.fusion.cached)
                tick += 1
                rel = st_pix[sp]
                pidx = bk + rel
                lvl = st_lvl[sp]
                d = dep[pidx]
                if d <= 0.0:
                    continue  # consumed meanwhile (or invalid)
                if st_chk[sp] == 0 and abs((seed_w[k] - d) / d) > max_depth_err:
                    continue  # the push-time depth check of a view that was not resident then
                n0 = nrm[pidx, 0]
                n1 = nrm[pidx, 1]
                n2 = nrm[pidx, 2]
                wnx = Rt[k, 0, 0] * n0 + Rt[k, 0, 1] * n1 + Rt[k, 0, 2] * n2
                wny = Rt[k, 1, 0] * n0 + Rt[k, 1, 1] * n1 + Rt[k, 1, 2] * n2
                wnz = Rt[k, 2, 0] * n0 + Rt[k, 2, 1] * n1 + Rt[k, 2, 2] * n2
                if lvl > 0 and rnx * wnx + rny * wny + rnz * wnz < min_cos:
                    continue
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
                    sp = 0  # the rest of the stack is dropped
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
                    q = nr * widths[j] + nc
                    bj = base[j]
                    if bj >= 0:
                        dq = dep[bj + q]
                        if dq <= 0.0:
                            continue  # invalid or consumed: it would be skipped at pop time
                        if abs((seed_w[j] - dq) / dq) > max_depth_err:
                            continue
                        st_chk[sp] = 1
                    else:
                        st_chk[sp] = 0
                    st_img[sp] = j
                    st_pix[sp] = q
                    st_lvl[sp] = lvl + 1
                    sp += 1
            if need >= 0:
                break
            if n >= min_px and n > 0 and n_out + (n if per_pixel else 1) > out_xyz.shape[0]:
                need = NEED_ROOM  # the seed stays pending: emitted when called again with room
                break
            in_seed = False
            p0 += 1
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
        if need != -1:
            break
        fused[img] = True
        phase = 0
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
    si[IMG] = img
    si[P0] = p0
    si[PHASE] = phase
    si[IN_SEED] = 1 if in_seed else 0
    si[SP] = sp
    si[N] = n
    si[N_VIS] = n_vis
    si[CONF_N] = conf_n
    si[SEED_ID] = seed_id
    si[N_OUT] = n_out
    si[TICK] = tick
    sf[CONF_SUM] = conf_sum
    sf[RNX] = rnx
    sf[RNY] = rny
    sf[RNZ] = rnz
    return need



def reprojection_limit_sq(options: FusionOptions) -> float:
    # Pixels of the seed's own view lie at exactly integer distances from the seed's projection, so
    # with a 1 px limit the accept/reject decision of its 4-neighbours would hinge on rounding noise.
    # A relative margin far above float64 noise makes "error <= limit" hold exactly as written.
    return options.max_reproj_error ** 2 * (1.0 + 1e-9) + 1e-12



def work_arrays(n_views: int, ov_ptr: np.ndarray, max_px: int) -> tuple:
    """The traversal's state that lives across calls of the kernel: its scalars (``si``, ``sf``), the stack,
    the cluster, the seed's projections, the overlap lists without fused views, and per view whether it is
    fused and the last seed it joined. Small: O(views + max_num_pixels x longest overlap list)."""
    max_ov = int(np.max(np.diff(ov_ptr), initial=0))
    n_ov = max(int(ov_ptr[-1]), 1)
    stack_cap = 1 + max_px * max(max_ov, 1)
    si = np.zeros(11, np.int64)
    return (si, np.zeros(4, np.float64), np.empty(stack_cap, np.int32), np.empty(stack_cap, np.int64),
            np.empty(stack_cap, np.int32), np.empty(stack_cap, np.uint8),
            # fused pixels of the current cluster, one row per attribute: x, y, z, normal x, y, z, r, g, b, view
            np.empty((10, max_px), np.float64), np.empty(max_px, np.float64),
            np.empty(n_views, np.float64), np.empty(n_views, np.float64), np.empty(n_views, np.float64),
            np.zeros(n_views + 1, np.int64), np.empty(n_ov, np.int64), np.empty((12, n_ov), np.float64),
            np.empty(max(max_ov, 1), np.float64), np.empty(max(max_ov, 1), np.float64),
            np.empty(max(max_ov, 1), np.float64), np.zeros(n_views, np.bool_), np.full(n_views, -1, np.int64))


def output_arrays(cap: int) -> tuple:
    """Room for ``cap`` points."""
    return (np.empty((cap, 3), np.float64), np.empty((cap, 3), np.float32), np.empty((cap, 3), np.uint8),
            np.empty(cap, np.int32), np.empty(cap, np.int32), np.empty(cap, np.float32), np.empty(cap, np.int32))


def kernel_options(options: FusionOptions) -> tuple:
    """The kernel's thresholds from ``options`` (validated)."""
    return (reprojection_limit_sq(options), options.max_depth_error, math.cos(math.radians(options.max_normal_error)),
            int(options.min_num_pixels), int(options.max_num_pixels), int(options.max_traversal_depth),
            bool(options.point_per_pixel))


def cloud_of(chunks: list[tuple]) -> FusedCloud:
    """The cloud of the kernel's output chunks in order, each (output arrays, points in them); an attribute's chunks
    are released as soon as that attribute is joined (peak: the cloud and one attribute's chunks).

    One chunk is shrunk to its points in place (``ndarray.resize``: a realloc, no copy): :func:`fuse` makes it room
    for every valid pixel, and copying a cloud of millions of points into fresh pages costs the tuning viewer a
    noticeable share of each recomputation. The chunk's arrays must be this call's alone."""
    if len(chunks) == 1 and all(a.flags.owndata and a.flags.c_contiguous for a in chunks[0][0]):
        out, n = chunks.pop()
        for a in out:
            a.resize((n, *a.shape[1:]), refcheck=False)  # (nothing else refers to them: see the docstring)
        xyz, nrm, rgb, nv, npx, conf, src = out
        return FusedCloud(xyz, nrm, rgb, nv, conf, src, npx)
    parts = [[a[:n] for a in out] for out, n in chunks]
    chunks.clear()
    fields = []
    for f in range(7):
        fields.append(np.concatenate([p[f] for p in parts]))
        for p in parts:
            p[f] = None
    xyz, nrm, rgb, nv, npx, conf, src = fields
    return FusedCloud(xyz, nrm, rgb, nv, conf, src, npx)


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
    dep, nrm, rgb, conf, offsets, widths, heights, P, Kinv, Rt, tvec, ov_ptr, ov_idx = pack_views(list(views), options)
    n_valid = sanitize_depth(dep)  # NaN / negative -> invalid
    min_px, max_px, per_pixel = options.min_num_pixels, options.max_num_pixels, options.point_per_pixel
    # every view resident: view k's pixels start at offsets[k]
    maps = (dep, nrm, rgb, conf, offsets[:-1].copy(), np.zeros(len(views), np.int64))
    work = work_arrays(len(views), ov_ptr, int(max_px))
    out = output_arrays(n_valid + 1 if per_pixel else n_valid // max(min_px, 1) + 1)  # room for every point
    need = fuse_kernel(maps, (widths, heights, P, Kinv, Rt, tvec, ov_ptr, ov_idx), work, out,
                        *kernel_options(options), conf.shape[0] == dep.shape[0])
    assert need == -1, "a view packed in memory was reported missing"
    return cloud_of([(out, int(work[0][N_OUT]))])
