"""Multi-scale PatchMatch driver (the schedule of Xu & Tao 2019 ACMM, as Kuhn et al. 2020 DeepC-MVS use it):
levels, passes over all views, iterations, events.

Schedule per level ℓ = L-1 .. 0 (L-1 coarsest): photometric pass (random init at the coarsest level,
JBU-upsampled maps plus detail restorer elsewhere), then ``geom_passes`` geometric passes reading
the other views' depth maps of the previous pass. Every pass runs over all views before the next
starts; each view: initial cost (top-k rule), then T red-black iterations (black, red half-steps).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable
from typing import Any

import numba
import numpy as np

import engine.patchmatch.kernels as K
from engine.camera import Camera
from engine.errors import DeepCError
from engine.interrupt import check_interrupt
from engine.observer import IterationEvent, readonly
from engine.patchmatch.buffers import BufferPool
from engine.patchmatch.context import build_context, fine_window_region
from engine.patchmatch.options import PatchMatchOptions
from engine.patchmatch.pyramid import area_resize, jbu_upsample, level_size
from engine.patchmatch.rng import stream_key
from engine.patchmatch.state import ROW_CACHE_MAX_BYTES, ViewState, row_cache_bytes
from engine.patchmatch.view_pass import run_view_level

# engine.memory sizes the cost caches with these (they live in state.py)
__all__ = ["MAX_SOURCES", "ROW_CACHE_MAX_BYTES", "PatchMatchView", "ViewMaps", "effective_levels", "row_cache_bytes",
           "run_patchmatch"]

MAX_SOURCES = 32  # selected-view masks are uint32
RANDOM_INIT_ITERATION = 1 << 20  # stream id of the random initialisation (never a real iteration)

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


def run_patchmatch(views: list[PatchMatchView], options: PatchMatchOptions | None = None,
                   observer: Any = None, progress: ProgressFn | None = None, checkpoint: Any = None) -> list[ViewMaps]:
    """Multi-scale PatchMatch MVS over all views; returns one :class:`ViewMaps` per view.

    Args:
        views: the views; ``source_views`` index into this list.
        options: settings (defaults: :class:`PatchMatchOptions`).
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
    states: list[ViewState | None] = [None] * n_views
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
        new_states: list[ViewState | None] = []
        for i, v in enumerate(views):
            if resume is not None:
                break  # this level's states are the resume point's
            check_interrupt()
            new_states.append(level_start_state(i, v, states[i], images[i][level], cameras[i][level], level,
                                                coarsest, active[i], options))
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
            snapshot = [s.depth.copy() for s in states] if geometric else None
            if progress is not None:
                progress(f"level {level} {kind}", 0, n_views)
            for i, v in enumerate(views):
                check_interrupt()
                saved = None if checkpoint is None else checkpoint.load(level, pass_index, i, states[i].depth.shape)
                if saved is not None:
                    states[i] = ViewState.from_checkpoint(saved)
                    step += n_iter if active[i] else 0
                elif active[i]:
                    step = _run_view_pass(i, v, states[i], images, cameras, snapshot, level, pass_index, detail,
                                          options, on_iter, step, done, random_start=coarsest and pass_index == 0,
                                          pool=pool)
                if checkpoint is not None and saved is None:
                    checkpoint.save(level, pass_index, i, states[i].checkpoint_arrays())
                if progress is not None:
                    progress(f"level {level} {kind}", i + 1, n_views)
            done += n_iter
            if checkpoint is not None:
                checkpoint.pass_complete(level, pass_index)
        resume = None
    out = [final_maps(st, active[i]) for i, st in enumerate(states)]
    if on_stage is not None:
        on_stage("patchmatch_done", levels=n_levels, views=n_views)
    return out


