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
from engine.core.camera import Camera
from engine.core.errors import DeepCError
from engine.core.heap_trim import release_free_memory
from engine.core.interrupt import check_interrupt
from engine.core.observer import IterationEvent, readonly
from engine.core.words import plural
from engine.patchmatch.buffers import BufferPool
from engine.patchmatch.context import build_context, fine_window_region
from engine.patchmatch.options import PatchMatchOptions
from engine.patchmatch.probe.pixel_probe import PassProbe, PixelProbe
from engine.patchmatch.pyramid import area_resize, jbu_upsample, level_size
from engine.patchmatch.rng import stream_key
from engine.patchmatch.state import ROW_CACHE_MAX_BYTES, ViewState, row_cache_bytes
from engine.patchmatch.view_pass import Box, run_view_level

# engine.run.memory sizes the cost caches with these (they live in state.py)
__all__ = ["MAX_SOURCES", "ROW_CACHE_MAX_BYTES", "PatchMatchView", "ViewMaps", "effective_levels", "replay_view",
           "row_cache_bytes", "run_patchmatch", "view_pyramids"]

MAX_SOURCES = 32  # selected-view masks are uint32
RANDOM_INIT_ITERATION = 1 << 20  # stream id of the random initialisation (never a real iteration)

ProgressFn = Callable[[str, int, int], Any]
# snapshots(level, pass_index, view indices) -> {view index: depth map the geometric pass read}
SnapshotFn = Callable[[int, int, list[int]], dict[int, np.ndarray]]
# on_pass(level, pass_index, phase, state, images, cameras): phase "start" before a pass, "end" after a level's last
PassFn = Callable[[int, int, str, ViewState, list, list], Any]


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


def check_views(views: list[PatchMatchView], options: PatchMatchOptions) -> list[bool]:
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
                   observer: Any = None, progress: ProgressFn | None = None, checkpoint: Any = None,
                   probe: PixelProbe | None = None, history: Any = None) -> list[ViewMaps]:
    """Multi-scale PatchMatch MVS over all views; returns one :class:`ViewMaps` per view.

    Args:
        views: the views; ``source_views`` index into this list.
        options: settings (defaults: :class:`PatchMatchOptions`).
        observer: optional; ``on_iteration(IterationEvent)`` after every red-black iteration of every
            view, pass and level, ``on_stage(name, **info)`` at pass boundaries. Either may be absent.
        progress: optional ``progress(description, done, total)``, called with done 0 when a pass starts
            and after each view finishes it, e.g. ``("level 2 photometric", 3, 11)``.
        checkpoint: optional :class:`engine.run.checkpoint.PatchMatchCheckpoint`: every view's state is saved
            after each pass, and states saved by an interrupted run with the same inputs are reused.
        probe: optional :class:`~engine.patchmatch.probe.pixel_probe.PixelProbe`:
            traces of its pixels of its view (passes restored from a checkpoint are not traced); the maps are the
            same with or without it.
        history: optional; ``save_snapshot(level, pass_index, depths)`` receives every view's depth map that the
            geometric pass ``pass_index`` of ``level`` reads (``engine.run.pass_history.PassHistory``), so that one
            view can be re-run alone later (:func:`replay_view`).

    Views without source views or with a degenerate depth range are skipped with a warning and get
    empty (zero) maps; they still serve as source images for others. Invalid inputs (image/camera
    size mismatch, images smaller than the matching window, bad source indices, more than 32 sources)
    raise :class:`DeepCError`. Same inputs, options and seed give identical maps on any thread count.
    """
    options = (options or PatchMatchOptions()).validate()
    if not views:
        return []
    active = check_views(views, options)
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
        if history is not None:
            history.bind(views, options, n_levels)
        if probe is not None:
            probe.bind([v.name for v in views], [(v.camera.width, v.camera.height) for v in views],
                       [list(v.source_views) for v in views])
        return _run(views, options, active, n_levels, on_iter, on_stage, progress, checkpoint, probe, history)
    finally:
        numba.set_num_threads(old_threads)
        release_free_memory()  # the pooled per-pass arrays and the coarser levels' states (engine/core/heap_trim.py)


