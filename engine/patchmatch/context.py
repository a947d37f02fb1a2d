"""Everything the kernels need about one reference view at one level, computed once per pass."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
from scipy import ndimage

from engine.core.camera import Camera
from engine.patchmatch.buffers import BufferPool
from engine.patchmatch.geometry import pack_geometry, relative_geometry
from engine.patchmatch.ncc import (
    FINE_CREASE,
    FINE_EDGE,
    FINE_OFF,
    WEIGHTING_CODES,
    load_window,
    pad_sources,
    window_offsets_2d,
    window_terms,
    window_weight_maps,
)
from engine.patchmatch.options import PatchMatchOptions
from engine.patchmatch.records import ReferenceWindows, SourceImages


@dataclasses.dataclass
class ViewContext:
    """Reference-side NCC terms, padded source images and ref->source geometry.

    Every pixel matches with one of up to two windows (the window set ``wset`` (H, W) u8 picks it: 0 = the
    standard window, 1 = the fine window, see ``PatchMatchOptions.fine_window``); window set s has
    ``ns[s]`` samples with offsets ``ox[s, :ns[s]]``, ``oy[s, :ns[s]]``.
    Shapes: kinv (9,); image (H, W) f32 the reference image (a pixel's weights are computed from it when a kernel
    visits it: ``ncc.load_window``); mu_a, var_a (H, W) f32; offs (S0, 2) i32 the standard window's offsets;
    wset (H, W) u8; ns (n_sets,) i64; offs_sets (n_sets, S, 2) i32 and ox, oy (n_sets, S) f32 each set's offsets
    (S = max(ns)); sigmas (n_sets, 2) f64 each set's spatial and colour sigma; weighting the ``ncc.WEIGHTING_CODES``
    code;
    src (N, Hm+1, Wm+1) f32 and its ravel ``flat``; geo (N, GEO_COLS) f64 the ref->source matrices A, b,
    B, c and source sizes packed for the kernels (``geometry.pack_geometry``); centers (N, 3) f64;
    sdepth (N, Hm, Wm) f32 source depth maps (zeros of shape (N, 1, 1) when not needed).
    """

    kinv: np.ndarray
    image: np.ndarray
    mu_a: np.ndarray
    var_a: np.ndarray
    offs: np.ndarray
    src: np.ndarray
    centers: np.ndarray
    sdepth: np.ndarray
    ox: np.ndarray
    oy: np.ndarray
    flat: np.ndarray
    wset: np.ndarray
    ns: np.ndarray
    geo: np.ndarray
    offs_sets: np.ndarray
    sigmas: np.ndarray
    weighting: int

    def offsets_at(self, x: int, y: int) -> tuple[np.ndarray, np.ndarray]:
        """The (S,) f32 offsets ``ox``, ``oy`` that reference pixel (x, y) matches with."""
        s = int(self.wset[y, x])
        n = int(self.ns[s])
        return self.ox[s, :n], self.oy[s, :n]

    def window_at(self, x: int, y: int, win: np.ndarray) -> int:
        """Load pixel (x, y)'s window into ``win`` (``ncc.ncc_work``); returns its number of samples."""
        return int(load_window(win, self.image, self.offs_sets, self.sigmas, self.weighting, self.ox, self.oy,
                               self.wset, self.ns, x, y))

    def window_weights(self) -> tuple[np.ndarray, np.ndarray]:
        """(H, W, S) f32 maps of every pixel's bilateral weights and w·a, as the kernels compute them (for tests
        and inspection: ``ncc.window_weight_maps``)."""
        return window_weight_maps(self.image, self.offs_sets, self.ns, self.sigmas, self.weighting, self.wset)

    def release(self, pool: BufferPool) -> None:
        """Hand the large reference-side arrays to ``pool`` (the context is unusable afterwards)."""
        pool.give(self.mu_a, self.var_a)
        self.mu_a = self.var_a = None

    def samples_per_cost(self) -> np.ndarray:
        """(H, W) i64 weighted samples one photometric cost takes at each pixel."""
        return self.ns[self.wset]

    def reference_windows(self) -> ReferenceWindows:
        """The reference-side arrays as the kernels take them (no copies)."""
        return ReferenceWindows(self.kinv, self.image, self.offs_sets, self.sigmas, self.weighting, self.mu_a,
                                self.var_a, self.ox, self.oy, self.wset, self.ns)

    def source_images(self) -> SourceImages:
        """The source-side arrays as the kernels take them (no copies)."""
        return SourceImages(self.flat, self.stride, self.plane, self.geo, self.sdepth)

    @property
    def stride(self) -> int:
        return int(self.src.shape[2])

    @property
    def plane(self) -> int:
        return int(self.src.shape[1] * self.src.shape[2])

    @property
    def num_sources(self) -> int:
        return int(self.geo.shape[0])


