"""Named records the numba kernels take: the parameters of one iteration, the maps of the reference view,
its cost caches, its matching windows and its source images.

They are ``typing.NamedTuple`` classes: numba passes them to a kernel as one struct and compiles an
attribute access to a field load, so a kernel takes a handful of records instead of 30 positional arrays
while its inner loops read the same values as before. A record's field types are part of the kernel's
compiled signature: build records with the functions here (or from ``ViewContext`` / ``ViewState``), which
fix every field's dtype, so that no second specialisation is compiled.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from engine.patchmatch.options import PatchMatchOptions


class KernelParams(NamedTuple):
    """Scalar settings of one red-black iteration (Xu & Tao 2019 ACMM; Kuhn et al. 2020 DeepC-MVS).

    Costs are photometric NCC costs 1 - NCC in [0, 2] unless said otherwise; geometric errors are in pixels.
    """

    zmin: float  # depth range, camera z in scene units: hypotheses outside it are never accepted
    zmax: float
    perturbation: float  # ε of the refinement hypotheses (relative depth, fraction of π/2 for normals)
    tau_good: float  # view selection: a cost below it is a good match (ACMM τ_g(t))
    tau_bad: float  # view selection: a cost above it is a bad match (ACMM τ_b)
    beta: float  # view selection: σ of the Gaussian weight of the good costs
    beta_fallback: float  # view selection: σ of the constant weight of a view with few bad costs
    prior_in: float  # view selection: prior factor per 4-neighbour that selected the view
    prior_out: float  # view selection: prior factor per 4-neighbour that did not
    geom_lambda: float  # λ: weight of the geometric term (cost per pixel of reprojection error)
    geom_max: float  # δ: truncation of the reprojection error (pixels)
    min_var: float  # NCC: a window whose intensity variance is below it has cost 2 (intensity²)
    detail_delta: float  # detail restorer: a new hypothesis must beat the upsampled one's cost by this
    min_improvement: float  # a replacement must lower the cost by more than this (0: any lower cost)
    k_viewsel: int  # candidates whose cost rows drive view selection (K_vs)
    k_update: int  # candidates considered for the update (K_up)
    top_k: int  # initial cost: mean of the top_k best views' costs
    n_good: int  # view selection: more than this many good costs give the Gaussian weight
    n_bad: int  # view selection: fewer than this many bad costs keep a view
    mc_samples: int  # view selection: Monte-Carlo draws of the view weights
    normal_retries: int  # normal perturbation: halvings of the angle range before falling back to n
    n_regions: int  # regions of the sampling pattern (one candidate each)
    plane_propagation: bool  # candidates take the neighbour's plane at this pixel (else its raw depth)
    geometric: bool  # geometric pass: add λ · min(reprojection error, δ) per view
    detail_restorer: bool  # photometric pass of a finer level: compare with the upsampled hypothesis
    deterministic: bool  # view weights are ω itself instead of Monte-Carlo counts
    all8: bool  # refinement tries all 8 combinations of current/perturbed/random depth and normal
    active_share: float  # active set: share of quiet pixels still updated; < 0 = every pixel is updated
    track_changes: bool  # write CostCaches.changed (the active set is on in this pass)
    change_depth: float  # active set: a hypothesis has changed when its depth moves more than this (relative)
    # the box of pixels a kernel updates, [box_x0, box_x1) x [box_y0, box_y1) in the maps' coordinates (an end < 0:
    # the image's edge): the pixel probe replays only the pixels a traced pixel depends on (probe/partial.py)
    box_x0: int = 0
    box_y0: int = 0
    box_x1: int = -1
    box_y1: int = -1
    # and inside the box only the pixels within L1 distance box_r of (box_cx, box_cy) (box_r < 0: the whole box):
    # the probe's dependency cone of one pixel, a diamond under a pattern of samples along the axes
    box_cx: int = 0
    box_cy: int = 0
    box_r: int = -1


def good_threshold(options: PatchMatchOptions, iteration: int) -> float:
    """τ_g of iteration ``iteration`` (0-based in its pass): tau0 · exp(-t² / alpha), constant for alpha 0
    (Xu & Tao 2019 ACMM)."""
    return options.tau0 * (math.exp(-(iteration**2) / options.alpha) if options.alpha > 0 else 1.0)


# the active set starts at this iteration of a pass: the first ones move most pixels (random start, upsampled or
# carried-over maps, the largest perturbations) and every pixel's first update has no earlier one to compare with
ACTIVE_FROM_ITERATION = 2


def active_share(options: PatchMatchOptions, iteration: int, last: bool = False) -> float:
    """``KernelParams.active_share`` of iteration ``iteration`` (0-based in its pass): -1 (every pixel is updated)
    while the active set is off, before ACTIVE_FROM_ITERATION and in the pass's ``last`` iteration (which accepts
    any lower cost: a quiet pixel's candidates may win there), else ``options.active_share``."""
    on = options.active_share >= 0 and iteration >= ACTIVE_FROM_ITERATION and not last
    return float(options.active_share) if on else -1.0


