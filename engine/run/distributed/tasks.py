"""The per-view tasks of a run: pure functions of (scene, view, options, level, pass) that read their inputs from
and write their outputs to the run folder atomically.

A task holds one view and its source views at the current pyramid level, never the whole scene's maps nor the
scene itself: its job carries a :class:`engine.scene.SceneViews` with the views it touches (its view, and its source
views for PatchMatch and the counter maps; cameras, depth ranges, source views as the driver's scene has them), so a
worker never reads the sparse model, and its images go through one cache of ``engine.scene.TASK_IMAGE_CACHE`` views
per process: a worker's memory does not grow with the scene's number of views. PatchMatch
states travel between passes as the checkpoint's files (``engine.run.checkpoint``: ``OUT/.deepc-resume/L{level}_P{pass}/
{view}.npz``), each read only if its SHA-256 is the one the driver recorded. A task killed half-way leaves no file
(atomic writes) and, run again anywhere, writes the same bytes: the engine's random numbers are keyed by (seed,
view, level, pass, iteration, pixel) (``engine.patchmatch.rng``), so a view's pass depends on its inputs only.
"""

from __future__ import annotations

import dataclasses
import hashlib
import time
from contextlib import contextmanager
from functools import lru_cache
from pathlib import Path
from typing import Any

import numba
import numpy as np

from engine.confidence.options import ConfidenceOptions
from engine.consistency import CounterOptions
from engine.core.camera import Camera
from engine.core.errors import DeepCError
from engine.core.observer import IterationEvent
from engine.io.dense import read_dense_map, write_dense_map
from engine.patchmatch import PatchMatchOptions, ViewMaps
from engine.patchmatch.multiscale import final_maps, level_start_state, run_view_pass
from engine.patchmatch.pyramid import area_resize, level_size
from engine.patchmatch.state import ViewState
from engine.refinement.options import RefinementOptions
from engine.refinement.refine import RefinedMap
from engine.refinement.views import refine_views
from engine.run.checkpoint import PatchMatchCheckpoint, write_state
from engine.run.folder import read_map, write_map
from engine.run.per_view import patchmatch_view, view_confidence, view_counter
from engine.scene import SceneViews


@dataclasses.dataclass(frozen=True)
class PassJob:
    """Pass ``pass_index`` of view ``view`` at ``level`` (of ``n_levels``); ``scene``: the view and its source views.

    ``inputs``: checkpoint file name -> SHA-256 of every state the task reads whole (its own state after the
    previous pass, or after the coarser level's last pass; in geometric passes the source views' states whose depth
    digest the driver does not know, after a resume). ``depths``: checkpoint file name -> SHA-256 of the depth
    array alone, for the source views whose depth it reads alone (a sixth of the state's bytes).
    ``done_before``: iterations of all earlier passes (the 'global' perturbation schedule). ``threads``: numba
    threads (0 = the worker's default; ``options.num_threads`` wins when set)."""

    scene: SceneViews
    folder: str
    view: int
    level: int
    pass_index: int
    n_levels: int
    active: bool
    options: PatchMatchOptions
    inputs: dict[str, str]
    done_before: int
    threads: int = 0
    depths: dict[str, str] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass(frozen=True)
class PassResult:
    """What a PatchMatch task returns: the SHA-256 of the state it wrote and of its depth array alone, its seconds
    and NCC windows."""

    sha256: str
    seconds: float
    ncc_windows: int
    depth_sha256: str = ""


@dataclasses.dataclass(frozen=True)
class FinishJob:
    """The final maps and the counter map of ``view``: reads the states after pass ``pass_index`` of level 0 of the
    view and its sources' depth (``inputs`` and ``depths`` as in :class:`PassJob`), writes depth, normal, cost and
    counter maps to ``out``."""

    scene: SceneViews
    folder: str
    out: str
    view: int
    pass_index: int
    active: bool
    inputs: dict[str, str]
    counter: CounterOptions
    threads: int = 0
    depths: dict[str, str] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass(frozen=True)
class ConfidenceJob:
    """The confidence map of ``view`` from the depth, normal and counter maps in ``out`` with the network in
    ``weights`` (None: the shipped weights); writes the confidence map, and the map before the back-facing rule (the
    refinement's weights) as ``raw_dir/{name}.bin`` when ``raw_dir`` is set."""

    scene: SceneViews
    out: str
    view: int
    options: ConfidenceOptions
    weights: str | None
    raw_dir: str = ""
    threads: int = 0