def level_start_state(i: int, v: PatchMatchView, prev: ViewState | None, image: np.ndarray, cam: Camera, level: int,
                      coarsest: bool, active: bool, options: PatchMatchOptions) -> ViewState:
    """The state view ``i`` starts ``level`` with (Xu & Tao 2019 ACMM): random hypotheses at the coarsest level,
    else ``prev`` (its final state one level coarser) JBU-upsampled to ``image`` (H, W), with random hypotheses
    where upsampling left none. Empty maps for an inactive view. A pure function of its arguments (the random
    stream is keyed by seed, view and level), so the per-view tasks of ``engine.distributed`` call it too."""
    h, w = image.shape
    st = ViewState.zeros(h, w)
    if active:
        kinv = np.linalg.inv(cam.K_idx).ravel()
        if not coarsest:
            st.depth, st.normal = jbu_upsample(prev.depth, prev.normal, image, options.jbu_radius,
                                               options.jbu_sigma_spatial, options.jbu_sigma_range / 255.0)
            _face_camera(st.normal, cam)
        key = np.uint64(stream_key(options.seed, i, level, 0, RANDOM_INIT_ITERATION, 0))
        K.random_init_kernel(st.depth, st.normal, kinv, float(v.depth_min), float(v.depth_max), key, not coarsest)
    return st


def final_maps(st: ViewState, active: bool) -> ViewMaps:
    """A view's output from its state after the last pass at level 0: normals and costs zeroed where there is no
    depth; empty maps for an inactive view."""
    if not active:
        h, w = st.depth.shape
        return ViewMaps.empty(h, w)
    valid = st.depth > 0
    st.normal[~valid] = 0.0
    st.cost[~valid] = 0.0
    return ViewMaps(st.depth, st.normal, st.cost, st.selected_views)


def _resume_states(checkpoint: Any, images: list, n_levels: int) -> tuple[int, int, list[ViewState]] | None:
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
        states.append(ViewState.from_checkpoint(saved))
    return level, pass_index, states


def _face_camera(normal: np.ndarray, cam: Camera) -> None:
    """Turn upsampled normals (H, W, 3) that face away from the camera (averaging can do that), in place."""
    rays = cam.pixel_rays().astype(np.float32)
    flip = np.einsum("hwc,hwc->hw", normal, rays) > 0
    normal[flip] *= -1.0


def _run_view_pass(i: int, v: PatchMatchView, st: ViewState, images: list, cameras: list, snapshot: list | None,
                   level: int, pass_index: int, detail: bool, options: PatchMatchOptions, on_iter: Callable | None,
                   step: int, done_before: int = 0, random_start: bool = False, pool: BufferPool | None = None) -> int:
    """Pass ``pass_index`` of view ``i`` at ``level`` (:func:`view_pass.run_view_level`) with its context built
    from the level's images and, in geometric passes, the ``snapshot`` of every view's depth; returns the step
    counter after it."""
    src_idx = list(v.source_views)
    ctx = build_context(images[i][level], cameras[i][level], [images[j][level] for j in src_idx],
                        [cameras[j][level] for j in src_idx], options,
                        [snapshot[j] for j in src_idx] if snapshot is not None else None,
                        fine_window_region(st.depth, st.normal, cameras[i][level], options, random_start, level), pool)
    kind = "geometric" if pass_index > 0 else "photometric"
    first_step = step

    def event(t: int, counts: np.ndarray, seconds: float) -> None:
        on_iter(IterationEvent(view=i, view_name=v.name, level=level, pass_kind=kind, pass_index=pass_index,
                               iteration=t, step=first_step + t, depth=readonly(st.depth),
                               normal=readonly(st.normal), cost=readonly(st.cost),
                               selected_views=readonly(st.selected_views), seconds=seconds,
                               ncc_windows=int(counts[: K.CNT_PIXELS].sum())))

    run_view_level(st, ctx, options, float(v.depth_min), float(v.depth_max), view=i, level=level,
                   pass_index=pass_index, detail=detail, done_before=done_before,
                   on_iteration=event if on_iter is not None else None, pool=pool)
    if pool is not None:
        ctx.release(pool)
    return step + options.pass_iterations(pass_index)