def view_pyramids(views: list[PatchMatchView | None], n_levels: int) -> tuple[list, list]:
    """Every view's images and cameras at levels 0 .. n_levels - 1 (None for a view given as None)."""
    images: list[list[np.ndarray] | None] = []
    cameras: list[list[Camera] | None] = []
    for v in views:
        if v is None:
            images.append(None)
            cameras.append(None)
            continue
        img0 = np.ascontiguousarray(v.image_gray, dtype=np.float32)
        imgs, cams = [], []
        for level in range(n_levels):
            w, h = level_size(v.camera.width, v.camera.height, level)
            imgs.append(area_resize(img0, w, h))
            cams.append(v.camera if level == 0 else v.camera.rescaled(w, h))
        images.append(imgs)
        cameras.append(cams)
    return images, cameras


def level_start(views: list[PatchMatchView], i: int, prev: ViewState | None, images: list, cameras: list, level: int,
                options: PatchMatchOptions, coarsest: bool = False) -> ViewState:
    """View ``i``'s state at the start of ``level`` as :func:`run_patchmatch` makes it from ``prev``, its state
    at the end of the coarser level (``images``, ``cameras``: the views' pyramids)."""
    return level_start_state(i, views[i], prev, images[i][level], cameras[i][level], level, coarsest, True, options)


def _pass_probe(probe: PixelProbe | None, i: int, st: ViewState, level: int, pass_index: int,
                detail: bool) -> PassProbe | None:
    """The probe's hook for pass ``pass_index`` of view ``i`` at ``level`` (None unless ``i`` is probed)."""
    if probe is None or probe.view != i:
        return None
    h, w = st.depth.shape
    return probe.pass_probe(level, pass_index, w, h, detail)


def _run(views: list[PatchMatchView], options: PatchMatchOptions, active: list[bool], n_levels: int,
         on_iter: Callable | None, on_stage: Callable | None, progress: ProgressFn | None,
         checkpoint: Any = None, probe: PixelProbe | None = None, history: Any = None) -> list[ViewMaps]:
    n_views = len(views)
    images, cameras = view_pyramids(views, n_levels)
    states: list[ViewState | None] = [None] * n_views
    step = 0
    done = 0  # iterations of all earlier passes (perturbation schedule 'global')
    n_active = sum(active)
    resume = _resume_states(checkpoint, images, n_levels)
    pool = BufferPool()  # the large per-pass arrays, reused from view to view (buffers.py)
    parked: dict[int, tuple[int, int]] = {}  # view -> the (level, pass) whose checkpoint holds its parked maps
    # every view's pass-start states for the probe (engine.run.probe_states.RunStates); a resumed run's earlier
    # passes are gone, so it records none
    record = getattr(history, "states", None) if resume is None else None
    if record is not None:
        record.begin([[images[i][lv].shape for lv in range(n_levels)] if active[i] else None for i in range(n_views)],
                     1 + options.geom_passes)
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
        if resume is None:
            # each view's start state is made just before its first pass here: until then it holds its coarser
            # state (parked), not two full states of every view at once
            starting = set(range(n_views))
            if coarsest:
                states = [None] * n_views
        else:
            states, starting = resume[2], set()  # this level's states are the resume point's
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
            if history is not None and snapshot is not None:
                history.save_snapshot(level, pass_index, snapshot)
            if progress is not None:
                progress(f"level {level} {kind}", 0, n_views)
            for i, v in enumerate(views):
                check_interrupt()
                _unpark(states, i, checkpoint, parked)
                if i in starting:
                    states[i] = level_start_state(i, v, states[i], images[i][level], cameras[i][level], level,
                                                  coarsest, active[i], options)
                    starting.discard(i)
                saved = None if checkpoint is None else checkpoint.load(level, pass_index, i, states[i].depth.shape)
                if saved is not None:
                    states[i] = ViewState.from_checkpoint(saved)
                    step += n_iter if active[i] else 0
                elif active[i]:
                    if record is not None:
                        record.state(i, level, pass_index, states[i].depth, states[i].normal)
                    step, ran = _run_view_pass(i, v, states[i], images, cameras, snapshot, level, pass_index,
                                               detail, options, on_iter, step, done,
                                               random_start=coarsest and pass_index == 0, pool=pool,
                                               on_stage=on_stage,
                                               probe=_pass_probe(probe, i, states[i], level, pass_index, detail))
                    if record is not None:  # a converged pass ends early, and a probe must replay it as long
                        record.ran(i, level, pass_index, ran)
                if record is not None and active[i] and pass_index == options.geom_passes:
                    record.state(i, level, "end", states[i].depth, states[i].normal)
                if checkpoint is not None and saved is None:
                    checkpoint.save(level, pass_index, i, states[i].checkpoint_arrays())
                if checkpoint is not None and active[i]:
                    _park(states, i, level, pass_index, parked)
                if progress is not None:
                    progress(f"level {level} {kind}", i + 1, n_views)
            done += n_iter
            if checkpoint is not None:
                checkpoint.pass_complete(level, pass_index)
        resume = None
    pool.clear()  # before the parked states come back
    for i in range(n_views):
        _unpark(states, i, checkpoint, parked)
    out = [final_maps(st, active[i]) for i, st in enumerate(states)]
    if on_stage is not None:
        on_stage("patchmatch_done", levels=n_levels, views=n_views)
    return out