def weighting_sigma(options: PatchMatchOptions) -> float:
    """Colour sigma in the units of the chosen weighting."""
    return options.sigma_color if options.ncc_weighting == "colmap" else options.acmm_sigma_color


def build_context(ref_img: np.ndarray, ref_cam: Camera, src_imgs: list[np.ndarray], src_cams: list[Camera],
                  options: PatchMatchOptions, src_depths: list[np.ndarray] | None = None,
                  fine_allowed: np.ndarray | None = None, pool: BufferPool | None = None,
                  box: tuple[int, int, int, int] | None = None) -> ViewContext:
    """Precompute the :class:`ViewContext` of one reference view (images float32 in [0, 1]).

    ``fine_allowed`` (H, W) bool or uint8 region codes (``fine_window_region``) restricts the fine window to
    those pixels (None = no restriction); the
    window terms' arrays come from ``pool`` when given (see :meth:`ViewContext.release`); ``box`` (x0, y0, x1, y1):
    the reference window terms of those pixels only (kernels that update only them)."""
    ref_img = np.ascontiguousarray(ref_img, dtype=np.float32)
    mu_a, var_a, wset, offs_sets, sigmas = reference_terms(ref_img, options, fine_allowed,
                                                           np.empty if pool is None else pool.take, box)
    offs = offs_sets[0]
    src, sizes = pad_sources(src_imgs)
    geo = relative_geometry(ref_cam, src_cams)
    if src_depths is None:
        sdepth = np.zeros((len(src_imgs), 1, 1), np.float32)
    else:
        sdepth = np.zeros((len(src_imgs), src.shape[1] - 1, src.shape[2] - 1), np.float32)
        for j, d in enumerate(src_depths):
            sdepth[j, : d.shape[0], : d.shape[1]] = d
    s_max = max(len(o) for o in offs_sets)
    ns = np.array([len(o) for o in offs_sets], np.int64)
    packed = np.zeros((len(offs_sets), s_max, 2), np.int32)
    for i, o in enumerate(offs_sets):
        packed[i, : len(o)] = o
    ox = packed[:, :, 0].astype(np.float32)
    oy = packed[:, :, 1].astype(np.float32)
    return ViewContext(geo["kinv"], ref_img, mu_a, var_a, offs, src, geo["centers"], sdepth, ox, oy, src.reshape(-1),
                       wset, ns, pack_geometry(geo, sizes), packed, sigmas, WEIGHTING_CODES[options.ncc_weighting])


def reference_terms(ref_img: np.ndarray, options: PatchMatchOptions, fine_allowed: np.ndarray | None = None,
                    alloc: Callable[..., np.ndarray] = np.empty, box: tuple[int, int, int, int] | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[np.ndarray], np.ndarray]:
    """Reference-side NCC terms with the per-pixel window choice.

    A pixel takes the fine window when the intensity variance under the fine window's spatial weights
    and the standard colour sigma reaches ``fine_min_var``: there the small window holds enough texture
    for a stable NCC and no longer straddles depth edges the way the large one does (foreground
    fattening); weakly textured pixels keep the large window. At FINE_CREASE pixels of ``fine_allowed`` the
    variance under the fine window's own weights (its sharper colour sigma) must also reach
    ``fine_crease_min_var_ratio`` times the standard window's: on piecewise-constant texture the sharp colour
    weight keeps little more than the centre's colour and the small window is nearly flat, while the large
    one still sees the pattern.
    Returns mu_a, var_a (H, W) f32, wset (H, W) u8 (of ``box`` (x0, y0, x1, y1) only when given, 0 elsewhere),
    the offset sets and their (spatial, colour) sigmas (n_sets, 2) f64.
    """
    offs = window_offsets_2d(options.window_offsets())
    sigma_c = weighting_sigma(options)
    use_fine = bool(options.fine_window) and (fine_allowed is None or bool(fine_allowed.any()))
    offs_f = window_offsets_2d(options.fine_window_offsets()) if use_fine else np.zeros((0, 2), np.int32)
    fine_c = options.fine_sigma_color if options.ncc_weighting == "colmap" else sigma_c
    mu_a, var_a, wset = window_terms(ref_img, offs, offs_f, options.ncc_weighting, options.sigma_spatial, sigma_c,
                                     options.fine_sigma_spatial, fine_c, options.fine_min_var, fine_allowed, alloc,
                                     options.fine_crease_min_var_ratio, box=box)
    sigmas = [(options.sigma_spatial, sigma_c), (options.fine_sigma_spatial, fine_c)]
    n_sets = 2 if use_fine else 1
    return mu_a, var_a, wset, [offs, offs_f][:n_sets], np.array(sigmas[:n_sets], np.float64)


