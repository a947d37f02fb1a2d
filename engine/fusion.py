"""Depth-map fusion into one point cloud, as COLMAP's StereoFusion (SPEC.md §7).

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
intrinsics ``Camera.K_idx`` (SPEC.md §1.2). COLMAP plugs (col, row) into its continuous K, so a
COLMAP workspace whose cameras carry K_idx reproduces our geometry exactly.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numba
import numpy as np

from engine.camera import Camera
from engine.errors import DeepCError
from engine.io.ply import read_ply, write_ply
from engine.options import Options, check, option


@dataclasses.dataclass
class FusionOptions(Options):
    """COLMAP-style fusion thresholds (SPEC.md §7, §12 ``fusion``); defaults = DeepC ETH3D high-res."""

    max_reproj_error: float = option(1.0, "largest reprojection error of the seed point in a fused view",
                                     metavar="PX")
    max_depth_error: float = option(0.01, "largest relative depth difference |z_proj - z| / z", metavar="REL")
    max_normal_error: float = option(20.0, "largest angle between a fused pixel's normal and the seed normal",
                                     metavar="DEGREES")
    min_num_pixels: int = option(3, "fewest fused pixels (seed included) for a point to be kept", metavar="N")
    max_num_pixels: int = option(10000, "stop a traversal after this many pixels", metavar="N")
    max_traversal_depth: int = option(100, "longest chain of views a traversal may follow", metavar="N")
    check_num_images: int = option(50, "overlapping views (most shared sparse points) searched per view",
                                   metavar="N")
    point_per_pixel: bool = option(False, "emit every pixel of a kept cluster as its own point instead of "
                                   "the cluster's median point (not COLMAP's behaviour)")

    def validate(self) -> FusionOptions:
        super().validate()
        check(self.max_reproj_error >= 0, "max_reproj_error", self.max_reproj_error, "must be >= 0")
        check(self.max_depth_error >= 0, "max_depth_error", self.max_depth_error, "must be >= 0")
        check(0 <= self.max_normal_error <= 180, "max_normal_error", self.max_normal_error,
              "must be in [0, 180] degrees")
        check(self.min_num_pixels >= 0, "min_num_pixels", self.min_num_pixels, "must be >= 0")
        check(self.max_num_pixels >= max(1, self.min_num_pixels), "max_num_pixels", self.max_num_pixels,
              "must be >= 1 and >= min_num_pixels")
        check(self.max_traversal_depth > 0, "max_traversal_depth", self.max_traversal_depth, "must be > 0")
        check(self.check_num_images > 0, "check_num_images", self.check_num_images, "must be > 0")
        return self


# SPEC.md §7.3 parameter sets.
FUSION_PRESETS: dict[str, FusionOptions] = {
    # COLMAP's own defaults.
    "colmap": FusionOptions(max_reproj_error=2.0, max_depth_error=0.01, max_normal_error=10.0, min_num_pixels=5),
    # "COLMAP fusion with ACMM parameters" (DeepC Table 1): reference + 2 consistent views.
    "acmm": FusionOptions(max_reproj_error=2.0, max_depth_error=0.01, max_normal_error=10.0, min_num_pixels=3),
    # DeepC vanilla / filtered maps, ETH3D high-res (Table 2 setting: 20 deg, 1 px, 2 supporting views).
    "deepc": FusionOptions(max_reproj_error=1.0, max_depth_error=0.01, max_normal_error=20.0, min_num_pixels=3),
    # DeepC on ETH3D low-res and Tanks and Temples: normal threshold quartered, 3 supporting views.
    "deepc_lowres": FusionOptions(max_reproj_error=1.0, max_depth_error=0.01, max_normal_error=5.0,
                                  min_num_pixels=4),
    # DeepC refined maps as SPEC.md §7.3 writes them: the paper's 5 deg, 3 pixels (the pixel count is [rec]).
    "refined_paper": FusionOptions(max_reproj_error=1.0, max_depth_error=0.01, max_normal_error=5.0,
                                   min_num_pixels=3),
    # Refined maps as --pipeline full fuses them: chosen on the four held-out synthetic scenes
    # (benchmarks/refined_fusion_sweep.py): a second pixel suffices, since the second network and the
    # depth/reprojection checks already test consistency (3 -> 2 px: F1 at 2 cm +3.7 to +7.9 points), and
    # 10 deg beats 5 deg on all four (+0.4 to +1.5): our refined normals at these resolutions are noisier
    # than the paper's (planar-normal error 5.5 deg mean on fountain_p11 768), so 5 deg splits true surfaces.
    "refined": FusionOptions(max_reproj_error=1.0, max_depth_error=0.01, max_normal_error=10.0, min_num_pixels=2),
    # What every pipeline fuses with by default (DEFAULT_PRESET). The paper's 1 px was set on ETH3D high-res
    # images (6048 px wide); at this tool's working sizes (<= 1536 px) a pixel is a 4-8x larger footprint,
    # and a 1 px radius around the seed's projection merges 2-3 neighbouring pixels of every view into one
    # median point: points are 2-3x sparser than the maps and blur across them. Half a pixel takes one
    # pixel per view, so the cloud keeps the maps' density, and a second agreeing view then suffices.
    # Chosen on the five held-out synthetic scenes (benchmarks/fusion_presets.py): F1 at 2 cm +2.8 to
    # +11.8 points over `deepc` on vanilla and fast maps, +1.6 to +8.5 over `refined` on refined maps,
    # never worse at 5 cm; the same on tiny, small and fountain_p11 (768, peer rule: 52.0 -> 54.9).
    "dense": FusionOptions(max_reproj_error=0.5, max_depth_error=0.01, max_normal_error=20.0, min_num_pixels=2),
    # What every pipeline fuses with by default (DEFAULT_PRESET): the clusters of `deepc`'s checks with a
    # second pixel enough, each pixel its own point. A cluster's median averages views whose cameras and
    # depths disagree slightly and leaves one point where the views sampled the surface n times; keeping the
    # verified pixels keeps every view's samples (3-4x the points of `dense`). Chosen on the five held-out
    # synthetic scenes (benchmarks/fusion_presets.py): F1 above `dense` on all five, on vanilla, fast and full
    # maps, at every tolerance (1 cm +3.9 to +12.1, 2 cm +1.4 to +5.1, 5 cm +0.6 to +2.1; accuracy at 2 cm
    # -2.3 to +0.5); with per-pixel points 1 px beats 0.5 px on all five. Also on tiny, small and
    # fountain_p11 (768, peer rule, vanilla: 54.9 -> 57.1 at 2 cm).
    "pixels": FusionOptions(max_reproj_error=1.0, max_depth_error=0.01, max_normal_error=20.0, min_num_pixels=2,
                            point_per_pixel=True),
}
DEFAULT_PRESET = "pixels"


@dataclasses.dataclass(eq=False)
class FusionView:
    """One view's maps for fusion, all at the depth-map resolution H x W.

    Attributes:
        camera: camera at the depth-map resolution (``camera.width == W``, ``camera.height == H``).
        depth: (H, W) float32 camera-frame z, 0 = none.
        normal: (H, W, 3) float32 unit normals in the camera frame (facing the camera).
        rgb: (H, W, 3) float32 in [0, 1] or uint8.
        confidence: (H, W) float32 in [0, 1], or None.
        overlap: indices (into the view list) of the views to search, best first (no self).
    """

    camera: Camera
    depth: np.ndarray
    normal: np.ndarray
    rgb: np.ndarray
    confidence: np.ndarray | None = None
    overlap: list[int] = dataclasses.field(default_factory=list)


@dataclasses.dataclass(eq=False)
class FusedCloud:
    """Fused points and the per-point attributes the viewer shows.

    Attributes:
        xyz: (N, 3) float64 (or float32 when read from a PLY) world positions.
        normal: (N, 3) float32 unit world normals.
        rgb: (N, 3) uint8 colours.
        num_views: (N,) int32 number of distinct views that contributed pixels (seed view included).
        mean_confidence: (N,) float32 mean confidence of the fused pixels; NaN without confidence maps.
        source_view: (N,) int32 index of the seed pixel's view (with ``point_per_pixel``: of the point's
            own pixel). ``num_views``, ``mean_confidence`` and ``num_pixels`` are always the cluster's.
        num_pixels: (N,) int32 number of fused pixels (seed included): the quantity ``min_num_pixels``
            thresholds, so masking a cloud fused with ``min_num_pixels=1`` by ``num_pixels >= m`` gives
            exactly the cloud fused with ``min_num_pixels=m``.
    """

    xyz: np.ndarray
    normal: np.ndarray
    rgb: np.ndarray
    num_views: np.ndarray
    mean_confidence: np.ndarray
    source_view: np.ndarray
    num_pixels: np.ndarray

    def __len__(self) -> int:
        return len(self.xyz)

    def subset(self, mask: np.ndarray) -> FusedCloud:
        """The points selected by a boolean mask or an index array."""
        return FusedCloud(*(np.asarray(getattr(self, f.name))[mask] for f in dataclasses.fields(self)))

    @classmethod
    def empty(cls) -> FusedCloud:
        return cls(np.zeros((0, 3)), np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8),
                   np.zeros(0, np.int32), np.zeros(0, np.float32), np.zeros(0, np.int32), np.zeros(0, np.int32))


# --------------------------------------------------------------------------------------------
# Packing views into flat arrays for the kernel.

def _rgb_uint8(rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) colours in [0, 1] (or uint8) -> uint8, rounding halves up; the reference of _to_uint8."""
    rgb = np.asarray(rgb)
    if rgb.dtype == np.uint8:
        return rgb
    return np.clip(np.floor(np.asarray(rgb, np.float64) * 255.0 + 0.5), 0, 255).astype(np.uint8)