def level_start_state(i: int, v: PatchMatchView, prev: ViewState | None, image: np.ndarray, cam: Camera, level: int,
                      coarsest: bool, active: bool, options: PatchMatchOptions) -> ViewState:
    """The state view ``i`` starts ``level`` with (Xu & Tao 2019 ACMM): random hypotheses at the coarsest level,
    else ``prev`` (its final state one level coarser) JBU-upsampled to ``image`` (H, W), with random hypotheses
    where upsampling left none. Empty maps for an inactive view. A pure function of its arguments (the random
    stream is keyed by seed, view and level), so the per-view tasks of ``engine.run.distributed`` call it too."""
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


def _park(states: list, i: int, level: int, pass_index: int, parked: dict[int, tuple[int, int]]) -> None:
    """Drop view ``i``'s normal, cost and selected views (20 B/px) until its next pass, when :func:`_unpark`
    reads them back from the checkpoint that has just saved them: between its passes a view is only a source, and
    a source's depth (kept) is all the other views' passes read. 79 MB of 11 views at 768x512."""
    states[i] = ViewState(states[i].depth, None, None, None)
    parked[i] = (level, pass_index)


def _unpark(states: list, i: int, checkpoint: Any, parked: dict[int, tuple[int, int]]) -> None:
    """Read view ``i``'s parked maps back from the checkpoint (nothing to do for a view that is not parked)."""
    where = parked.pop(i, None)
    if where is None:
        return
    saved = checkpoint.load(*where, i, states[i].depth.shape, reuse=False)
    if saved is None:
        raise DeepCError("a PatchMatch state saved during this run could not be read back (disk full or files "
                         "changed?): run again", checkpoint.folder)
    states[i] = ViewState.from_checkpoint(saved)


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
                   step: int, done_before: int = 0, random_start: bool = False, pool: BufferPool | None = None,
                   on_stage: Callable | None = None, probe: PassProbe | None = None, iterations: int | None = None,
                   box: Box | Callable[[int], Box] | None = None, regions: dict | None = None) -> tuple[int, int]:
    """Pass ``pass_index`` of view ``i`` at ``level`` (:func:`view_pass.run_view_level`) with its context built
    from the level's images and, in geometric passes, the ``snapshot`` of every view's depth; returns the step
    counter after it and the iterations the pass ran. ``regions``: the passes' fine-window regions by (level,
    pass), filled on first use (a function of the pass's start state alone: replays of one view share them)."""
    src_idx = list(v.source_views)
    widest = box(0) if callable(box) else box  # the pass's initial cost covers the widest box
    if regions is not None and (level, pass_index) in regions:
        region = regions[(level, pass_index)]
    else:
        region = fine_window_region(st.depth, st.normal, cameras[i][level], options, random_start, level)
        if regions is not None:
            regions[(level, pass_index)] = region
    ctx = build_context(images[i][level], cameras[i][level], [images[j][level] for j in src_idx],
                        [cameras[j][level] for j in src_idx], options,
                        [snapshot[j] for j in src_idx] if snapshot is not None else None, region, pool, box=widest)
    kind = "geometric" if pass_index > 0 else "photometric"
    first_step = step
    ran = 0

    def event(t: int, counts: np.ndarray, seconds: float) -> None:
        nonlocal ran
        ran = t + 1
        if on_iter is not None:
            on_iter(IterationEvent(view=i, view_name=v.name, level=level, pass_kind=kind, pass_index=pass_index,
                                   iteration=t, step=first_step + t, depth=readonly(st.depth),
                                   normal=readonly(st.normal), cost=readonly(st.cost),
                                   selected_views=readonly(st.selected_views), seconds=seconds,
                                   ncc_windows=int(counts[: K.CNT_PIXELS].sum()),
                                   pixel_updates=int(counts[K.CNT_PIXELS]), pixels_skipped=int(counts[K.CNT_SKIPPED])))

    run_view_level(st, ctx, options, float(v.depth_min), float(v.depth_max), view=i, level=level,
                   pass_index=pass_index, detail=detail, done_before=done_before, on_iteration=event, pool=pool,
                   probe=probe, iterations=iterations, box=box)
    if pool is not None:
        ctx.release(pool)
    planned = options.pass_iterations(pass_index)
    if on_stage is not None and ran < planned:
        on_stage("patchmatch_view_converged", view=i, view_name=v.name, level=level, pass_index=pass_index,
                 iterations=ran, planned=planned)
    # steps stay reserved for the planned iterations: a view's n-th iteration has the same step however its
    # earlier passes ended
    return step + planned, ran

