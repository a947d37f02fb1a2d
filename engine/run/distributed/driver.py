"""The driver of a run whose per-view work runs as tasks (``deepc run --executor dask``): PatchMatch one task per
view and pass (the schedule of ``engine.patchmatch.multiscale``: levels coarse to fine, a photometric pass then
geometric passes, every view of a pass before the next pass), then one task per view for its final maps and counter
map, then one per view for its confidence. Maps equal ``--executor local``'s byte for byte.

Each job carries the views its task touches (``Scene.subset``: a few kB), so a worker never loads the scene's
sparse model. The driver holds no map while the tasks run, and images only in its scene's bounded cache: it records
each state's SHA-256 in the checkpoint's manifest (``engine.run.checkpoint``), so ``--resume`` continues an interrupted
run with either executor, and the SHA-256 of each state's depth array, so that a geometric pass (and the counter
maps) read only their source views' depth from the state files (a sixth of their bytes; whole states, verified by
the manifest, after a resume). After the
tasks, ``engine.run.distributed.streamed`` fuses and scores the maps from the run folder without reading them all back.
"""

from __future__ import annotations

import shutil
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from engine.confidence.options import ConfidenceOptions
from engine.consistency import CounterOptions
from engine.io.dense import read_dense_map
from engine.patchmatch import PatchMatchOptions, ViewMaps
from engine.patchmatch.multiscale import check_views, effective_levels, final_maps
from engine.patchmatch.pyramid import level_size
from engine.refinement.options import RefinementOptions
from engine.refinement.refine import RefinedMap
from engine.run.checkpoint import CHECKPOINT_DIR, PatchMatchCheckpoint
from engine.run.distributed.executor import Executor
from engine.run.distributed.streamed import read_view_map
from engine.run.distributed.tasks import (
    ConfidenceJob,
    FinishJob,
    PassJob,
    PassResult,
    RefineJob,
    confidence_view,
    finish_view,
    load_state,
    pass_event,
    patchmatch_view_pass,
    refine_view,
    state_reader,
)
from engine.run.per_view import SceneView
from engine.scene import Scene, SceneViews

ProgressFn = Callable[[str, int, int], Any]
RAW_CONFIDENCE_DIR = ".deepc-raw-confidence"  # the refinement's weights between the two stages (removed)
MANIFEST_EVERY_S = 1.0  # the checkpoint's manifest is rewritten at most this often while a pass runs


def pass_schedule(options: PatchMatchOptions, n_levels: int) -> list[tuple[int, int, int]]:
    """(level, pass, iterations of all earlier passes) of every pass in the order the engine runs them."""
    out, done = [], 0
    for level in range(n_levels - 1, -1, -1):
        for p in range(1 + options.geom_passes):
            out.append((level, p, done))
            done += options.pass_iterations(p)
    return out