@numba.njit(cache=True, nogil=True)
def _to_uint8(src: np.ndarray, dst: np.ndarray) -> None:
    # _rgb_uint8 in one pass: the numpy expression makes four float64 temporaries (26 of 40 ms of
    # packing 11 views at 768x512). NaN maps to 0 as in numpy's clip-then-cast on this platform.
    for i in range(src.shape[0]):
        v = np.floor(np.float64(src[i]) * 255.0 + 0.5)
        dst[i] = 0 if not v > 0.0 else (255 if v > 255.0 else np.uint8(v))


def _check_view(i: int, v: FusionView, n_views: int) -> None:
    h, w = v.camera.height, v.camera.width
    if np.shape(v.depth) != (h, w):
        raise ValueError(f"view {i}: depth shape {np.shape(v.depth)} does not match its camera ({h}, {w})")
    if np.shape(v.normal) != (h, w, 3):
        raise ValueError(f"view {i}: normal shape {np.shape(v.normal)}, expected ({h}, {w}, 3)")
    if np.shape(v.rgb) != (h, w, 3):
        raise ValueError(f"view {i}: rgb shape {np.shape(v.rgb)}, expected ({h}, {w}, 3)")
    if v.confidence is not None and np.shape(v.confidence) != (h, w):
        raise ValueError(f"view {i}: confidence shape {np.shape(v.confidence)}, expected ({h}, {w})")
    bad = [j for j in v.overlap if not 0 <= j < n_views]
    if bad:
        raise ValueError(f"view {i}: overlap indices {bad} out of range 0..{n_views - 1}")