def replay_view(views: list[PatchMatchView], view: int, snapshots: SnapshotFn, options: PatchMatchOptions | None = None,
                probe: PixelProbe | None = None, on_pass: PassFn | None = None,
                on_iter: Callable | None = None, pyramids: tuple[list, list] | None = None) -> ViewMaps:
    """Re-run the PatchMatch of view ``view`` alone: the same passes, random streams and kernels as
    :func:`run_patchmatch`, with every geometric pass reading the source depth maps ``snapshots`` gives
    (``engine.run.pass_history``). Given the snapshots the full run's geometric passes read, the result is that run's
    maps of this view, bit for bit.

    ``probe``: traces of the view's pixels (``probe.view`` must be ``view``); ``on_pass(level, pass_index,
    phase, state, images, cameras)``: called with phase "start" before each pass (the state the pass starts
    from) and "end" after each level's last pass (``images``, ``cameras``: every view's pyramid, None for views
    the replay does not need); the state must not be kept without a copy. ``on_iter(event)``: after every
    red-black iteration (an ``IterationEvent``; its ``iteration`` tells how many a converged pass ran).
    ``pyramids`` (images, cameras): the views' pyramids (:func:`view_pyramids`), if already made."""
    options = (options or PatchMatchOptions()).validate()
    active = check_views(views, options)
    if not 0 <= view < len(views):
        raise DeepCError(f"view {view} does not exist (the scene has {plural(len(views), 'view')})")
    if not active[view]:
        raise DeepCError(f"view {view} ({views[view].name}) has no PatchMatch (no source view or no depth range)")
    if probe is not None:
        if probe.view != view:
            raise DeepCError(f"probe: the probe is for view {probe.view}, the replay is of view {view}")
        probe.bind([v.name for v in views], [(v.camera.width, v.camera.height) for v in views],
                   [list(v.source_views) for v in views])
    n_levels = effective_levels(views, options)
    v = views[view]
    if pyramids is None:
        needed = {view, *v.source_views}
        pyramids = view_pyramids([u if j in needed else None for j, u in enumerate(views)], n_levels)
    images, cameras = pyramids
    old_threads = numba.get_num_threads()
    if options.num_threads > 0:
        numba.set_num_threads(min(options.num_threads, numba.config.NUMBA_NUM_THREADS))
    try:
        st: ViewState | None = None
        done = 0
        pool = BufferPool()
        for level in range(n_levels - 1, -1, -1):
            coarsest = level == n_levels - 1
            pool.clear()
            st = level_start_state(view, v, st, images[view][level], cameras[view][level], level, coarsest, True,
                                   options)
            for pass_index in range(1 + options.geom_passes):
                check_interrupt()
                geometric = pass_index > 0
                if on_pass is not None:
                    on_pass(level, pass_index, "start", st, images, cameras)
                snapshot = None
                if geometric:
                    got = snapshots(level, pass_index, list(v.source_views))
                    snapshot = [got.get(j) for j in range(len(views))]
                run_view_pass(views, view, st, images, cameras, snapshot, level, pass_index, n_levels, options, done,
                              probe, pool, on_iter=on_iter)
                done += options.pass_iterations(pass_index)
            if on_pass is not None:
                on_pass(level, options.geom_passes, "end", st, images, cameras)
    finally:
        numba.set_num_threads(old_threads)
    valid = st.depth > 0
    st.normal[~valid] = 0.0
    st.cost[~valid] = 0.0
    return ViewMaps(st.depth, st.normal, st.cost, st.selected_views)


