"""Refined maps of a run folder, and the stamp that says how they were made.

    RUN/refined/{depth,normal,counter}_maps/<name>.bin   refined depth, normals and their own counter maps
    RUN/refined/confidence_maps/<name>.bin               confidence of the refined maps (``--pipeline full``)
    RUN/refined/stamp.json                               what the refined maps were made from (below)

``deepc run --pipeline full`` writes them as it goes. :func:`refine_run` adds them to a finished vanilla
(or fast) run without re-running PatchMatch — network-1 confidence of the run's maps, refinement, counter
maps of the refined maps (SPEC.md §6.6b), the stages of :mod:`engine.pipeline` — so that the run can train
the second confidence network (``load_run(..., refined=True)``, ``deepc train --refined``).

The stamp's ``key`` holds everything that determines the refined maps: the SHA-256 of the network-1
weights file, the options of confidence inference, refinement and counter maps, the scene and its options,
a digest of the run's own depth, normal and counter maps, and the engine version. :func:`refine_run`
reuses refined maps only when the stored key equals the new one and every map exists. The stamp is
written last and removed before any map is rewritten, so an interrupted refinement is never reused.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from engine import __version__
from engine.errors import DeepCError
from engine.interrupt import check_interrupt
from engine.io.outputs import map_path, read_map, read_metrics, write_json, write_map

STAMP = Path("refined") / "stamp.json"
#: refinement options that act only after the refined maps exist (filtering before fusion, sky filter)
POST_REFINEMENT = ("refined_conf_tau", "sky_filter", "keep_confident")
#: confidence options that change the predicted values (tau and refined_weights act elsewhere)
INFERENCE = ("tile", "overlap", "bf16", "zero_backfacing")
#: the maps of a refined run that every refined run has (confidence only where a second network ran)
REFINED_KINDS = ("refined_depth", "refined_normal", "refined_counter")


def file_sha256(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def maps_digest(names: list[str], depths: list[np.ndarray], normals: list[np.ndarray],
                counters: list[np.ndarray]) -> str:
    """Hex SHA-256 of the per-view input maps as float32 (what a run folder stores, so in-memory maps of a
    pipeline and the same maps read back from its folder give the same digest)."""
    digest = hashlib.sha256()
    for name, *arrays in zip(names, depths, normals, counters, strict=True):
        digest.update(name.encode("utf-8") + b"\0")
        for a in arrays:
            a = np.ascontiguousarray(a, np.float32)
            digest.update(repr(a.shape).encode() + a.tobytes())
    return digest.hexdigest()


def refinement_key(scene, weights_sha256: str, options, inputs_sha256: str) -> dict[str, Any]:
    """The stamp key (module doc); ``options`` is an :class:`engine.pipeline.PipelineOptions`."""
    confidence = options.confidence.to_dict()
    refinement = options.refinement.to_dict()
    key = {
        "scene_path": str(Path(scene.root).resolve()), "scene_options": scene.options.to_dict(),
        "inputs_sha256": inputs_sha256, "weights_sha256": weights_sha256,
        "confidence": {k: confidence[k] for k in INFERENCE},
        "refinement": {k: v for k, v in refinement.items() if k not in POST_REFINEMENT},
        "counter": options.counter.to_dict(), "engine_version": __version__,
    }
    return json.loads(json.dumps(key))  # tuples -> lists, as read back from the stamp


def read_stamp(run_dir: str | Path) -> dict[str, Any] | None:
    """The stamp of a run's refined maps; None when there is none or it is unreadable."""
    try:
        stamp = json.loads((Path(run_dir) / STAMP).read_text())
    except (OSError, ValueError):
        return None
    return stamp if isinstance(stamp, dict) and isinstance(stamp.get("key"), dict) else None


def refined_maps_complete(run_dir: str | Path, names: list[str], key: dict[str, Any]) -> bool:
    """Whether ``run_dir`` holds refined maps of every view made as ``key`` says."""
    stamp = read_stamp(run_dir)
    return stamp is not None and stamp["key"] == key and all(
        map_path(run_dir, kind, n).is_file() for n in names for kind in REFINED_KINDS)


def write_refined_maps(out_dir: str | Path, names: list[str], refined: list, counter: list[np.ndarray],
                       confidence: list[np.ndarray] | None = None) -> None:
    """Write the refined depth, normals, counter (and confidence) maps of every view; any stamp goes first."""
    (Path(out_dir) / STAMP).unlink(missing_ok=True)
    for i, name in enumerate(names):
        check_interrupt()  # between files only (engine/interrupt.py)
        write_map(out_dir, "refined_depth", name, refined[i].depth)
        write_map(out_dir, "refined_normal", name, refined[i].normal)
        write_map(out_dir, "refined_counter", name, counter[i])
        if confidence is not None:
            write_map(out_dir, "refined_confidence", name, confidence[i])


def write_stamp(out_dir: str | Path, key: dict[str, Any], weights: str | Path, seconds: dict[str, float]) -> Path:
    """Write RUN/refined/stamp.json (after every map)."""
    return write_json(Path(out_dir) / STAMP, {
        "format": "deepc-refined-maps", "key": key, "weights": str(Path(weights).resolve()),
        "seconds": seconds, "written": time.strftime("%Y-%m-%dT%H:%M:%S%z")})


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
    ``options``: an :class:`engine.pipeline.PipelineOptions` (its confidence, refinement and counter sections
    count). Maps whose stamp matches are reused. ``log`` gets a line per refined view.
    """
    from engine.confidence.data import run_scene
    from engine.confidence.weights import DEFAULT_WEIGHTS, load_weights
    from engine.patchmatch import ViewMaps
    from engine.pipeline import (
        PipelineOptions,
        compute_counter_maps,
        confidence_stage,
        patchmatch_views,
        refinement_confidence,
        refinement_stage,
    )

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
    if read_metrics(run_dir).get("pipeline") == "full" and (run_dir / "refined").is_dir():
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