def _pack(views: list[FusionView], options: FusionOptions):
    n = len(views)
    for i, v in enumerate(views):
        _check_view(i, v, n)
    sizes = np.array([v.camera.width * v.camera.height for v in views], np.int64)
    offsets = np.zeros(n + 1, np.int64)
    offsets[1:] = np.cumsum(sizes)
    # A private copy: the kernel marks consumed pixels by negating their depth.
    depth = np.concatenate([np.asarray(v.depth, np.float32).ravel() for v in views])
    normal = np.concatenate([np.asarray(v.normal, np.float32).reshape(-1, 3) for v in views])
    rgb = np.empty((int(offsets[-1]), 3), np.uint8)
    for v, a, b in zip(views, offsets[:-1], offsets[1:], strict=True):
        colours = np.asarray(v.rgb)
        if colours.dtype == np.uint8:
            rgb[a:b] = colours.reshape(-1, 3)
        else:
            if colours.dtype not in (np.float32, np.float64):
                colours = colours.astype(np.float64)
            _to_uint8(np.ascontiguousarray(colours).ravel(), rgb[a:b].reshape(-1))
    if all(v.confidence is None for v in views):
        conf = np.full(1, np.nan, np.float32)  # the kernel reads no confidence then
    else:
        conf = np.concatenate([np.full(int(s), np.nan, np.float32) if v.confidence is None
                               else np.asarray(v.confidence, np.float32).ravel()
                               for v, s in zip(views, sizes, strict=True)])
    widths = np.array([v.camera.width for v in views], np.int64)
    heights = np.array([v.camera.height for v in views], np.int64)
    P = np.zeros((n, 3, 4))
    Kinv = np.zeros((n, 3, 3))
    Rt = np.zeros((n, 3, 3))
    tvec = np.zeros((n, 3))
    for i, v in enumerate(views):
        K = v.camera.K_idx
        P[i, :, :3] = K @ v.camera.R
        P[i, :, 3] = K @ v.camera.t
        Kinv[i] = np.linalg.inv(K)
        Rt[i] = v.camera.R.T
        tvec[i] = v.camera.t
    ov_ptr = np.zeros(n + 1, np.int64)
    ov_lists = []
    for i, v in enumerate(views):
        seen: set[int] = set()
        lst = []
        for j in v.overlap:
            if j != i and j not in seen:
                seen.add(j)
                lst.append(int(j))
        ov_lists.append(lst[:options.check_num_images])
        ov_ptr[i + 1] = ov_ptr[i] + len(ov_lists[-1])
    ov_idx = np.array([j for lst in ov_lists for j in lst], np.int64)
    # Depth apart from the normals: the ~10 push-time depth lookups per fused pixel read only this array
    # (4 bytes a pixel, 17 MB for 11 views at 768x512), a pop adds one normal read. Measured against
    # 16-byte depth+normal records: best of 5 1.28 vs 1.31 s on fountain_p11 768 (small, but not slower).
    return depth, normal, rgb, conf, offsets, widths, heights, P, Kinv, Rt, tvec, ov_ptr, ov_idx