def run_view_pass(views: list[PatchMatchView], i: int, st: ViewState, images: list, cameras: list,
                  snapshot: list | None, level: int, pass_index: int, n_levels: int, options: PatchMatchOptions,
                  done_before: int, probe: PixelProbe | None = None, pool: BufferPool | None = None,
                  origin: tuple[int, int] = (0, 0), on_iter: Callable | None = None, iterations: int | None = None,
                  box: Box | Callable[[int], Box] | None = None, regions: dict | None = None) -> None:
    """Pass ``pass_index`` of view ``i`` at ``level`` on ``st`` in place, as :func:`run_patchmatch` runs it (detail
    restorer in a finer level's photometric pass, random start at the coarsest's): ``images``, ``cameras``: every
    view's pyramid (``images[i][level]`` may be a crop of the level's image at ``origin`` (x, y), with its camera;
    ``probe`` then traces the probed pixels inside it); ``snapshot``: the views' depth maps a geometric pass reads;
    ``done_before``: iterations of all earlier passes; ``on_iter(event)`` after each iteration; ``iterations``: run
    exactly this many (the count a converged pass of the run ran; None: the schedule's, ended by convergence);
    ``box`` (x0, y0, x1, y1), or ``box(j)`` per half-step: update only those pixels (``view_pass.run_view_level``);
    ``regions``: the fine-window regions of the view's passes, kept across calls (:func:`_run_view_pass`)."""
    coarsest = level == n_levels - 1
    detail = pass_index == 0 and not coarsest and options.detail_restorer
    pass_probe = None
    if probe is not None and probe.view == i:
        w, h = level_size(views[i].camera.width, views[i].camera.height, level)
        pass_probe = probe.pass_probe(level, pass_index, w, h, detail, origin, st.depth.shape)
    _run_view_pass(i, views[i], st, images, cameras, snapshot, level, pass_index, detail, options, on_iter, 0,
                   done_before, random_start=coarsest and pass_index == 0, pool=pool, probe=pass_probe,
                   iterations=iterations, box=box, regions=regions)
