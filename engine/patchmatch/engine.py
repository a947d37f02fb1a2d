"""Multi-scale PatchMatch driver (SPEC.md §2.11): levels, passes over all views, iterations, events.

Schedule per level ℓ = L-1 .. 0 (L-1 coarsest): photometric pass (random init at the coarsest level,
JBU-upsampled maps plus detail restorer elsewhere), then ``geom_passes`` geometric passes reading
the other views' depth maps of the previous pass. Every pass runs over all views before the next
starts; each view: initial cost (top-k rule), then T red-black iterations (black, red half-steps).
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from collections.abc import Callable
from typing import Any

import numba
import numpy as np

from engine.camera import Camera
from engine.errors import DeepCError
from engine.interrupt import check_interrupt
from engine.observer import IterationEvent, readonly
from engine.patchmatch import kernels as K
from engine.patchmatch.buffers import BufferPool
from engine.patchmatch.context import ViewContext, build_context, fine_window_region
from engine.patchmatch.options import PatchMatchOptions
from engine.patchmatch.propagation import sampling_pattern
from engine.patchmatch.pyramid import area_resize, jbu_upsample, level_size
from engine.patchmatch.records import KernelParams, kernel_params
from engine.patchmatch.rng import stream_key

MAX_SOURCES = 32  # selected-view masks are uint32
RANDOM_INIT_ITERATION = 1 << 20  # stream id of the random initialisation (never a real iteration)
RESTORER_ITERATION = (1 << 20) + 1  # stream id of the detail restorer's random reference normals
# the candidate row cache takes K_up · (4 N + 6) + 4 bytes per pixel (165 MB at 768x512 with 5 sources,
# 291 MB with 10); above this it is left out (results are the same either way, only slower)
ROW_CACHE_MAX_BYTES = 2 << 30

ProgressFn = Callable[[str, int, int], Any]


@dataclasses.dataclass
class PatchMatchView:
    """One input view.

    Attributes:
        name: image name.
        image_gray: (H, W) float32 grey image in [0, 1].
        camera: camera at the image's resolution (``camera.width == W``).
        depth_min, depth_max: depth range (camera z, scene units) for sampling and validity.
        source_views: indices into the list of views (not itself), at most 32.
    """

    name: str
    image_gray: np.ndarray
    camera: Camera
    depth_min: float
    depth_max: float
    source_views: list[int]


@dataclasses.dataclass
class ViewMaps:
    """PatchMatch output of one view at level 0 (the input resolution).

    depth (H, W) f32 camera z, 0 = none; normal (H, W, 3) f32 unit, camera frame, facing the camera,
    zeros where depth is 0; cost (H, W) f32 final aggregated cost; selected_views (H, W) uint32 bitmask
    over positions in the view's ``source_views``.
    """

    depth: np.ndarray
    normal: np.ndarray
    cost: np.ndarray
    selected_views: np.ndarray

    @classmethod
    def empty(cls, height: int, width: int) -> ViewMaps:
        return cls(np.zeros((height, width), np.float32), np.zeros((height, width, 3), np.float32),
                   np.zeros((height, width), np.float32), np.zeros((height, width), np.uint32))


@dataclasses.dataclass
class _State:
    """Mutable per-view maps at the current level, and the cost caches of the running pass (set by
    :func:`init_cost`, see ``kernels.half_step_kernel``): ``P`` (H, W, N) f64 per-view photometric cost
    of each pixel's stored hypothesis (NaN = unknown); ``VER`` (H, W) u32 hypothesis versions; ``RS``
    (H, W, K_up) i16, ``RV`` (H, W, K_up) u32, ``RC`` (H, W, K_up, N) f32, ``RN`` (H, W) i32: the
    candidates (pattern sample and its pixel's version) and cost rows of each pixel's last update.
    Between the passes of a level: ``known`` (H, W, N) f32, the last pass's P, with ``known_wset`` (H, W) u8
    the window set each pixel matched with (:func:`init_cost` of the next pass reuses them)."""

    Z: np.ndarray
    N: np.ndarray
    C: np.ndarray
    S: np.ndarray
    P: np.ndarray | None = None
    VER: np.ndarray | None = None
    RS: np.ndarray | None = None
    RV: np.ndarray | None = None
    RC: np.ndarray | None = None
    RN: np.ndarray | None = None
    known: np.ndarray | None = None
    known_wset: np.ndarray | None = None

    def drop_caches(self, keep_costs_of: ViewContext | None = None, pool: BufferPool | None = None) -> None:
        """Free the pass's caches (into ``pool`` when given); with ``keep_costs_of`` (the pass's context) keep
        the photometric costs of the stored hypotheses for the next pass at this level (float32 holds them
        exactly)."""
        if keep_costs_of is not None and self.P is not None:
            # the context's wset is never pooled: keeping a reference is enough
            self.known, self.known_wset = self.P.astype(np.float32), keep_costs_of.wset
        else:
            self.known = self.known_wset = None
        if pool is not None:
            pool.give(self.P, self.VER, self.RS, self.RV, self.RC, self.RN)
        self.P = self.VER = self.RS = self.RV = self.RC = self.RN = None

    def maps(self) -> dict[str, np.ndarray]:
        """The maps a checkpoint saves (no copies, unlike ``dataclasses.asdict``, which would also deep-copy
        the caches)."""
        return {"Z": self.Z, "N": self.N, "C": self.C, "S": self.S}


def _check_views(views: list[PatchMatchView], options: PatchMatchOptions) -> list[bool]:
    """Validate inputs; returns which views are processed (others are skipped with a warning)."""
    active = []
    for i, v in enumerate(views):
        img = np.asarray(v.image_gray)
        if img.ndim != 2:
            raise DeepCError(f"view {i} ({v.name}): image_gray must be (H, W), got shape {img.shape}")
        h, w = img.shape
        if (v.camera.width, v.camera.height) != (w, h):
            raise DeepCError(f"view {i} ({v.name}): image is {w}x{h} but its camera is "
                             f"{v.camera.width}x{v.camera.height}")
        if min(w, h) < options.window:
            raise DeepCError(f"view {i} ({v.name}): image {w}x{h} is smaller than the "
                             f"{options.window}x{options.window} matching window")
        src = list(v.source_views)
        if len(src) > MAX_SOURCES:
            raise DeepCError(f"view {i} ({v.name}): {len(src)} source views, at most {MAX_SOURCES} supported")
        for j in src:
            if not (0 <= j < len(views)) or j == i:
                raise DeepCError(f"view {i} ({v.name}): invalid source view index {j}")
        if len(set(src)) != len(src):
            raise DeepCError(f"view {i} ({v.name}): duplicate source views {src}")
        ok = True
        if not src:
            warnings.warn(f"PatchMatch: view {i} ({v.name}) has no source view; skipped (empty maps)",
                          stacklevel=3)
            ok = False
        zmin, zmax = float(v.depth_min), float(v.depth_max)
        if ok and not (math.isfinite(zmin) and math.isfinite(zmax) and 0.0 < zmin < zmax):
            warnings.warn(f"PatchMatch: view {i} ({v.name}) has a degenerate depth range [{zmin}, {zmax}]; "
                          "skipped (empty maps)", stacklevel=3)
            ok = False
        active.append(ok)
    return active


def effective_levels(views: list[PatchMatchView], options: PatchMatchOptions) -> int:
    """Number of pyramid levels actually used: at most ``options.levels``, and the coarsest level's
    shorter side must be >= max(min_level_size, window) for every view."""
    need = max(options.min_level_size, options.window)
    levels = options.levels
    while levels > 1:
        ok = all(min(level_size(v.camera.width, v.camera.height, levels - 1)) >= need for v in views)
        if ok:
            break
        levels -= 1
    return levels


def perturbation_scale(options: PatchMatchOptions, iteration: int, done_before: int) -> float:
    """ε of iteration ``iteration`` of a pass preceded by ``done_before`` iterations of earlier passes
    (all levels): 2^-t per pass ('pass'), or 2^-(done_before + t) floored at eps_min ('global')."""
    if options.eps_schedule == "pass":
        return 2.0 ** (-iteration)
    return max(2.0 ** (-(done_before + iteration)), options.eps_min)


def row_cache_bytes(h: int, w: int, k_up: int, n_sources: int) -> int:
    """Bytes of the candidate row cache of an (h, w) view (see :class:`_State`)."""
    return h * w * (k_up * (4 * n_sources + 2 + 4) + 4)


def _caches(state: _State, ctx: ViewContext, k_up: int, reset: bool, pool: BufferPool | None = None) -> bool:
    """(Re)allocate the state's cost caches for this context (from ``pool`` when given); ``reset`` empties
    them (new pass). Returns whether the row cache is used (it is left out above ROW_CACHE_MAX_BYTES)."""
    h, w = state.Z.shape
    n = ctx.num_sources
    empty = np.empty if pool is None else pool.take
    if state.P is None or state.P.shape != (h, w, n):
        state.P = empty((h, w, n), np.float64)
        state.VER = empty((h, w), np.uint32)
        reset = True
    rows = row_cache_bytes(h, w, k_up, n) <= ROW_CACHE_MAX_BYTES
    if not rows:
        state.RS, state.RV = np.empty((1, 1, k_up), np.int16), np.empty((1, 1, k_up), np.uint32)
        state.RC, state.RN = np.empty((1, 1, k_up, n), np.float32), np.zeros((1, 1), np.int32)
    elif state.RN is None or state.RC.shape != (h, w, k_up, n):
        # contents are never read before written: RN = 0 (below) makes every cached row unknown
        state.RS, state.RV = empty((h, w, k_up), np.int16), empty((h, w, k_up), np.uint32)
        state.RC, state.RN = empty((h, w, k_up, n), np.float32), empty((h, w), np.int32)
        state.RN[:] = 0
    if reset:
        state.P[:] = np.nan
        state.VER[:] = 0
        state.RN[:] = 0
    return rows


def init_cost(state: _State, ctx: ViewContext, params: KernelParams, cache: bool = True,
              pool: BufferPool | None = None) -> None:
    """Recompute cost and selected views of the stored hypotheses (§2.4 top-k rule); with ``cache``
    also (re)start the cost caches the half-steps of this pass read (allocated from ``pool`` if given)."""
    if cache:
        _caches(state, ctx, params.k_update, True, pool)
    P = state.P if cache else np.empty((1, 1, 1))
    known, known_wset = state.known, state.known_wset
    if known is None:  # the kernel also ignores carried-over costs of another shape
        known, known_wset = np.empty((1, 1, 1), np.float32), np.empty((1, 1), np.uint8)
    K.init_cost_kernel(state.Z, state.N, state.C, state.S, P, cache, known, known_wset, ctx.flat, ctx.stride,
                       ctx.plane, ctx.geo, ctx.sdepth, ctx.kinv, ctx.wgt, ctx.wa, ctx.mu_a, ctx.var_a, ctx.ox,
                       ctx.oy, ctx.wset, ctx.ns, params)
    state.known = state.known_wset = None  # only valid for the hypotheses they were computed for


def half_step(state: _State, ctx: ViewContext, colour: int, cpre: np.ndarray, pat: np.ndarray,
              region: np.ndarray, key: np.uint64, params: KernelParams) -> np.ndarray:
    """One red or black half-step on one view (in place). Call :func:`init_cost` first in every pass
    (and after changing the state's maps from outside): it fills the cost cache the half-steps trust.

    Returns (N_COUNTS,) int64: NCC windows evaluated for the view-selection rows, the current
    hypotheses, the remaining candidates and the refinement, and the number of pixels updated."""
    rows = _caches(state, ctx, params.k_update, False)
    counts = np.zeros((state.Z.shape[0], K.N_COUNTS), np.int64)
    K.half_step_kernel(colour, state.Z, state.N, state.C, state.S, state.P, state.VER, state.RS, state.RV, state.RC,
                       state.RN, rows, cpre,
                       ctx.flat, ctx.stride, ctx.plane, ctx.geo, ctx.sdepth, ctx.kinv,
                       ctx.wgt, ctx.wa, ctx.mu_a, ctx.var_a, ctx.ox, ctx.oy, ctx.wset, ctx.ns, pat, region, key, params,
                       counts)
    return counts.sum(axis=0)


def restorer_reference(st: _State, ctx: ViewContext, options: PatchMatchOptions, params: KernelParams,
                       view: int, level: int, zmin: float, zmax: float) -> np.ndarray | None:
    """Cpre for detail_restorer_reference='random': top-k photometric cost (§2.4 rule) of the upsampled
    depth with a random normal facing the camera (None for 'upsampled': computed by the caller)."""
    if options.detail_restorer_reference != "random":
        return None
    h, w = st.Z.shape
    tmp = _State(np.empty((h, w), np.float32), np.empty((h, w, 3), np.float32), np.empty((h, w), np.float32),
                 np.empty((h, w), np.uint32))
    key = np.uint64(stream_key(options.seed, view, level, 0, RESTORER_ITERATION, 0))
    K.random_init_kernel(tmp.Z, tmp.N, ctx.kinv, zmin, zmax, key, False)
    tmp.Z[:] = st.Z
    init_cost(tmp, ctx, params, cache=False)
    return tmp.C


def _fix_normals(state: _State, cam: Camera) -> None:
    """Turn upsampled normals that face away from the camera (averaging can do that)."""
    rays = cam.pixel_rays().astype(np.float32)
    flip = np.einsum("hwc,hwc->hw", state.N, rays) > 0
    state.N[flip] *= -1.0


def run_patchmatch(views: list[PatchMatchView], options: PatchMatchOptions | None = None,
                   observer: Any = None, progress: ProgressFn | None = None, checkpoint: Any = None) -> list[ViewMaps]:
    """Multi-scale PatchMatch MVS over all views; returns one :class:`ViewMaps` per view.

    Args:
        views: the views; ``source_views`` index into this list.
        options: settings (defaults: SPEC.md §12).
        observer: optional; ``on_iteration(IterationEvent)`` after every red-black iteration of every
            view, pass and level, ``on_stage(name, **info)`` at pass boundaries. Either may be absent.
        progress: optional ``progress(description, done, total)``, called with done 0 when a pass starts
            and after each view finishes it, e.g. ``("level 2 photometric", 3, 11)``.
        checkpoint: optional :class:`engine.checkpoint.PatchMatchCheckpoint`: every view's state is saved
            after each pass, and states saved by an interrupted run with the same inputs are reused.

    Views without source views or with a degenerate depth range are skipped with a warning and get
    empty (zero) maps; they still serve as source images for others. Invalid inputs (image/camera
    size mismatch, images smaller than the matching window, bad source indices, more than 32 sources)
    raise :class:`DeepCError`. Same inputs, options and seed give identical maps on any thread count.
    """
    options = (options or PatchMatchOptions()).validate()
    if not views:
        return []
    active = _check_views(views, options)
    n_levels = effective_levels(views, options)
    if n_levels < options.levels:
        warnings.warn(f"PatchMatch: images too small for {options.levels} levels; using {n_levels}", stacklevel=2)
    on_iter = getattr(observer, "on_iteration", None) if observer is not None else None
    on_stage = getattr(observer, "on_stage", None) if observer is not None else None
    old_threads = numba.get_num_threads()
    if options.num_threads > 0:
        numba.set_num_threads(min(options.num_threads, numba.config.NUMBA_NUM_THREADS))
    try:
        if checkpoint is not None:
            checkpoint.bind(views, options, n_levels)
        return _run(views, options, active, n_levels, on_iter, on_stage, progress, checkpoint)
    finally:
        numba.set_num_threads(old_threads)


def _run(views: list[PatchMatchView], options: PatchMatchOptions, active: list[bool], n_levels: int,
         on_iter: Callable | None, on_stage: Callable | None, progress: ProgressFn | None,
         checkpoint: Any = None) -> list[ViewMaps]:
    pat, region = sampling_pattern(options.pattern)
    n_regions = int(region.max()) + 1
    n_views = len(views)
    # pyramid of images and cameras
    images: list[list[np.ndarray]] = []
    cameras: list[list[Camera]] = []
    for v in views:
        img0 = np.ascontiguousarray(v.image_gray, dtype=np.float32)
        imgs, cams = [], []
        for level in range(n_levels):
            w, h = level_size(v.camera.width, v.camera.height, level)
            imgs.append(area_resize(img0, w, h))
            cams.append(v.camera if level == 0 else v.camera.rescaled(w, h))
        images.append(imgs)
        cameras.append(cams)
    states: list[_State | None] = [None] * n_views
    step = 0
    done = 0  # iterations of all earlier passes (perturbation schedule 'global')
    n_active = sum(active)
    resume = _resume_states(checkpoint, images, n_levels)
    pool = BufferPool()  # the large per-pass arrays, reused from view to view (buffers.py)
    for level in range(n_levels - 1, -1, -1):
        coarsest = level == n_levels - 1
        pool.clear()  # a new level's arrays have other shapes
        if resume is not None and level >= resume[0]:
            # passes up to the resume point are done: only advance the counters
            for pass_index in range(1 + options.geom_passes):
                if level > resume[0] or pass_index <= resume[1]:
                    step += options.pass_iterations(pass_index) * n_active
                    done += options.pass_iterations(pass_index)
            if level > resume[0]:
                continue
        new_states: list[_State | None] = []
        for i, v in enumerate(views):
            if resume is not None:
                break  # this level's states are the resume point's
            check_interrupt()
            h, w = images[i][level].shape
            st = _State(np.zeros((h, w), np.float32), np.zeros((h, w, 3), np.float32),
                        np.zeros((h, w), np.float32), np.zeros((h, w), np.uint32))
            if active[i]:
                cam = cameras[i][level]
                kinv = np.linalg.inv(cam.K_idx).ravel()
                if not coarsest:
                    prev = states[i]
                    st.Z, st.N = jbu_upsample(prev.Z, prev.N, images[i][level], options.jbu_radius,
                                              options.jbu_sigma_spatial, options.jbu_sigma_range / 255.0)
                    _fix_normals(st, cam)
                key = np.uint64(stream_key(options.seed, i, level, 0, RANDOM_INIT_ITERATION, 0))
                K.random_init_kernel(st.Z, st.N, kinv, float(v.depth_min), float(v.depth_max), key, not coarsest)
            new_states.append(st)
        states = new_states if resume is None else resume[2]
        for pass_index in range(1 + options.geom_passes):
            if resume is not None and level == resume[0] and pass_index <= resume[1]:
                continue
            geometric = pass_index > 0
            kind = "geometric" if geometric else "photometric"
            detail = (not geometric) and (not coarsest) and options.detail_restorer
            n_iter = options.pass_iterations(pass_index)
            if on_stage is not None:
                on_stage("patchmatch_pass", level=level, pass_kind=kind, pass_index=pass_index, iterations=n_iter)
            snapshot = [s.Z.copy() for s in states] if geometric else None
            if progress is not None:
                progress(f"level {level} {kind}", 0, n_views)
            for i, v in enumerate(views):
                check_interrupt()
                saved = None if checkpoint is None else checkpoint.load(level, pass_index, i, states[i].Z.shape)
                if saved is not None:
                    states[i] = _State(**saved)
                    step += n_iter if active[i] else 0
                elif active[i]:
                    step = _run_view_pass(i, v, states[i], images, cameras, snapshot, level, pass_index, kind,
                                          detail, n_iter, options, pat, region, n_regions, on_iter, step, done,
                                          random_start=coarsest and pass_index == 0, pool=pool)
                if checkpoint is not None and saved is None:
                    checkpoint.save(level, pass_index, i, states[i].maps())
                if progress is not None:
                    progress(f"level {level} {kind}", i + 1, n_views)
            done += n_iter
            if checkpoint is not None:
                checkpoint.pass_complete(level, pass_index)
        resume = None
    out = []
    for i, st in enumerate(states):
        if not active[i]:
            h, w = images[i][0].shape
            out.append(ViewMaps.empty(h, w))
            continue
        valid = st.Z > 0
        st.N[~valid] = 0.0
        st.C[~valid] = 0.0
        out.append(ViewMaps(st.Z, st.N, st.C, st.S))
    if on_stage is not None:
        on_stage("patchmatch_done", levels=n_levels, views=n_views)
    return out


def _resume_states(checkpoint: Any, images: list, n_levels: int) -> tuple[int, int, list[_State]] | None:
    """(level, pass, every view's state after that pass) from the checkpoint's latest complete pass, or
    None to start from the beginning (no checkpoint, nothing saved, or a saved state failed its checks)."""
    point = None if checkpoint is None else checkpoint.resume_point()
    if point is None or not 0 <= point[0] < n_levels:
        return None
    level, pass_index = point
    states = []
    for i in range(len(images)):
        saved = checkpoint.load(level, pass_index, i, images[i][level].shape)
        if saved is None:
            return None
        states.append(_State(**saved))
    return level, pass_index, states


def _run_view_pass(i: int, v: PatchMatchView, st: _State, images: list, cameras: list, snapshot: list | None,
                   level: int, pass_index: int, kind: str, detail: bool, n_iter: int, options: PatchMatchOptions,
                   pat: np.ndarray, region: np.ndarray, n_regions: int, on_iter: Callable | None, step: int,
                   done_before: int = 0, random_start: bool = False, pool: BufferPool | None = None) -> int:
    src_idx = list(v.source_views)
    ctx = build_context(images[i][level], cameras[i][level], [images[j][level] for j in src_idx],
                        [cameras[j][level] for j in src_idx], options,
                        [snapshot[j] for j in src_idx] if snapshot is not None else None,
                        fine_window_region(st.Z, st.N, cameras[i][level], options, random_start, level), pool)
    zmin, zmax = float(v.depth_min), float(v.depth_max)
    params = kernel_params(options, zmin, zmax, 0, kind == "geometric", detail, n_regions)
    if detail:
        cpre = restorer_reference(st, ctx, options, params, i, level, zmin, zmax)
    init_cost(st, ctx, params, pool=pool)
    if not detail:
        cpre = st.C
    elif options.detail_restorer_reference == "upsampled":
        cpre = st.C.copy()
    for t in range(n_iter):
        check_interrupt()  # a stop request is honoured between kernels (engine/interrupt.py)
        t0 = time.perf_counter()
        params = kernel_params(options, zmin, zmax, t, kind == "geometric", detail, n_regions,
                               perturbation_scale(options, t, done_before), last=t == n_iter - 1)
        counts = np.zeros(K.N_COUNTS, np.int64)
        for colour in (0, 1):
            key = np.uint64(stream_key(options.seed, i, level, pass_index, t, colour))
            counts += half_step(st, ctx, colour, cpre, pat, region, key, params)
        if on_iter is not None:
            on_iter(IterationEvent(view=i, view_name=v.name, level=level, pass_kind=kind, pass_index=pass_index,
                                   iteration=t, step=step, depth=readonly(st.Z), normal=readonly(st.N),
                                   cost=readonly(st.C), selected_views=readonly(st.S),
                                   seconds=time.perf_counter() - t0,
                                   ncc_windows=int(counts[: K.CNT_PIXELS].sum())))
        step += 1
    # the caches are only valid within this pass (ctx); the photometric costs of the final hypotheses also hold
    # in the next pass of this level (same images; init_cost checks the window set)
    st.drop_caches(keep_costs_of=ctx if pass_index < options.geom_passes else None, pool=pool)
    if pool is not None:
        ctx.release(pool)
    return step