# --------------------------------------------------------------------------------------------
# The numba kernel.

@numba.njit(cache=True, inline="always")
def _round_half_away(x: float) -> int:
    # std::round: halves away from zero.
    if x >= 0.0:
        return int(math.floor(x + 0.5))
    return -int(math.floor(-x + 0.5))


@numba.njit(cache=True, nogil=True)
def _median(buf: np.ndarray, n: int, scratch: np.ndarray) -> float:
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
                    nc = _round_half_away(fc)
                    nr = _round_half_away(fr)
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
            mnx = _median(cluster[3], n, scratch)
            mny = _median(cluster[4], n, scratch)
            mnz = _median(cluster[5], n, scratch)
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
            out_xyz[n_out, 0] = _median(cluster[0], n, scratch)
            out_xyz[n_out, 1] = _median(cluster[1], n, scratch)
            out_xyz[n_out, 2] = _median(cluster[2], n, scratch)
            out_nrm[n_out, 0] = mnx / norm
            out_nrm[n_out, 1] = mny / norm
            out_nrm[n_out, 2] = mnz / norm
            out_rgb[n_out, 0] = min(255, _round_half_away(_median(cluster[6], n, scratch)))
            out_rgb[n_out, 1] = min(255, _round_half_away(_median(cluster[7], n, scratch)))
            out_rgb[n_out, 2] = min(255, _round_half_away(_median(cluster[8], n, scratch)))
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


