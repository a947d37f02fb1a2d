"""Refined maps for a finished run, without re-running PatchMatch.

``deepc run --pipeline full`` writes refined maps as it goes. :func:`refine_run` adds them to a finished vanilla
(or fast) run — network-1 confidence of the run's maps, refinement, counter maps of the refined maps (the
stages of :mod:`engine.run.pipeline`) — so that the run can train the second confidence network
(``load_run(..., refined=True)``, ``deepc train --refined``). Where they go and how their stamp decides reuse:
:mod:`engine.run.folder`.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from engine.confidence.weights import DEFAULT_WEIGHTS, load_weights
from engine.core.errors import DeepCError
from engine.patchmatch import ViewMaps
from engine.run.folder import (
    file_sha256,
    map_path,
    maps_digest,
    read_map,
    read_run_metrics,
    refined_maps_complete,
    refinement_key,
    run_scene,
    write_refined_maps,
    write_stamp,
)
from engine.run.pipeline import (
    PipelineOptions,
    compute_counter_maps,
    confidence_stage,
    patchmatch_views,
    refinement_confidence,
    refinement_stage,
)


@dataclasses.dataclass
class RefinedRun:
    """What :func:`refine_run` did: ``reused`` cached maps, or refined ``views`` views in ``seconds``."""

    run_dir: Path
    reused: bool
    views: int
    seconds: dict[str, float]


def refine_run(run_dir: str | Path, weights: str | Path | None = None, options=None, model: Any = None,
               log: Callable[[str], None] | None = None) -> RefinedRun:
    """Write the refined maps of the finished run ``run_dir`` into ``run_dir/refined/`` (module doc).

    ``weights``: network-1 weights whose confidence guides the refinement (default: ``options.confidence.weights``,
    else the shipped weights); ``model``: those weights already loaded (saves loading them per run).
    ``options``: an :class:`engine.run.pipeline.PipelineOptions` (its confidence, refinement and counter sections
    count). Maps whose stamp matches are reused. ``log`` gets a line per refined view.
    """
    run_dir = Path(run_dir)
    options = (options or PipelineOptions()).validate()
    weights = Path(weights or options.confidence.weights or DEFAULT_WEIGHTS)
    if not weights.is_file():
        raise DeepCError("confidence weights file not found", weights)
    scene = run_scene(run_dir)
    names = [v.name for v in scene.views]
    maps, counter = [], []
    for v in scene.views:
        arrays = {}
        for kind in ("depth", "normal", "counter"):
            arrays[kind] = read_map(run_dir, kind, v.name)
            if arrays[kind] is None:
                raise DeepCError(f"run has no {kind} map for view {v.name}", map_path(run_dir, kind, v.name))
        if arrays["depth"].shape != (v.camera.height, v.camera.width):
            raise DeepCError(f"{arrays['depth'].shape[1]}x{arrays['depth'].shape[0]} depth map, but the scene's "
                             f"view {v.name} is {v.camera.width}x{v.camera.height}",
                             map_path(run_dir, "depth", v.name))
        depth = arrays["depth"]
        maps.append(ViewMaps(depth, arrays["normal"], np.zeros_like(depth), np.zeros(depth.shape, np.uint32)))
        counter.append(arrays["counter"])
    key = refinement_key(scene, file_sha256(weights), options,
                         maps_digest(names, [m.depth for m in maps], [m.normal for m in maps], counter))
    if refined_maps_complete(run_dir, names, key):
        return RefinedRun(run_dir, True, 0, {})
    if read_run_metrics(run_dir).pipeline == "full" and (run_dir / "refined").is_dir():
        raise DeepCError("the refined maps of this full run were made with other weights or options (or before "
                         "stamps existed); refining again would overwrite outputs of the run (refine a vanilla run "
                         "instead)", run_dir / "refined")

    seconds: dict[str, float] = {}
    t = time.perf_counter()
    model = model if model is not None else load_weights(weights)
    raw: list[np.ndarray] = []
    confidence = refinement_confidence(confidence_stage(scene, maps, counter, options.confidence, model, raw=raw),
                                       raw, options.refinement)
    seconds["confidence"] = time.perf_counter() - t

    t = last = time.perf_counter()

    def view_done(i: int, n: int, result) -> None:
        nonlocal last
        now = time.perf_counter()
        if log is not None:
            state = "refined" if result is not None else "left empty (no data)"
            log(f"{scene.name}: view {i + 1}/{n} {names[i]} {state} ({now - last:.1f} s)")
        last = now

    refined = refinement_stage(scene, maps, confidence, options.refinement, progress=view_done)
    seconds["refinement"] = time.perf_counter() - t
    t = time.perf_counter()
    refined_counter = compute_counter_maps(patchmatch_views(scene), refined, options.counter)
    seconds["counter"] = time.perf_counter() - t
    write_refined_maps(run_dir, names, refined, refined_counter)
    write_stamp(run_dir, key, weights, seconds)
    return RefinedRun(run_dir, False, len(names), seconds)
