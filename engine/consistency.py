"""Counter maps (Kuhn et al. 2020, §3.2): per pixel, the number of source views that confirm the final estimate.

A source view j of reference r is *consistent* at pixel p (with depth z and normal n) iff
  1. geometric: the forward-backward reprojection error through j's final depth map is
     <= ``reproj_px`` (nearest source pixel, no truncation);
  2. photometric: the bilateral NCC cost m_j(z, n) <= 1 - ``ncc_min``;
  3. viewing geometry: the triangulation angle between the rays from X to both camera centres is
     >= ``tri_angle_min_deg`` and, with ``check_facing``, n faces camera j;
  4. optionally (``rel_depth``): the reprojected point's depth in r differs from z by < rel_depth·z.
K(p) = number of consistent views (0 where z = 0), clipped to ``cap``, as uint8.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numba import njit, prange

from engine.core.heap_trim import release_free_memory
from engine.core.interrupt import check_interrupt
from engine.core.options import Options, option
from engine.patchmatch.buffers import BufferPool
from engine.patchmatch.context import build_context, fine_window_region
from engine.patchmatch.geometry import plane_vector, ray, reprojection
from engine.patchmatch.kernels import photometric_cost
from engine.patchmatch.multiscale import PatchMatchView, ViewMaps
from engine.patchmatch.ncc import load_window, ncc_work
from engine.patchmatch.options import PatchMatchOptions


@dataclasses.dataclass
class CounterOptions(Options):
    """Consistency checks of the counter map: COLMAP's filter of its depth maps."""

    reproj_px: float = option(1.0, "max forward-backward reprojection error", unit="px", source="COLMAP", above=0)
    ncc_min: float = option(0.1, "min NCC (cost <= 1 - ncc_min)", source="COLMAP", low=-1, high=1)
    tri_angle_min_deg: float = option(3.0, "min triangulation angle between the two viewing rays", unit="degrees",
                                      source="COLMAP", low=0, below=90)
    check_facing: bool = option(True, "require the normal to face the source camera", source="COLMAP")
    rel_depth: float | None = option(None, "max relative depth difference after reprojection (ACMM: 0.01); unset = "
                                     "no such check", source="COLMAP", above=0)
    cap: int = option(10, "counts are clipped to this value (the confidence network divides by it)", source="ours",
                      low=1, high=255)


@njit(cache=True, parallel=True)
def counter_kernel(Z, Nrm, src, stride, plane, geo, centers, sdepth, kinv, img, offs, sig, mode, mu_a, var_a, ox, oy,
                   wset, ns, min_var, reproj_px, max_cost, cos_tri_max, check_facing, rel_depth, cap, out):
    """Fill ``out`` (H, W) uint8 with the number of consistent source views (module doc)."""
    h, w = Z.shape
    n_views = geo.shape[0]
    for y in prange(h):
        win, sidx = ncc_work(ox.shape[1])
        for x in range(w):
            z = np.float64(Z[y, x])
            out[y, x] = 0
            if z <= 0.0:
                continue
            rp = ray(kinv, x, y)
            nx = np.float64(Nrm[y, x, 0])
            ny = np.float64(Nrm[y, x, 1])
            nz = np.float64(Nrm[y, x, 2])
            m0, m1, m2, ok = plane_vector(kinv, rp, z, nx, ny, nz)
            if not ok:
                continue
            n = load_window(win, img, offs, sig, mode, ox, oy, wset, ns, x, y)
            px = z * rp[0]
            py = z * rp[1]
            pz = z * rp[2]
            count = 0
            for j in range(n_views):
                err, zr = reprojection(geo, j, sdepth, x, y, z)
                if err < 0.0 or err > reproj_px:
                    continue
                if rel_depth > 0.0 and abs(zr - z) >= rel_depth * z:
                    continue
                # rays from X to both camera centres (reference centre = origin)
                ax, ay, az = -px, -py, -pz
                bx, by, bz = centers[j, 0] - px, centers[j, 1] - py, centers[j, 2] - pz
                na = math.sqrt(ax * ax + ay * ay + az * az)
                nb = math.sqrt(bx * bx + by * by + bz * bz)
                if na <= 0.0 or nb <= 0.0:
                    continue
                if (ax * bx + ay * by + az * bz) / (na * nb) > cos_tri_max:
                    continue
                if check_facing and nx * bx + ny * by + nz * bz <= 0.0:
                    continue
                cost = photometric_cost(src, stride, plane, geo, j, win, n, mu_a[y, x], var_a[y, x], x, y, m0, m1, m2,
                                        min_var, sidx)
                if cost > max_cost:
                    continue
                count += 1
            out[y, x] = min(count, cap)


def compute_counter_maps(views: list[PatchMatchView], maps: list[ViewMaps], options: CounterOptions | None = None,
                         ncc_options: PatchMatchOptions | None = None) -> list[np.ndarray]:
    """Counter map (H, W) uint8 of every view from the final maps of all views.

    Args:
        views: the PatchMatch inputs (images, cameras, source lists) at the maps' resolution.
        maps: final maps of every view (same order).
        options: the checks (defaults: the paper's).
        ncc_options: window and weighting of the photometric check (defaults: PatchMatchOptions()).
    Views without source views or with empty maps get an all-zero map.
    """
    options = (options or CounterOptions()).validate()
    ncc_options = (ncc_options or PatchMatchOptions()).validate()
    if len(views) != len(maps):
        raise ValueError(f"{len(views)} views but {len(maps)} maps")
    out = []
    pool = BufferPool()  # one view's window moments, reused by the next view of the same size
    for i, v in enumerate(views):
        check_interrupt()  # between kernels (engine/core/interrupt.py)
        m = maps[i]
        h, w = m.depth.shape
        counter = np.zeros((h, w), np.uint8)
        src_idx = list(v.source_views)
        if not src_idx or not np.any(m.depth > 0):
            out.append(counter)
            continue
        if (v.camera.width, v.camera.height) != (w, h):
            raise ValueError(f"view {i}: maps are {w}x{h} but the camera is {v.camera.width}x{v.camera.height}")
        ctx = build_context(np.asarray(v.image_gray, np.float32), v.camera,
                            [np.asarray(views[j].image_gray, np.float32) for j in src_idx],
                            [views[j].camera for j in src_idx], ncc_options, [maps[j].depth for j in src_idx],
                            fine_window_region(m.depth, m.normal, v.camera, ncc_options), pool)
        counter_kernel(np.ascontiguousarray(m.depth, np.float32), np.ascontiguousarray(m.normal, np.float32),
                       ctx.flat, ctx.stride, ctx.plane, ctx.geo, ctx.centers,
                       ctx.sdepth, ctx.kinv, ctx.image, ctx.offs_sets, ctx.sigmas, ctx.weighting, ctx.mu_a, ctx.var_a,
                       ctx.ox, ctx.oy, ctx.wset, ctx.ns, float(ncc_options.min_var), float(options.reproj_px),
                       1.0 - float(options.ncc_min),
                       math.cos(math.radians(options.tri_angle_min_deg)), bool(options.check_facing),
                       float(options.rel_depth or 0.0), int(options.cap), counter)
        ctx.release(pool)
        out.append(counter)
    pool.clear()
    release_free_memory()  # the window terms and PatchMatch's arrays, before fusion packs the maps (heap_trim)
    return out