def _reproj_sq_limit(options: FusionOptions) -> float:
    # Pixels of the seed's own view lie at exactly integer distances from the seed's projection, so
    # with a 1 px limit the accept/reject decision of its 4-neighbours would hinge on rounding noise.
    # A relative margin far above float64 noise makes "error <= limit" hold exactly as written.
    return options.max_reproj_error ** 2 * (1.0 + 1e-9) + 1e-12


def fuse(views: list[FusionView], options: FusionOptions | None = None) -> FusedCloud:
    """Fuse per-view depth/normal maps into one point cloud (SPEC.md §7). Deterministic.

    Args:
        views: the views, each with its camera, maps and overlap list (indices into ``views``).
        options: thresholds; default ``FusionOptions()`` (DeepC high-res).
    Returns:
        The fused cloud (world frame), in emission order.
    """
    options = (options or FusionOptions()).validate()
    if not views:
        return FusedCloud.empty()
    packed = _pack(list(views), options)
    xyz, nrm, rgb, nv, conf, src, npx = _fuse_kernel(
        *packed, _reproj_sq_limit(options), options.max_depth_error,
        math.cos(math.radians(options.max_normal_error)), int(options.min_num_pixels),
        int(options.max_num_pixels), int(options.max_traversal_depth), bool(options.point_per_pixel))
    return FusedCloud(xyz, nrm, rgb, nv, conf, src, npx)


# --------------------------------------------------------------------------------------------
# Plain-Python reference of the kernel (for tests on small maps; same algorithm, no numba).