def kernel_params(options: PatchMatchOptions, zmin: float, zmax: float, iteration: int = 0, geometric: bool = False,
                  detail: bool = False, n_regions: int = 24, perturbation: float | None = None,
                  last: bool = False, box: tuple[int, ...] | None = None) -> KernelParams:
    """The :class:`KernelParams` of iteration ``iteration`` of a pass over a view with depth range [zmin, zmax].

    ``perturbation`` defaults to 2^-iteration; ``last``: the pass's last iteration, where any lower cost
    replaces a hypothesis (``PatchMatchOptions.min_improvement`` does not apply); ``n_regions``: regions of the
    sampling pattern (``propagation.sampling_pattern``); ``box``: (x0, y0, x1, y1), the pixels the kernels update
    (None: all), optionally followed by (cx, cy, r): only those within L1 distance r of (cx, cy) (see
    :class:`KernelParams`)."""
    x0, y0, x1, y1, cx, cy, r = (0, 0, -1, -1, 0, 0, -1) if box is None else (*(int(c) for c in box), 0, 0, -1)[:7]
    return KernelParams(
        zmin=float(zmin), zmax=float(zmax),
        perturbation=float(2.0 ** (-iteration) if perturbation is None else perturbation),
        tau_good=float(good_threshold(options, iteration)), tau_bad=float(options.tau_bad),
        beta=float(options.beta), beta_fallback=float(options.beta_fallback),
        prior_in=float(options.prior_in), prior_out=float(options.prior_out),
        geom_lambda=float(options.geom_lambda), geom_max=float(options.geom_max), min_var=float(options.min_var),
        detail_delta=float(options.detail_restorer_delta),
        min_improvement=0.0 if last else float(options.min_improvement),
        k_viewsel=int(options.k_viewsel), k_update=int(options.k_update), top_k=int(options.init_top_k),
        n_good=int(options.n_good_gt), n_bad=int(options.n_bad_lt), mc_samples=int(options.mc_samples),
        normal_retries=int(options.normal_perturb_retries), n_regions=int(n_regions),
        plane_propagation=bool(options.plane_propagation), geometric=bool(geometric), detail_restorer=bool(detail),
        deterministic=options.view_sampling == "deterministic", all8=options.combos == "all8",
        active_share=active_share(options, iteration, last), track_changes=bool(options.active_share >= 0),
        change_depth=float(options.converge_depth), box_x0=x0, box_y0=y0, box_x1=x1, box_y1=y1, box_cx=cx, box_cy=cy,
        box_r=r)


class HypothesisMaps(NamedTuple):
    """The reference view's hypothesis per pixel at the current level (Schönberger et al. 2016 COLMAP keep
    depth and normal; Xu & Tao 2019 ACMM add the selected views). H, W: the level's image size."""

    depth: np.ndarray  # (H, W) f32 camera z, scene units; 0 = none
    normal: np.ndarray  # (H, W, 3) f32 unit normal, camera frame, facing the camera
    cost: np.ndarray  # (H, W) f32 aggregated cost of the stored hypothesis
    selected_views: np.ndarray  # (H, W) u32 bitmask over the source views that support it