@contextmanager
def numba_threads(threads: int, options_threads: int = 0):
    """Use ``options_threads`` (when > 0) or ``threads`` numba threads in this worker while the task runs."""
    n = options_threads if options_threads > 0 else threads
    old = numba.get_num_threads()
    if n > 0:
        numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    try:
        yield
    finally:
        numba.set_num_threads(old)


def state_reader(folder: str, inputs: dict[str, str]) -> PatchMatchCheckpoint:
    """A checkpoint that reads (and verifies) only the states named in ``inputs``; it never writes a manifest."""
    reader = PatchMatchCheckpoint(folder, resume=True)
    reader.entries = dict(inputs)
    return reader


def load_state(reader: PatchMatchCheckpoint, level: int, pass_index: int, view: int, shape: tuple[int, int]
               ) -> ViewState:
    """A verified saved state; a missing or damaged one is an error (its producer's task must run again)."""
    saved = reader.load(level, pass_index, view, shape)
    if saved is None:
        raise DeepCError(f"state of view {view} after level {level} pass {pass_index} is missing or damaged",
                         reader.folder)
    return ViewState.from_checkpoint(saved)


def depth_digest(depth: np.ndarray) -> str:
    """SHA-256 of a depth map's float32 bytes (what :func:`load_depth` verifies)."""
    return hashlib.sha256(np.ascontiguousarray(depth, np.float32).tobytes()).hexdigest()


def load_depth(folder: str, inputs: dict[str, str], depths: dict[str, str], level: int, pass_index: int, view: int,
               shape: tuple[int, int]) -> np.ndarray:
    """A view's depth after a pass: only the depth array of its state file when ``depths`` holds its digest (the
    archive's other members are not read), else from the whole state verified against ``inputs``."""
    name = PatchMatchCheckpoint.file_name(level, pass_index, view)
    if name not in depths:
        return load_state(state_reader(folder, inputs), level, pass_index, view, shape).depth
    try:
        with np.load(Path(folder) / name, allow_pickle=False) as archive:
            depth = archive["Z"]
    except Exception as exc:  # noqa: BLE001  (np.load raises assorted types on a damaged archive)
        raise DeepCError(f"depth of view {view} after level {level} pass {pass_index} is unreadable ({exc})",
                         folder) from None
    if depth.dtype != np.float32 or depth.shape != tuple(shape) or depth_digest(depth) != depths[name]:
        raise DeepCError(f"depth of view {view} after level {level} pass {pass_index} is damaged", folder)
    return depth


def level_input(scene: SceneViews, j: int, level: int) -> tuple[np.ndarray, Camera]:
    """View ``j``'s grey image (H, W) f32 and camera at pyramid ``level`` (as ``engine.patchmatch.multiscale._run``
    builds its pyramid: each level area-resized from the working resolution)."""
    cam = scene.views[j].camera
    w, h = level_size(cam.width, cam.height, level)
    image = area_resize(np.ascontiguousarray(scene.gray(j), dtype=np.float32), w, h)
    return image, cam if level == 0 else cam.rescaled(w, h)


def patchmatch_view_pass(job: PassJob) -> PassResult:
    """Run one view's pass and write its state into the checkpoint folder (see the module docstring)."""
    t0 = time.perf_counter()
    options = job.options
    with numba_threads(job.threads, options.num_threads):
        scene = job.scene
        i, level, p = job.view, job.level, job.pass_index
        v = patchmatch_view(scene, i)
        coarsest = level == job.n_levels - 1
        reader = state_reader(job.folder, job.inputs)
        needed = [i, *v.source_views] if job.active else [i]
        images: dict[int, dict[int, np.ndarray]] = {}
        cameras: dict[int, dict[int, Camera]] = {}
        for j in needed:
            image, cam = level_input(scene, j, level)
            images[j], cameras[j] = {level: image}, {level: cam}
        shape = images[i][level].shape
        snapshot = None
        if p == 0:
            prev = None
            if job.active and not coarsest:
                w, h = level_size(v.camera.width, v.camera.height, level + 1)
                prev = load_state(reader, level + 1, options.geom_passes, i, (h, w))
            st = level_start_state(i, v, prev, images[i][level], cameras[i][level], level, coarsest, job.active,
                                   options)
        else:
            st = load_state(reader, level, p - 1, i, shape)
            if job.active:
                snapshot = {j: load_depth(job.folder, job.inputs, job.depths, level, p - 1, j, images[j][level].shape)
                            for j in v.source_views}
        windows = []
        if job.active:  # as run_patchmatch runs it (detail restorer, random start at the coarsest level)
            run_view_pass({i: v}, i, st, images, cameras, snapshot, level, p, job.n_levels, options, job.done_before,
                          on_iter=lambda event: windows.append(event.ncc_windows))
        arrays = st.checkpoint_arrays()
        sha = write_state(job.folder, level, p, i, arrays)
    return PassResult(sha, time.perf_counter() - t0, int(sum(windows)), depth_digest(arrays["Z"]))