def fuse_reference(views: list[FusionView], options: FusionOptions | None = None) -> FusedCloud:
    """Slow, straightforward implementation of :func:`fuse` used to test the numba kernel."""
    options = (options or FusionOptions()).validate()
    n_views = len(views)
    if n_views == 0:
        return FusedCloud.empty()
    for i, v in enumerate(views):
        _check_view(i, v, n_views)
    overlap = []
    for i, v in enumerate(views):
        lst = []
        for j in v.overlap:
            if j != i and j not in lst:
                lst.append(j)
        overlap.append(lst[:options.check_num_images])
    depth = [np.asarray(v.depth, np.float64) for v in views]
    normals = [np.asarray(v.normal, np.float64) for v in views]
    colours = [_rgb_uint8(v.rgb) for v in views]
    Ps = [np.hstack([v.camera.K_idx @ v.camera.R, (v.camera.K_idx @ v.camera.t)[:, None]]) for v in views]
    consumed = [np.zeros(d.shape, bool) for d in depth]
    fused = [False] * n_views
    min_cos = math.cos(math.radians(options.max_normal_error))
    out: dict[str, list] = {k: [] for k in ("xyz", "nrm", "rgb", "nv", "conf", "src", "npx")}

    def backproject(k, row, col, d):
        cam = views[k].camera
        Xc = d * (np.linalg.inv(cam.K_idx) @ np.array([col, row, 1.0]))
        return cam.R.T @ (Xc - cam.t)

    img = 0
    while img >= 0:
        H, W = depth[img].shape
        for row0 in range(H):
            for col0 in range(W):
                if consumed[img][row0, col0] or depth[img][row0, col0] <= 0:
                    continue
                stack = [(img, row0, col0, 0)]
                pts, nrms, cols, vis, confs, views_of = [], [], [], set(), [], []
                ref = ref_n = None
                while stack:
                    k, row, col, lvl = stack.pop()
                    d = depth[k][row, col]
                    if consumed[k][row, col] or d <= 0:
                        continue
                    if lvl > 0:
                        p = Ps[k] @ np.append(ref, 1.0)
                        if abs((p[2] - d) / d) > options.max_depth_error:
                            continue
                        if (p[0] / p[2] - col) ** 2 + (p[1] / p[2] - row) ** 2 > _reproj_sq_limit(options):
                            continue
                    nw = views[k].camera.R.T @ normals[k][row, col]
                    if lvl > 0 and float(ref_n @ nw) < min_cos:
                        continue
                    X = backproject(k, row, col, d)
                    consumed[k][row, col] = True
                    pts.append(X)
                    nrms.append(nw)
                    cols.append(colours[k][row, col].astype(np.float64))
                    vis.add(k)
                    views_of.append(k)
                    if views[k].confidence is not None and not math.isnan(views[k].confidence[row, col]):
                        confs.append(float(views[k].confidence[row, col]))
                    if lvl == 0:
                        ref, ref_n = X, nw
                    if len(pts) >= options.max_num_pixels:
                        break
                    if lvl >= options.max_traversal_depth - 1:
                        continue
                    for j in overlap[k]:
                        if fused[j]:
                            continue
                        q = Ps[j] @ np.append(X, 1.0)
                        if q[2] <= 0:
                            continue
                        u, v_ = q[0] / q[2], q[1] / q[2]
                        if not (-1 < u < views[j].camera.width and -1 < v_ < views[j].camera.height):
                            continue
                        nc, nr = _round_half_away(u), _round_half_away(v_)
                        if 0 <= nc < views[j].camera.width and 0 <= nr < views[j].camera.height:
                            stack.append((j, nr, nc, lvl + 1))
                if len(pts) < max(options.min_num_pixels, 1):
                    continue
                mn = np.median(np.array(nrms), axis=0)
                norm = float(np.linalg.norm(mn))
                if norm < 1.1920929e-07:
                    continue
                if options.point_per_pixel:
                    for X, nw, c, k in zip(pts, nrms, cols, views_of, strict=True):
                        out["xyz"].append(X)
                        out["nrm"].append(nw)
                        out["rgb"].append(c)
                        out["nv"].append(len(vis))
                        out["conf"].append(np.mean(confs) if confs else np.nan)
                        out["src"].append(k)
                        out["npx"].append(len(pts))
                    continue
                out["xyz"].append(np.median(np.array(pts), axis=0))
                out["nrm"].append(mn / norm)
                out["rgb"].append([min(255, _round_half_away(c)) for c in np.median(np.array(cols), axis=0)])
                out["nv"].append(len(vis))
                out["conf"].append(np.mean(confs) if confs else np.nan)
                out["src"].append(img)
                out["npx"].append(len(pts))
        fused[img] = True
        nxt = next((j for j in overlap[img] if not fused[j]), -1)
        if nxt < 0:
            nxt = next((j for j in range(n_views) if not fused[j]), -1)
        img = nxt
    if not out["xyz"]:
        return FusedCloud.empty()
    return FusedCloud(np.array(out["xyz"]), np.array(out["nrm"], np.float32), np.array(out["rgb"], np.uint8),
                      np.array(out["nv"], np.int32), np.array(out["conf"], np.float32),
                      np.array(out["src"], np.int32), np.array(out["npx"], np.int32))


# --------------------------------------------------------------------------------------------
# PLY I/O and helpers.

_EXTRA = ("num_views", "confidence", "source_view", "num_pixels")


def write_fused_ply(path: str | Path, cloud: FusedCloud) -> None:
    """Write ``fused.ply``: binary little-endian, float32 x/y/z, nx/ny/nz, uchar red/green/blue, plus the
    viewer attributes ``num_views`` (int), ``confidence`` (float, NaN = none), ``source_view`` (int)."""
    write_ply(path, np.asarray(cloud.xyz, np.float32), normals=np.asarray(cloud.normal, np.float32),
              rgb=np.asarray(cloud.rgb, np.uint8),
              extra={"num_views": np.asarray(cloud.num_views, np.int32),
                     "confidence": np.asarray(cloud.mean_confidence, np.float32),
                     "source_view": np.asarray(cloud.source_view, np.int32),
                     "num_pixels": np.asarray(cloud.num_pixels, np.int32)})


