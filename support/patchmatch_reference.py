"""Slow plain-Python/numpy references of the numba kernels, written straight from the papers'
formulas (Xu & Tao 2019 ACMM; Kuhn et al. 2020 DeepC-MVS; Schönberger et al. 2016 COLMAP).

They share no code with the kernels (only the counter-based random numbers, which are part of the
specification of determinism), so the tests comparing the two check the kernels' formulas, indexing
and control flow. Use them on tiny inputs only.
"""

from __future__ import annotations

import math

import numpy as np

import engine.patchmatch.rng as rng
from engine.patchmatch.ncc import FINE_CREASE, FINE_EDGE

# ----------------------------------------------------------------------------- NCC (COLMAP)


def bilateral_weights_ref(img: np.ndarray, x: int, y: int, offsets: np.ndarray, weighting: str,
                          sigma_s: float, sigma_c: float) -> tuple[np.ndarray, np.ndarray]:
    """Normalised weights (S,) and reference values a_o (S,) at pixel (x, y) (border-clamped)."""
    h, w = img.shape
    a0 = float(img[y, x])
    a = np.array([img[min(max(y + dy, 0), h - 1), min(max(x + dx, 0), w - 1)] for dx, dy in offsets], np.float64)
    d2 = np.array([dx * dx + dy * dy for dx, dy in offsets], np.float64)
    if weighting == "colmap":
        wts = np.exp(-d2 / (2 * sigma_s**2) - (a - a0) ** 2 / (2 * sigma_c**2))
    else:
        wts = np.exp(-np.sqrt(d2) / (2 * sigma_s**2) - np.abs(a - a0) * 255.0 / (2 * sigma_c**2))
    return wts / wts.sum(), a


def bilinear_ref(img: np.ndarray, u: float, v: float) -> float:
    """Bilinear sample with border clamping (index-space coordinates: pixel centres at integers)."""
    h, w = img.shape
    u = min(max(u, 0.0), w - 1.0)
    v = min(max(v, 0.0), h - 1.0)
    x0, y0 = int(math.floor(u)), int(math.floor(v))
    x1, y1 = min(x0 + 1, w - 1), min(y0 + 1, h - 1)
    fu, fv = u - x0, v - y0
    top = img[y0, x0] * (1 - fu) + img[y0, x1] * fu
    bot = img[y1, x0] * (1 - fu) + img[y1, x1] * fu
    return float(top * (1 - fv) + bot * fv)


def ncc_cost_ref(ref_img: np.ndarray, src_img: np.ndarray, H: np.ndarray, x: int, y: int, offsets: np.ndarray,
                 weighting: str = "colmap", sigma_s: float = 5.0, sigma_c: float = 0.2,
                 min_var: float = 1e-5) -> float:
    """Bilateral weighted NCC cost in [0, 2] of homography H (3, 3) at reference pixel (x, y)."""
    sh, sw = src_img.shape
    c = H @ np.array([x, y, 1.0])
    if c[2] <= 0:
        return 2.0
    cu, cv = c[0] / c[2], c[1] / c[2]
    if not (0 <= cu <= sw - 1 and 0 <= cv <= sh - 1):
        return 2.0
    wts, a = bilateral_weights_ref(ref_img, x, y, offsets, weighting, sigma_s, sigma_c)
    b = np.empty(len(offsets))
    for k, (dx, dy) in enumerate(offsets):
        q = H @ np.array([x + dx, y + dy, 1.0])
        z = max(q[2], 1e-6)
        b[k] = bilinear_ref(src_img, q[0] / z, q[1] / z)
    mu_a, mu_b = (wts * a).sum(), (wts * b).sum()
    var_a = (wts * a * a).sum() - mu_a**2
    var_b = (wts * b * b).sum() - mu_b**2
    if var_a < min_var or var_b < min_var:
        return 2.0
    cov = (wts * a * b).sum() - mu_a * mu_b
    return float(min(max(1.0 - cov / math.sqrt(var_a * var_b), 0.0), 2.0))