def finish_view(job: FinishJob) -> None:
    """Write a view's final depth, normal and cost maps and its counter map (Kuhn et al. 2020, §3.1)."""
    with numba_threads(job.threads):
        scene = job.scene
        i = job.view
        v = patchmatch_view(scene, i)
        reader = state_reader(job.folder, job.inputs)
        maps = final_maps(load_state(reader, 0, job.pass_index, i, v.image_gray.shape), job.active)
        sources = [patchmatch_view(scene, j) for j in v.source_views]
        depths = [load_depth(job.folder, job.inputs, job.depths, 0, job.pass_index, j, s.image_gray.shape)
                  for j, s in zip(v.source_views, sources, strict=True)]
        counter = view_counter(v, sources, maps, depths, job.counter)
        for kind, array in (("depth", maps.depth), ("normal", maps.normal), ("cost", maps.cost),
                            ("counter", counter)):
            write_map(job.out, kind, v.name, array)


@lru_cache(maxsize=2)
def _model(weights: str | None) -> Any:
    from engine.confidence.weights import load_weights  # lazy: torch

    return load_weights(weights)


def confidence_view(job: ConfidenceJob) -> None:
    """Write a view's confidence map (the network of Kuhn et al. 2020, §3.2) from its maps in the run folder."""
    from engine.confidence.inference import torch_threads  # lazy: torch

    scene = job.scene
    view = scene.views[job.view]
    depth, normal, counter = (read_map(job.out, kind, view.name) for kind in ("depth", "normal", "counter"))
    if depth is None or normal is None or counter is None:
        raise DeepCError(f"maps of view {view.name} missing", Path(job.out))
    maps = ViewMaps(depth, normal, np.zeros_like(depth), np.zeros(depth.shape, np.uint32))
    with torch_threads(job.options.num_threads or job.threads):
        c, raw = view_confidence(scene.image(job.view), maps, counter.astype(np.uint8), len(view.source_views),
                                 job.options, _model(job.weights))
    write_map(job.out, "confidence", view.name, c)
    if job.raw_dir:
        write_dense_map(Path(job.raw_dir) / f"{view.name}.bin", raw)


@dataclasses.dataclass(frozen=True)
class RefineJob:
    """Rossi et al. 2020's refinement of ``view`` from its PatchMatch depth and normal maps in ``out``, weighted
    by ``confidence`` (H, W) f32 (the network's, before the back-facing rule unless the options say otherwise), or,
    when it is None, by the map in ``confidence_file`` (what the confidence task wrote: no map travels in the job)."""

    scene: SceneViews
    out: str
    view: int
    confidence: np.ndarray | None
    options: RefinementOptions
    threads: int = 0
    confidence_file: str = ""


class _OneView:
    """A scene seen as holding only its view ``i`` (what ``refine_views`` reads: views, image)."""

    def __init__(self, scene: SceneViews, i: int):
        self.scene, self.i, self.views = scene, i, [scene.views[i]]

    def image(self, _index: int) -> np.ndarray:
        return self.scene.image(self.i)


def refine_view(job: RefineJob) -> RefinedMap | None:
    """One view's refined map (None where it has no data to refine from; a warning names it)."""
    with numba_threads(job.threads):
        scene = job.scene
        name = scene.views[job.view].name
        depth, normal = read_map(job.out, "depth", name), read_map(job.out, "normal", name)
        if depth is None or normal is None:
            raise DeepCError(f"maps of view {name} missing", Path(job.out))
        confidence = job.confidence
        if confidence is None:
            confidence = read_dense_map(job.confidence_file, channels=1)
        return refine_views(_OneView(scene, job.view), [depth], [normal], [confidence], job.options)[0]


def pass_event(i: int, name: str, level: int, pass_index: int, iteration: int, step: int, state: ViewState,
               result: PassResult) -> IterationEvent:
    """The event the driver sends its observer when a view's pass task ends: the view's state after the pass, as
    the last iteration's event of an in-process run (the rerun stream draws it)."""
    return IterationEvent(view=i, view_name=name, level=level, pass_kind="geometric" if pass_index else "photometric",
                          pass_index=pass_index, iteration=iteration, step=step, depth=state.depth,
                          normal=state.normal, cost=state.cost, selected_views=state.selected_views,
                          seconds=result.seconds, ncc_windows=result.ncc_windows)