def read_fused_ply(path: str | Path) -> FusedCloud:
    """Read a fused cloud (ours or COLMAP's ``fused.ply``); missing attributes get neutral values
    (normals 0, colour 0, num_views 0, confidence NaN, source_view -1)."""
    cols = read_ply(path)
    n = len(cols["x"])
    xyz = np.stack([cols["x"], cols["y"], cols["z"]], axis=1)

    def stack(names, dtype, fill):
        if all(k in cols for k in names):
            return np.stack([cols[k] for k in names], axis=1).astype(dtype)
        return np.full((n, len(names)), fill, dtype)

    def column(name, dtype, fill):
        return cols[name].astype(dtype) if name in cols else np.full(n, fill, dtype)

    return FusedCloud(xyz, stack(("nx", "ny", "nz"), np.float32, 0), stack(("red", "green", "blue"), np.uint8, 0),
                      column("num_views", np.int32, 0), column("confidence", np.float32, np.nan),
                      column("source_view", np.int32, -1), column("num_pixels", np.int32, 0))


def depth_normals(camera: Camera, depth: np.ndarray, max_relative_jump: float = 0.02) -> np.ndarray:
    """(H, W, 3) float32 camera-frame normals estimated from a depth map (e.g. ground truth).

    Central differences of the back-projected points (index-space K), oriented towards the camera.
    Pixels without depth, at the border, or next to a depth jump larger than ``max_relative_jump``
    (relative to the centre depth) get the zero vector: callers usually drop them.
    """
    depth = np.asarray(depth, np.float64)
    if depth.shape != (camera.height, camera.width):
        raise ValueError(f"depth shape {depth.shape} does not match camera ({camera.height}, {camera.width})")
    X = camera.pixel_rays() * depth[..., None]
    out = np.zeros(depth.shape + (3,), np.float32)
    if min(depth.shape) < 3:
        return out
    c = depth[1:-1, 1:-1]
    nbrs = (depth[1:-1, 2:], depth[1:-1, :-2], depth[2:, 1:-1], depth[:-2, 1:-1])
    ok = c > 0
    for nb in nbrs:
        ok &= (nb > 0) & (np.abs(nb - c) <= max_relative_jump * c)
    dx = X[1:-1, 2:] - X[1:-1, :-2]
    dy = X[2:, 1:-1] - X[:-2, 1:-1]
    n = np.cross(dx, dy)
    norm = np.linalg.norm(n, axis=-1)
    ok &= norm > 0
    n = n / np.where(norm > 0, norm, 1.0)[..., None]
    flip = np.einsum("ijk,ijk->ij", n, X[1:-1, 1:-1]) > 0
    n[flip] *= -1
    out[1:-1, 1:-1] = np.where(ok[..., None], n, 0.0)
    return out


def views_from_scene(scene, depth_maps: list[np.ndarray], normal_maps: list[np.ndarray],
                     confidence_maps: list[np.ndarray | None] | None = None,
                     check_num_images: int = 50) -> list[FusionView]:
    """Fusion views for every view of ``scene`` (an ``engine.scene.Scene``).

    Cameras and colours are brought to each depth map's resolution; the overlap lists are the
    views sharing most sparse points (COLMAP's ``GetMaxOverlappingImages``).
    """
    from engine.io.images import resize_area

    if len(depth_maps) != len(scene.views) or len(normal_maps) != len(scene.views):
        raise DeepCError(f"scene has {len(scene.views)} views but {len(depth_maps)} depth and "
                         f"{len(normal_maps)} normal maps were given", scene.root)
    views = []
    for i, sv in enumerate(scene.views):
        depth = np.asarray(depth_maps[i], np.float32)
        h, w = depth.shape
        cam = sv.camera if (sv.camera.width, sv.camera.height) == (w, h) else sv.camera.rescaled(w, h)
        rgb = scene.image(i)
        if rgb.shape[:2] != (h, w):
            rgb = resize_area(rgb, (w, h))
        conf = None if confidence_maps is None else confidence_maps[i]
        views.append(FusionView(cam, depth, np.asarray(normal_maps[i], np.float32), rgb, conf,
                                scene.overlapping_views(i, check_num_images)))
    return views