class CostCaches(NamedTuple):
    """What the half-steps of one pass remember between updates of a pixel (N sources, K = K_up). Every
    cached value is a float32 cost of an unchanged hypothesis, so a cached run is bit-identical to one that
    evaluates every window afresh (see ``kernels.half_step_kernel``)."""

    view_costs: np.ndarray  # (H, W, N) f32 per-view photometric cost of the stored hypothesis, NaN = unknown
    versions: np.ndarray  # (H, W) u32 the half-step (clock) of the stored hypothesis's last change, 0 = none
    row_samples: np.ndarray  # (H, W, K) i8 pattern sample of each candidate of the pixel's last update
    row_stamps: np.ndarray  # (H, W) u32 the half-step (clock) of that update
    row_costs: np.ndarray  # (H, W, K, N) f32 the candidates' photometric costs, NaN = not evaluated
    row_count: np.ndarray  # (H, W) i32 candidates of the last update (0 = none cached)
    changed: np.ndarray  # (H, W) u8 1 = the pixel's last update moved its plane (the active set, see kernels)
    rows: bool  # whether the row cache is used (the row_* arrays are (1, 1, ...) placeholders otherwise)
    clock: np.ndarray  # (1,) u32 half-steps of this pass so far (counted before each half-step's first block)


class RowBlock(NamedTuple):
    """The rows [start, stop) of the level's image that one call of a row kernel updates (``view_pass`` runs a
    view as blocks of a fraction of a second each, so that a stop request is honoured between them)."""

    start: int
    stop: int


class ReferenceWindows(NamedTuple):
    """Reference-side terms of the bilaterally weighted NCC (Schönberger et al. 2016 COLMAP) with
    each pixel's window set (``context.ViewContext``); S = the larger window's sample count."""

    kinv: np.ndarray  # (9,) f64 inverse intrinsics K⁻¹, row-major (pixel index -> ray)
    image: np.ndarray  # (H, W) f32 the reference image (a pixel's weights are computed from it: ncc.load_window)
    offsets: np.ndarray  # (n_sets, S, 2) i32 sample offsets (dx, dy) of each window set
    sigmas: np.ndarray  # (n_sets, 2) f64 spatial (px) and colour sigma of each window set's bilateral weights
    weighting: int  # ncc.WEIGHTING_CODES: 0 COLMAP's squared Gaussians, 1 ACMM's
    mean: np.ndarray  # (H, W) f32 weighted mean intensity μ_a
    variance: np.ndarray  # (H, W) f32 weighted intensity variance v_a
    offset_x: np.ndarray  # (n_sets, S) f32 sample offsets of each window set (pixels)
    offset_y: np.ndarray  # (n_sets, S) f32
    window_set: np.ndarray  # (H, W) u8 the window set of each pixel (0 standard, 1 fine)
    n_samples: np.ndarray  # (n_sets,) i64 samples of each window set


class SourceImages(NamedTuple):
    """The N source images with the ref -> source geometry (``geometry.pack_geometry``)."""

    pixels: np.ndarray  # (N·(Hm+1)·(Wm+1),) f32 the raveled padded images (Hm, Wm the largest source size)
    stride: int  # Wm + 1: one image row
    plane: int  # (Hm + 1)(Wm + 1): one image
    geometry: np.ndarray  # (N, GEO_COLS) f64 packed ref -> source matrices and source sizes
    depth: np.ndarray  # (N, Hm, Wm) f32 the sources' depth maps of the previous pass (geometric passes)


class SamplingPattern(NamedTuple):
    """Where a pixel looks for candidates (``propagation.sampling_pattern``)."""

    offsets: np.ndarray  # (P, 2) i32 sample offsets (dx, dy), all of odd |dx| + |dy| (the other colour)
    regions: np.ndarray  # (P,) i32 region of each sample: each region gives at most one candidate