def window_choice_ref(img: np.ndarray, x: int, y: int, options, allowed: int = FINE_EDGE
                      ) -> tuple[np.ndarray, float, float]:
    """Offsets (S, 2), spatial and colour sigma of the window reference pixel (x, y) matches with: the fine
    window when ``allowed`` (the pixel's code in the pass's fine-window region, not FINE_OFF) and the intensity
    variance under its spatial weights and the standard colour sigma reaches ``options.fine_min_var`` (and, at
    FINE_CREASE with ``options.fine_crease_min_var_ratio`` > 0, the variance under its own weights reaches that
    fraction of the standard window's), else the standard window (PatchMatchOptions.fine_window)."""
    colmap = options.ncc_weighting == "colmap"
    sigma_c = options.sigma_color if colmap else options.acmm_sigma_color
    std = options.window_offsets()
    standard = np.array([(dx, dy) for dy in std for dx in std]), options.sigma_spatial, sigma_c
    if not options.fine_window or not allowed:
        return standard
    f1 = options.fine_window_offsets()
    fine = np.array([(dx, dy) for dy in f1 for dx in f1])
    wts, a = bilateral_weights_ref(img, x, y, fine, options.ncc_weighting, options.fine_sigma_spatial, sigma_c)
    if _variance(wts, a) < options.fine_min_var:
        return standard
    fine_c = options.fine_sigma_color if colmap else sigma_c
    if allowed == FINE_CREASE and options.fine_crease_min_var_ratio > 0:
        v_own = _variance(*bilateral_weights_ref(img, x, y, fine, options.ncc_weighting,
                                                 options.fine_sigma_spatial, fine_c))
        v_std = _variance(*bilateral_weights_ref(img, x, y, standard[0], options.ncc_weighting,
                                                 options.sigma_spatial, sigma_c))
        if v_own < options.fine_crease_min_var_ratio * v_std:
            return standard
    return fine, options.fine_sigma_spatial, fine_c


def _variance(wts: np.ndarray, a: np.ndarray) -> float:
    mu = float((wts * a).sum())
    return float((wts * a * a).sum()) - mu * mu


def edge_band_ref(depth: np.ndarray, normal: np.ndarray, K: np.ndarray, jump: float, radius: int,
                  crease_angle: float = 0.0) -> np.ndarray:
    """(H, W) bool: pixels within ``radius`` (Chebyshev) of a 4-neighbour pair where neither pixel's plane
    predicts the other's depth within ``jump`` (relative), or either depth is <= 0, or (``crease_angle`` > 0)
    the two normals are more than ``crease_angle`` degrees apart (context.depth_edge_band)."""
    h, w = depth.shape
    Kinv = np.linalg.inv(K)

    def predicts(p, q):  # p's plane at q's ray, within jump of q's depth
        rp, rq = Kinv @ np.array([p[1], p[0], 1.0]), Kinv @ np.array([q[1], q[0], 1.0])
        n = normal[p].astype(np.float64)
        denom = float(n @ rq)
        if denom == 0.0:
            return False
        pred = float(depth[p]) * float(n @ rp) / denom
        return pred > 0 and abs(pred - depth[q]) / depth[q] <= jump

    edge = np.zeros((h, w), bool)
    for y in range(h):
        for x in range(w):
            for q in ((y + 1, x), (y, x + 1)):
                if q[0] >= h or q[1] >= w:
                    continue
                p = (y, x)
                cos_pq = float(normal[p].astype(np.float64) @ normal[q].astype(np.float64))
                crease = crease_angle > 0 and cos_pq < math.cos(math.radians(crease_angle))
                if depth[p] <= 0 or depth[q] <= 0 or not (predicts(p, q) or predicts(q, p)) or crease:
                    edge[p] = edge[q] = True
    band = np.zeros((h, w), bool)
    for y, x in np.argwhere(edge):
        band[max(0, y - radius): y + radius + 1, max(0, x - radius): x + radius + 1] = True
    return band