def run_patchmatch_tasks(scene: Scene, out_dir: str | Path, options: PatchMatchOptions, counter: CounterOptions,
                         executor: Executor, observer: Any = None, progress: ProgressFn | None = None,
                         checkpoint: PatchMatchCheckpoint | None = None, read_back: bool = True
                         ) -> tuple[list[ViewMaps], list[np.ndarray]] | None:
    """PatchMatch and counter maps of every view as tasks on ``executor``; the tasks write the depth, normal, cost
    and counter maps into ``out_dir``. Returns the maps and counter maps (read back), like ``run_patchmatch`` and
    ``compute_counter_maps``, or None without ``read_back`` (the driver then holds no map). ``observer``, ``progress``
    and ``checkpoint`` as for ``run_patchmatch``; the observer gets one ``on_iteration`` per view and pass (when its
    task ends) instead of one per iteration. Without a checkpoint the states go through ``out_dir/.deepc-resume`` all
    the same (removed at the end)."""
    options = options.validate()
    views = [SceneView(scene, i) for i in range(len(scene.views))]
    if not views:
        return ([], []) if read_back else None
    active = check_views(views, options)
    n_levels = effective_levels(views, options)
    if n_levels < options.levels:
        warnings.warn(f"PatchMatch: images too small for {options.levels} levels; using {n_levels}", stacklevel=2)
    own = checkpoint is None
    if own:
        checkpoint = PatchMatchCheckpoint(Path(out_dir) / CHECKPOINT_DIR, resume=False)
    checkpoint.bind(views, options, n_levels)
    folder, n = str(checkpoint.folder), len(views)
    on_iter = getattr(observer, "on_iteration", None)
    on_stage = getattr(observer, "on_stage", None)
    schedule = pass_schedule(options, n_levels)
    resume = checkpoint.resume_point()
    first = 0 if resume is None else next((k + 1 for k, (lv, p, _) in enumerate(schedule) if (lv, p) == resume), 0)
    step = sum(options.pass_iterations(p) for _, p, _ in schedule[:first]) * sum(active)
    flushed = time.monotonic()
    known: dict[str, str] = {}  # depth digests of the previous pass's states (none for passes before a resume)
    for k in range(first, len(schedule)):
        level, p, done = schedule[k]
        shapes = [level_size(v.camera.width, v.camera.height, level)[::-1] for v in views]
        kind = "geometric" if p else "photometric"
        n_iter = options.pass_iterations(p)
        if on_stage is not None:
            on_stage("patchmatch_pass", level=level, pass_kind=kind, pass_index=p, iterations=n_iter)
        description = f"level {level} {kind}"
        if progress is not None:
            progress(description, 0, n)
        # states an interrupted run saved for this pass are verified and kept
        todo = [i for i in range(n) if checkpoint.load(level, p, i, shapes[i]) is None]
        finished = n - len(todo)
        if progress is not None and finished:
            progress(description, finished, n)
        previous = None if k == 0 else schedule[k - 1][:2]
        jobs = []
        for i in todo:
            whole, depths = _inputs(checkpoint, known, previous, i, views[i].source_views if p else [])
            jobs.append(PassJob(_own(scene, i), folder, i, level, p, n_levels, active[i], options, whole, done,
                                executor.threads, depths))
        written: dict[str, str] = {}  # the depth digests of this pass's states (the next pass reads depth alone)

        def ended(index: int, result: PassResult, level=level, p=p, description=description, todo=todo,
                  shapes=shapes, n_iter=n_iter, written=written) -> None:
            nonlocal finished, step
            nonlocal flushed
            i = todo[index]
            # the manifest (every entry) at most once a second: a stopped driver loses at most a second of tasks
            flush = time.monotonic() - flushed > MANIFEST_EVERY_S
            checkpoint.record(level, p, i, result.sha256, write=flush)
            written[PatchMatchCheckpoint.file_name(level, p, i)] = result.depth_sha256
            flushed = time.monotonic() if flush else flushed
            finished += 1
            if on_iter is not None and active[i]:
                state = load_state(state_reader(folder, checkpoint.entries), level, p, i, shapes[i])
                step += n_iter
                on_iter(pass_event(i, views[i].name, level, p, n_iter - 1, step - 1, state, result))
            if progress is not None:
                progress(description, finished, n)

        try:
            executor.map(patchmatch_view_pass, jobs, ended)
        finally:  # a stopped run keeps every state its tasks finished (--resume)
            checkpoint.flush()
        checkpoint.pass_complete(level, p)
        known = written
    last = (0, options.geom_passes)
    finish = []
    for i in range(n):
        whole, depths = _inputs(checkpoint, known, last, i, views[i].source_views)
        finish.append(FinishJob(_own(scene, i), folder, str(out_dir), i, last[1], active[i], whole, counter,
                                executor.threads, depths))
    executor.map(finish_view, finish)
    result = None
    if read_back:
        reader = state_reader(folder, checkpoint.entries)
        result = ([final_maps(load_state(reader, *last, i, (v.camera.height, v.camera.width)), active[i])
                   for i, v in enumerate(views)],
                  [read_view_map(out_dir, "counter", v.name).astype(np.uint8) for v in views])
    if own:
        checkpoint.clear()
    if on_stage is not None:
        on_stage("patchmatch_done", levels=n_levels, views=n)
    return result