def write_colmap_workspace(scene, views: list[FusionView], workdir: str | Path,
                           sparse_dir: str | Path | None = None) -> Path:
    """Write a minimal COLMAP dense workspace for ``views`` (one per ``scene.views``, same order).

    Images at the depth-map resolution (PNG data, lossless), the scene's sparse model (its tracks
    give COLMAP's overlap graph) with every camera set to the depth-map size and our index-space
    intrinsics (so COLMAP's (col, row) un-projection equals ours), depth and normal maps written
    with our COLMAP-layout writer (pycolmap's NormalMap binding scrambles channels), fusion.cfg.
    """
    import pycolmap
    from PIL import Image

    from engine.io.colmap_model import find_model_dir
    from engine.io.dense import write_dense_map

    workdir = Path(workdir)
    rec = pycolmap.Reconstruction(str(sparse_dir or find_model_dir(scene.root)))
    by_name = {im.name: im for im in rec.images.values()}
    set_cameras: dict[int, tuple] = {}
    for sv, v in zip(scene.views, views, strict=True):
        im = by_name[sv.name]
        K = v.camera.K_idx
        params = (v.camera.width, v.camera.height, K[0, 0], K[1, 1], K[0, 2], K[1, 2])
        if set_cameras.setdefault(im.camera_id, params) != params:
            raise ValueError(f"views sharing COLMAP camera {im.camera_id} have different map sizes or intrinsics")
        cam = rec.cameras[im.camera_id]
        cam.width, cam.height = v.camera.width, v.camera.height
        cam.params = list(params[2:])
    (workdir / "sparse").mkdir(parents=True, exist_ok=True)
    rec.write_binary(str(workdir / "sparse"))
    for sv, v in zip(scene.views, views, strict=True):
        image_path = workdir / "images" / sv.name
        image_path.parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(_rgb_uint8(v.rgb)).save(image_path, format="PNG")
        write_dense_map(workdir / "stereo" / "depth_maps" / f"{sv.name}.geometric.bin", v.depth)
        write_dense_map(workdir / "stereo" / "normal_maps" / f"{sv.name}.geometric.bin", v.normal)
    (workdir / "stereo" / "fusion.cfg").write_text("".join(f"{sv.name}\n" for sv in scene.views))
    return workdir


def run_colmap_fusion(workdir: str | Path, options: FusionOptions, num_threads: int = 1) -> FusedCloud:
    """Run ``pycolmap.stereo_fusion`` (CPU) on a workspace from :func:`write_colmap_workspace`.

    ``num_threads=1`` makes COLMAP deterministic. Returns its points; num_views comes from
    ``fused.ply.vis`` (source_view is -1: COLMAP does not record it).
    """
    import pycolmap

    workdir = Path(workdir)
    copts = pycolmap.StereoFusionOptions(
        min_num_pixels=options.min_num_pixels, max_num_pixels=options.max_num_pixels,
        max_traversal_depth=options.max_traversal_depth, max_reproj_error=options.max_reproj_error,
        max_depth_error=options.max_depth_error, max_normal_error=options.max_normal_error,
        check_num_images=options.check_num_images, num_threads=num_threads)
    out = workdir / "fused.ply"
    pycolmap.stereo_fusion(str(out), str(workdir), input_type="geometric", options=copts, output_type="PLY")
    cloud = read_fused_ply(out)
    vis = workdir / "fused.ply.vis"
    if vis.is_file():
        data = np.fromfile(vis, "<u4")
        counts, pos = [], 2  # a uint64 point count comes first
        for _ in range(len(cloud)):
            counts.append(int(data[pos]))
            pos += 1 + int(data[pos])
        cloud.num_views = np.array(counts, np.int32)
    return cloud


def colmap_reference_fusion(scene, views: list[FusionView], options: FusionOptions, workdir: str | Path,
                            num_threads: int = 1, sparse_dir: str | Path | None = None) -> FusedCloud:
    """Fuse the same maps with COLMAP's own fusion as a referee (workspace under ``workdir``)."""
    write_colmap_workspace(scene, views, workdir, sparse_dir)
    return run_colmap_fusion(workdir, options, num_threads)