def fine_window_region(depth: np.ndarray, normal: np.ndarray, camera: Camera, options: PatchMatchOptions,
                       random_start: bool = False, level: int = 0) -> np.ndarray | None:
    """(H, W) uint8 where matching may use the fine window, or None for no restriction.

    Nowhere at levels coarser than ``fine_max_level``; up to it, None with ``fine_edge_radius`` 0, else the
    band around the depth discontinuities of the map a pass starts from (or of the final map, for the
    counter maps): occlusion edges are where the large window fattens the foreground, and only there does
    the fine window repay its lower precision inside textured surfaces. A random start has no edges yet,
    so its pass uses the standard window only. Codes: FINE_OFF (standard window), FINE_EDGE (the fine window
    where the texture test passes), FINE_CREASE (band of a crease only, ``fine_crease_angle``: the fine window
    where the texture test and ``fine_crease_min_var_ratio`` pass). depth (H, W), normal (H, W, 3) camera
    frame."""
    if not options.fine_window:
        return None
    if level > options.fine_max_level:
        return np.full(depth.shape, FINE_OFF, np.uint8)
    if options.fine_edge_radius <= 0:
        return None
    if random_start:
        return np.full(depth.shape, FINE_OFF, np.uint8)
    edge, crease = _edge_seeds(depth, normal, camera.pixel_rays(), options.fine_edge_jump, options.fine_crease_angle)
    edge_band = _dilate(edge, options.fine_edge_radius)
    region = edge_band.view(np.uint8) * np.uint8(FINE_EDGE)
    if crease.any():
        region[_dilate(crease, options.fine_edge_radius) & ~edge_band] = FINE_CREASE
    return region


def depth_edge_band(depth: np.ndarray, normal: np.ndarray, rays: np.ndarray, jump: float, radius: int,
                    crease_angle: float = 0.0) -> np.ndarray:
    """(H, W) bool: pixels within ``radius`` px (Chebyshev) of a depth discontinuity of a hypothesis map.

    Neighbouring pixels p, q (4-neighbours) are a discontinuity when each one's plane predicts the other's
    depth with a relative error above ``jump``, or when either has no valid hypothesis: a slanted plane
    (depth changing fast from pixel to pixel) is not an edge, an occlusion boundary is. With
    ``crease_angle`` > 0 (degrees), a pair whose normals differ by more than that is one too (a crease).
    depth (H, W) camera-frame depth, normal (H, W, 3) camera-frame unit normals, rays (H, W, 3) the pixels'
    rays K⁻¹ [x, y, 1] (``Camera.pixel_rays``).
    """
    edge, crease = _edge_seeds(depth, normal, rays, jump, crease_angle)
    return _dilate(edge | crease, radius)


def _edge_seeds(depth, normal, rays, jump, crease_angle):
    """(H, W) bool pixels of discontinuous pairs, and of crease pairs (normals more than ``crease_angle``
    apart; none at 0). Both consumers take the union or the crease part outside the edges' band, so a
    pixel may be in both."""
    h, w = depth.shape
    z = depth.astype(np.float64)
    n = normal.astype(np.float64)
    n_dot_own = np.einsum("hwc,hwc->hw", n, rays)
    edge = np.zeros((h, w), bool)
    crease = np.zeros((h, w), bool)
    for axis in (0, 1):
        a = (slice(None, -1), slice(None)) if axis == 0 else (slice(None), slice(None, -1))
        b = (slice(1, None), slice(None)) if axis == 0 else (slice(None), slice(1, None))
        pair = _discontinuous(z[a], z[b], n[a], n[b], n_dot_own[a], n_dot_own[b], rays[a], rays[b], jump)
        edge[a] |= pair
        edge[b] |= pair
        if crease_angle > 0:
            bent = np.einsum("...c,...c->...", n[a], n[b]) < math.cos(math.radians(crease_angle))
            crease[a] |= bent
            crease[b] |= bent
    return edge, crease


def _dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    if radius <= 0 or not mask.any():
        return mask
    # a square dilation is a maximum filter, which scipy applies axis by axis (binary_dilation visits the
    # whole (2r+1)^2 structure per pixel)
    return ndimage.maximum_filter(mask.view(np.uint8), size=2 * radius + 1, mode="constant", cval=0).astype(bool)


def _discontinuous(zp, zq, n_p, n_q, np_rp, nq_rq, rp, rq, jump):
    """Pairs (p, q) where neither plane predicts the other pixel's depth within ``jump`` (relative)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        pred_q = zp * np_rp / np.einsum("...c,...c->...", n_p, rq)  # p's plane at q's ray
        pred_p = zq * nq_rq / np.einsum("...c,...c->...", n_q, rp)
        err_q = np.abs(pred_q - zq) / zq
        err_p = np.abs(pred_p - zp) / zp
    ok_q = (pred_q > 0) & (err_q <= jump)
    ok_p = (pred_p > 0) & (err_p <= jump)
    valid = (zp > 0) & (zq > 0)
    return ~valid | ~(ok_q | ok_p)