def _own(scene: Scene, i: int) -> SceneViews:
    """What a PatchMatch or counter task of view ``i`` reads of the scene: the view and its source views."""
    return scene.subset([i, *scene.views[i].source_views])


def _inputs(checkpoint: PatchMatchCheckpoint, known: dict[str, str], at: tuple[int, int] | None, view: int,
            sources: list[int]) -> tuple[dict[str, str], dict[str, str]]:
    """What a task after pass ``at`` reads (nothing before the first pass): (checkpoint file name -> SHA-256 of the
    states it reads whole: ``view``'s, and a source's whose depth digest is not ``known``; file name -> depth
    digest of the sources whose depth it reads alone)."""
    if at is None:
        return {}, {}
    whole, depths = {}, {}
    for j in [view, *sources]:
        name = PatchMatchCheckpoint.file_name(*at, j)
        if j != view and known.get(name):
            depths[name] = known[name]
        elif name in checkpoint.entries:
            whole[name] = checkpoint.entries[name]
    return whole, depths


def run_confidence_tasks(scene: Scene, out_dir: str | Path, options: ConfidenceOptions, executor: Executor,
                         want_raw: bool, read_back: bool = True) -> tuple[list[np.ndarray] | None,
                                                                       StoredMaps | None]:
    """Confidence maps of every view (one task each, from the maps the PatchMatch tasks wrote into ``out_dir``;
    they write the confidence maps). Returns them (read back; None without ``read_back``) and, with ``want_raw``,
    the maps before the back-facing rule (the refinement's weights) as :class:`StoredMaps`: the tasks write them into
    ``out_dir/.deepc-raw-confidence`` and the driver holds none (:func:`run_refinement_tasks` hands its tasks the
    files, then removes them)."""
    raw = StoredMaps(Path(out_dir) / RAW_CONFIDENCE_DIR, [v.name for v in scene.views]) if want_raw else None
    if raw is not None:
        raw.remove()  # an interrupted run's
    raw_dir = str(raw.folder) if raw is not None else ""
    jobs = [ConfidenceJob(scene.subset([i]), str(out_dir), i, options, options.weights or None, raw_dir,
                          executor.threads) for i in range(len(scene.views))]
    executor.map(confidence_view, jobs)
    confidence = [read_view_map(out_dir, "confidence", v.name) for v in scene.views] if read_back else None
    return confidence, raw


def run_refinement_tasks(scene: Scene, out_dir: str | Path, confidence: Sequence[np.ndarray],
                         options: RefinementOptions, executor: Executor,
                         progress: Callable[[int, int, Any], None] | None = None) -> list[RefinedMap | None]:
    """Rossi et al. 2020's refinement of every view (one task each, from the PatchMatch maps in ``out_dir``), as
    ``engine.refinement.views.refine_views`` returns it; ``progress(i, n, result)`` as each view's task ends.
    ``confidence``: the weights per view, in memory (each job carries its map), or :class:`StoredMaps` (each task
    reads its file; they are removed once every task ended)."""
    n = len(scene.views)
    stored = isinstance(confidence, StoredMaps)
    jobs = [RefineJob(scene.subset([i]), str(out_dir), i, None if stored else confidence[i], options, executor.threads,
                      str(confidence.path(i)) if stored else "") for i in range(n)]
    refined = executor.map(refine_view, jobs, None if progress is None else lambda i, r: progress(i, n, r))
    if stored:
        confidence.remove()
    return refined


class StoredMaps(Sequence):
    """One-channel maps of views as ``folder/{name}.bin`` (float32 as written), read when indexed: the
    refinement's weights, which the driver passes on without holding them."""

    def __init__(self, folder: Path, names: list[str]):
        self.folder, self.names = Path(folder), list(names)

    def __len__(self) -> int:
        return len(self.names)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(len(self)))]
        return read_dense_map(self.path(i), channels=1)

    def path(self, i: int) -> Path:
        """The file of view ``i``'s map."""
        return self.folder / f"{self.names[i]}.bin"

    def remove(self) -> None:
        """Delete the folder and every map in it."""
        shutil.rmtree(self.folder, ignore_errors=True)