# ----------------------------------------------------------------------------- geometry (ACMM)


def homography_ref(K_ref: np.ndarray, R_ref: np.ndarray, t_ref: np.ndarray, K_src: np.ndarray, R_src: np.ndarray,
                   t_src: np.ndarray, x: int, y: int, z: float, n: np.ndarray) -> np.ndarray:
    """Plane-induced homography ref -> src for hypothesis (z, n) at pixel (x, y) (index-space K)."""
    R_rel = R_src @ R_ref.T
    t_rel = t_src - R_rel @ t_ref
    r = np.linalg.inv(K_ref) @ np.array([x, y, 1.0])
    d = -z * float(n @ r)
    return K_src @ (R_rel - np.outer(t_rel, n) / d) @ np.linalg.inv(K_ref)


def reprojection_error_ref(K_ref, R_ref, t_ref, K_src, R_src, t_src, src_depth: np.ndarray, x: int, y: int,
                           z: float) -> float:
    """Forward-backward reprojection error (px) via the nearest source pixel; -1 if unavailable."""
    X_ref = z * (np.linalg.inv(K_ref) @ np.array([x, y, 1.0]))
    Xw = R_ref.T @ (X_ref - t_ref)
    Xs = R_src @ Xw + t_src
    if Xs[2] <= 0:
        return -1.0
    u, v = (K_src @ Xs)[:2] / Xs[2]
    iu, iv = int(math.floor(u + 0.5)), int(math.floor(v + 0.5))
    h, w = src_depth.shape
    if not (0 <= iu < w and 0 <= iv < h) or src_depth[iv, iu] <= 0:
        return -1.0
    Xs2 = src_depth[iv, iu] * (np.linalg.inv(K_src) @ np.array([u, v, 1.0]))
    Xr2 = R_ref @ (R_src.T @ (Xs2 - t_src)) + t_ref
    if Xr2[2] <= 0:
        return -1.0
    p = (K_ref @ Xr2)[:2] / Xr2[2]
    return float(np.hypot(p[0] - x, p[1] - y))


def propagate_depth_ref(K_ref: np.ndarray, q: tuple[int, int], zq: float, nq: np.ndarray, p: tuple[int, int],
                        plane: bool = True) -> float:
    """Depth at p of q's plane (or z_q without plane propagation / for degenerate rays)."""
    if not plane:
        return zq
    Ki = np.linalg.inv(K_ref)
    rq = Ki @ np.array([q[0], q[1], 1.0])
    rp = Ki @ np.array([p[0], p[1], 1.0])
    den = float(nq @ rp)
    if abs(den) < 1e-5:
        return zq
    return zq * float(nq @ rq) / den


# ----------------------------------------------------------------------------- view selection (ACMM)


def view_weights_ref(M: np.ndarray, n_rows: int, neighbour_masks: list[int], tau_g: float, tau_bad: float = 1.2,
                     beta: float = 0.3, beta_fb: float = 0.4, n_good_gt: int = 2, n_bad_lt: int = 3,
                     prior_in: float = 0.9, prior_out: float = 0.1, deterministic: bool = True,
                     mc_samples: int = 15, key: int = 0, draw: int = 0) -> np.ndarray:
    """View weights (N,) from cost rows M (K_vs, N) (rows >= n_rows count as cost 2) and the
    selected-view masks of the in-image 4-neighbours."""
    k_rows, n = M.shape
    rows = np.full((k_rows, n), 2.0)
    rows[:n_rows] = M[:n_rows]
    omega = np.zeros(n)
    for j in range(n):
        col = rows[:, j]
        good = col < tau_g
        n_good, n_bad = int(good.sum()), int((col > tau_bad).sum())
        if n_good > n_good_gt and n_bad < n_bad_lt:
            om = float(np.exp(-col[good] ** 2 / (2 * beta**2)).sum() / n_good)
        elif n_bad < n_bad_lt:
            om = math.exp(-tau_g**2 / (2 * beta_fb**2))
        else:
            om = 0.0
        if om > 0:
            om *= sum(prior_in if (m >> j) & 1 else prior_out for m in neighbour_masks)
        omega[j] = om
    total = omega.sum()
    if total <= 0 or deterministic:
        return omega if total > 0 else np.zeros(n)
    v = np.zeros(n)
    cdf = np.cumsum(omega / total)
    nonzero = np.nonzero(omega > 0)[0]
    for s in range(mc_samples):
        u = rng.uniform(np.uint64(key), draw + s) - 1.1920929e-07
        hits = [j for j in range(n) if omega[j] > 0 and cdf[j] > u]
        v[hits[0] if hits else nonzero[-1]] += 1
    return v


# ----------------------------------------------------------------------------- JBU (ACMM)


def jbu_ref(depth_lo: np.ndarray, normal_lo: np.ndarray, guide_hi: np.ndarray, radius: int = 2,
            sigma_s: float = 0.5, sigma_r: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Joint bilateral upsampling, pixel-centre aligned, invalid (0) low-res depths excluded."""
    hl, wl = depth_lo.shape
    hh, wh = guide_hi.shape
    fx, fy = wl / wh, hl / hh
    depth = np.zeros((hh, wh))
    normal = np.zeros((hh, wh, 3))
    for y in range(hh):
        for x in range(wh):
            px, py = (x + 0.5) * fx - 0.5, (y + 0.5) * fy - 0.5
            cx, cy = int(math.floor(px + 0.5)), int(math.floor(py + 0.5))
            sw, sd, sn = 0.0, 0.0, np.zeros(3)
            for j in range(-radius, radius + 1):
                for i in range(-radius, radius + 1):
                    qx, qy = min(max(cx + i, 0), wl - 1), min(max(cy + j, 0), hl - 1)
                    if depth_lo[qy, qx] <= 0:
                        continue
                    ux = min(max(int(math.floor((qx + 0.5) / fx)), 0), wh - 1)
                    uy = min(max(int(math.floor((qy + 0.5) / fy)), 0), hh - 1)
                    wgt = math.exp(-((px - qx) ** 2 + (py - qy) ** 2) / (2 * sigma_s**2)
                                   - (guide_hi[y, x] - guide_hi[uy, ux]) ** 2 / (2 * sigma_r**2))
                    sw += wgt
                    sd += wgt * depth_lo[qy, qx]
                    sn += wgt * normal_lo[qy, qx]
            nn = np.linalg.norm(sn)
            if sw > 1e-30 and nn > 1e-12:
                depth[y, x] = sd / sw
                normal[y, x] = sn / nn
    return depth.astype(np.float32), normal.astype(np.float32)


# ----------------------------------------------------------------------------- random hypotheses (ACMM, COLMAP)


def random_normal_ref(key: int, draw: int, rp: np.ndarray) -> tuple[np.ndarray, int]:
    """Marsaglia sphere sample facing the camera; returns (normal, next draw)."""
    while True:
        q1 = 2.0 * rng.uniform(np.uint64(key), draw) - 1.0
        q2 = 2.0 * rng.uniform(np.uint64(key), draw + 1) - 1.0
        draw += 2
        s = q1 * q1 + q2 * q2
        if s < 1.0:
            break
    n = np.array([2 * q1 * math.sqrt(1 - s), 2 * q2 * math.sqrt(1 - s), 1 - 2 * s])
    return (-n if n @ rp > 0 else n), draw


def perturb_normal_ref(key: int, draw: int, rp: np.ndarray, n: np.ndarray, eps: float, retries: int) -> np.ndarray:
    """COLMAP-style normal perturbation: R_x(a1) R_y(a2) R_z(a3) n with angles in ±eps·π/2."""
    scale = eps * math.pi
    for _ in range(retries + 1):
        a = [(rng.uniform(np.uint64(key), draw + i) - 0.5) * scale for i in range(3)]
        draw += 3
        c, s = np.cos(a), np.sin(a)
        Rx = np.array([[1, 0, 0], [0, c[0], -s[0]], [0, s[0], c[0]]])
        Ry = np.array([[c[1], 0, s[1]], [0, 1, 0], [-s[1], 0, c[1]]])
        Rz = np.array([[c[2], -s[2], 0], [s[2], c[2], 0], [0, 0, 1]])
        m = Rx @ Ry @ Rz @ n
        if m @ rp < 0:
            return m / np.linalg.norm(m)
        scale *= 0.5
    return n


def refinement_hypotheses_ref(key: int, rp: np.ndarray, z: float, n: np.ndarray, zmin: float, zmax: float, eps: float,
                              retries: int, all8: bool) -> list[tuple[float, np.ndarray]]:
    """The local refinement's (depth, normal) hypotheses around (z, n): ACMM's five combinations of the current,
    perturbed and random depth and normal, or all eight besides the current one."""
    z_rnd = zmin + (zmax - zmin) * rng.uniform(np.uint64(key), 100)
    z_prt = z * (1.0 - eps + 2.0 * eps * rng.uniform(np.uint64(key), 101))
    n_rnd, _ = random_normal_ref(key, 102, rp)
    n_prt = perturb_normal_ref(key, 200, rp, n, eps, retries)
    if all8:
        return [(zz, nn) for zz in (z, z_prt, z_rnd) for nn in (n, n_prt, n_rnd)][1:]
    return [(z_rnd, n), (z, n_rnd), (z_rnd, n_rnd), (z, n_prt), (z_prt, n)]


# ----------------------------------------------------------------------------- one half-step (ACMM, DeepC)


class RefProblem:
    """A tiny reference-view problem for the plain-Python half-step.

    Args:
        ref_img: (H, W) reference grey image; ref_cam: its Camera.
        src_imgs, src_cams: source images and cameras.
        src_depths: source depth maps (geometric passes) or None.
        options: PatchMatchOptions.
    """

    def __init__(self, ref_img, ref_cam, src_imgs, src_cams, src_depths, options):
        self.ref_img = np.asarray(ref_img, np.float64)
        self.ref_cam = ref_cam
        self.src_imgs = [np.asarray(s, np.float64) for s in src_imgs]
        self.src_cams = src_cams
        self.src_depths = src_depths
        self.o = options
        self.Ki = np.linalg.inv(ref_cam.K_idx)
        self._windows: dict[tuple[int, int], tuple[np.ndarray, float, float]] = {}

    def ray(self, x: int, y: int) -> np.ndarray:
        return self.Ki @ np.array([x, y, 1.0])

    def photometric(self, x: int, y: int, z: float, n: np.ndarray, j: int) -> float:
        if z <= 0 or -z * float(n @ self.ray(x, y)) <= 1e-12:
            return 2.0
        c, s = self.ref_cam, self.src_cams[j]
        H = homography_ref(c.K_idx, c.R, c.t, s.K_idx, s.R, s.t, x, y, z, n)
        if (x, y) not in self._windows:
            self._windows[x, y] = window_choice_ref(self.ref_img, x, y, self.o)
        offsets, sigma_s, sigma_c = self._windows[x, y]
        return ncc_cost_ref(self.ref_img, self.src_imgs[j], H, x, y, offsets, self.o.ncc_weighting, sigma_s, sigma_c,
                            self.o.min_var)

    def geometric(self, x: int, y: int, z: float, j: int) -> float:
        c, s = self.ref_cam, self.src_cams[j]
        e = reprojection_error_ref(c.K_idx, c.R, c.t, s.K_idx, s.R, s.t, self.src_depths[j], x, y, z)
        return self.o.geom_max if (e < 0 or e > self.o.geom_max) else e

    def aggregated(self, x, y, z, n, v, geometric):
        total = 0.0
        for j, vj in enumerate(v):
            if vj > 0:
                cost = self.photometric(x, y, z, n, j)
                if geometric:
                    cost += self.o.geom_lambda * self.geometric(x, y, z, j)
                total += vj * cost
        return total / v.sum()


def init_cost_ref(prob: RefProblem, Z: np.ndarray, N: np.ndarray, geometric: bool,
                  rows: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Top-k initial cost and selected-view masks of all pixels (ACMM's top-k rule); with ``rows`` (start, stop)
    of the rows in that range only (zeros elsewhere)."""
    h, w = Z.shape
    o = prob.o
    C = np.zeros((h, w))
    S = np.zeros((h, w), np.uint32)
    for y in range(*(rows or (0, h))):
        for x in range(w):
            costs = np.array([prob.photometric(x, y, float(Z[y, x]), N[y, x].astype(np.float64), j)
                              for j in range(len(prob.src_imgs))])
            k = min(int((costs < 2).sum()), o.init_top_k)
            if k == 0:
                C[y, x] = 2.0 + (o.geom_lambda * o.geom_max if geometric else 0.0)
                continue
            kth = np.sort(costs)[k - 1]
            sel = np.nonzero(costs <= kth)[0]
            C[y, x] = np.sort(costs)[:k].mean()
            if geometric:
                C[y, x] += o.geom_lambda * np.mean([prob.geometric(x, y, float(Z[y, x]), j) for j in sel])
            S[y, x] = sum(1 << int(j) for j in sel)
    return C, S


def half_step_ref(prob: RefProblem, Z, N, C, S, Cpre, colour: int, key: int, iteration: int, zmin: float,
                  zmax: float, geometric: bool, detail: bool, pattern: tuple[np.ndarray, np.ndarray],
                  eps: float | None = None, changed: np.ndarray | None = None, active_share: float = -1.0,
                  rows: tuple[int, int] | None = None) -> None:
    """Plain-Python red-black half-step, in place (same semantics and random draws as the kernel); with ``rows``
    (start, stop) only the pixels of those rows are updated (one block of the kernel).

    ``eps`` is the perturbation scale (default 2^-iteration, the 'pass' schedule). Active set: with ``changed``
    (H, W) u8 (1 = the pixel's last update moved its depth by more than converge_depth or its normal by more than
    5 degrees; updated in place) and ``active_share`` >= 0,
    a pixel is updated only if it, a pattern sample or a 4-neighbour changed, or if draw 1 << 16 of its stream
    falls below ``active_share``."""
    o = prob.o
    h, w = Z.shape
    pat, region = pattern
    n_views = len(prob.src_imgs)
    if eps is None:
        eps = 2.0**-iteration
    tau_g = o.tau0 if o.alpha == 0 else o.tau0 * math.exp(-(iteration**2) / o.alpha)
    Z0, N0, C0, S0 = Z.copy(), N.copy(), C.copy(), S.copy()  # other colour's state, read-only
    for y in range(*(rows or (0, h))):
        for x in range((y + colour) % 2, w, 2):
            pk = int(rng.combine(np.uint64(key), y * w + x))
            if changed is not None:
                reads = [(x + int(dx), y + int(dy)) for dx, dy in pat]
                reads += [(x, y - 1), (x, y + 1), (x - 1, y), (x + 1, y)]
                moved = changed[y, x] or any(changed[qy, qx] for qx, qy in reads if 0 <= qx < w and 0 <= qy < h)
                drawn = rng.uniform(np.uint64(pk), 1 << 16) < active_share
                if active_share >= 0 and not moved and not drawn:
                    continue
                changed[y, x] = 0
            rp = prob.ray(x, y)
            # candidates: per region the in-image, valid sample with the lowest stored cost
            best_in_region: dict[int, tuple[float, int]] = {}
            for s, (dx, dy) in enumerate(pat):
                qx, qy = x + dx, y + dy
                if 0 <= qx < w and 0 <= qy < h and Z0[qy, qx] > 0:
                    r = int(region[s])
                    if r not in best_in_region or C0[qy, qx] < best_in_region[r][0]:
                        best_in_region[r] = (float(C0[qy, qx]), s)
            cands = []
            for r in sorted(best_in_region):
                cost, s = best_in_region[r]
                qx, qy = x + pat[s][0], y + pat[s][1]
                nq = N0[qy, qx].astype(np.float64)
                z = propagate_depth_ref(prob.ref_cam.K_idx, (qx, qy), float(Z0[qy, qx]), nq, (x, y),
                                        o.plane_propagation)
                if zmin <= z <= zmax:
                    cands.append((cost, z, nq))
            cands.sort(key=lambda c: c[0])  # stable: ties keep region order
            cands = cands[: o.k_update]
            n_vs = min(len(cands), o.k_viewsel)
            M = np.array([[prob.photometric(x, y, z, nq, j) for j in range(n_views)] for _, z, nq in cands[:n_vs]])
            M = M.reshape(n_vs, n_views)
            full = np.full((o.k_viewsel, n_views), 2.0)
            full[:n_vs] = M
            masks = [int(S0[qy, qx]) for qx, qy in ((x, y - 1), (x, y + 1), (x - 1, y), (x + 1, y))
                     if 0 <= qx < w and 0 <= qy < h]
            v = view_weights_ref(full, n_vs, masks, tau_g, o.tau_bad, o.beta, o.beta_fallback, o.n_good_gt,
                                 o.n_bad_lt, o.prior_in, o.prior_out, o.view_sampling == "deterministic",
                                 o.mc_samples, pk, 0)
            z0, n0 = float(Z[y, x]), N[y, x].astype(np.float64)
            if v.sum() <= 0:
                cur = np.array([prob.photometric(x, y, z0, n0, j) for j in range(n_views)])
                kth = np.sort(cur)[min(o.init_top_k, n_views) - 1]
                v = np.zeros(n_views)
                for j in range(n_views):
                    if cur[j] <= kth and v.sum() < o.init_top_k:
                        v[j] = 1.0
            c_cur = prob.aggregated(x, y, z0, n0, v, geometric)
            # a replacement must be cheaper by more than min_improvement: below ``bar``
            bar = c_cur - o.min_improvement
            best, zb, nb, won = bar, z0, n0, False
            for _k, (_, z, nq) in enumerate(cands):
                cost = prob.aggregated(x, y, z, nq, v, geometric)
                if cost < best:
                    best, zb, nb, won = cost, z, nq, True
            hyps = refinement_hypotheses_ref(pk, rp, zb, nb, zmin, zmax, eps, o.normal_perturb_retries,
                                             o.combos == "all8")
            for zz, nn in hyps:
                if not (zmin <= zz <= zmax):
                    continue
                cost = prob.aggregated(x, y, zz, nn, v, geometric)
                if cost < best:
                    best, zb, nb = cost, zz, nn
            if not best < bar:  # nothing won
                C[y, x] = c_cur
                continue
            if detail and not (best < Cpre[y, x] - o.detail_restorer_delta):
                C[y, x] = c_cur
                continue
            z_old, n_old = float(Z[y, x]), N[y, x].astype(np.float64)
            z_new, n_new = float(np.float32(zb)), nb.astype(np.float32).astype(np.float64)
            if changed is not None and (z_new != z_old or np.any(n_new != n_old)) and (
                    abs(z_new - z_old) > o.converge_depth * max(z_new, z_old)
                    or float(n_new @ n_old) < math.cos(math.radians(5.0))):
                changed[y, x] = 1
            Z[y, x], N[y, x], C[y, x] = zb, nb, best
            if won:
                S[y, x] = sum(1 << j for j in range(n_views) if v[j] > 0)
