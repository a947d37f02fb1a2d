"""The options a run computes with, made from the flags of ``workbench/flags/run.py``.

Shared by ``deepc run`` and the entries of a regression suite. Bad weights fail here, before PatchMatch.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from engine.core.options import Options
from engine.fusion import DEFAULT_PRESET, FUSION_PRESETS, FusionOptions
from engine.meshing.options import MeshOptions
from engine.patchmatch import PatchMatchOptions
from engine.run.pipeline import PipelineOptions
from engine.scene import SceneOptions
from workbench.flags.assignments import (
    check_stages,
    nested_options,
    section_overrides,
    stage_overrides,
    with_overrides,
)
from workbench.flags.options import given_flags, options_from_args
from workbench.rerun.options import StreamOptions


def run_sections() -> dict[str, Options]:
    """The stages ``deepc run --set STAGE.NAME=VALUE`` reaches, with their defaults: the scene, every nested
    options dataclass of :class:`PipelineOptions` (so a stage added to the pipeline is reachable as it is), the
    mesh and the rerun stream."""
    pipeline = PipelineOptions()
    return {"scene": SceneOptions(), **{name: getattr(pipeline, name) for name in nested_options(PipelineOptions)},
            "mesh": MeshOptions(), "stream": StreamOptions()}


def run_options_from_args(args: argparse.Namespace) -> tuple[SceneOptions, PipelineOptions, StreamOptions]:
    """(SceneOptions, PipelineOptions, StreamOptions) from the flags of :func:`add_run_option_flags`;
    shared by ``deepc run`` and the entries of a regression suite. ``--set`` wins over a flag of the same option;
    bad weights fail here, before PatchMatch."""
    check_stages(args.set, run_sections())
    scene_options = options_from_args(SceneOptions, args, **section_overrides(args.set, "scene", SceneOptions))
    changes = stage_overrides(args.set, PipelineOptions)
    changes["patchmatch"] = {**given_flags(PatchMatchOptions, args), **changes["patchmatch"]}
    changes["fusion"] = {**given_flags(FusionOptions, args), **changes["fusion"]}
    if getattr(args, "weights", None):
        changes["confidence"]["weights"] = str(Path(args.weights).resolve())
    preset = FUSION_PRESETS[args.fusion_preset or DEFAULT_PRESET]
    options = with_overrides(PipelineOptions(pipeline=args.pipeline, fusion=preset), changes)
    stream = section_overrides(args.set, "stream", StreamOptions)
    if getattr(args, "stream_confidence_every", None) is not None:
        stream["confidence_every"] = args.stream_confidence_every
    stream_options = with_overrides(StreamOptions(), stream)
    if options.pipeline in ("fast", "full"):
        check_pipeline_weights(options)
    return scene_options, options, stream_options


def mesh_options(method: str | None, set_items: list[str]) -> MeshOptions:
    """MeshOptions from a method (``deepc run --mesh``, ``deepc mesh --method``; None = none) and
    ``--set mesh.NAME=VALUE`` items."""
    return with_overrides(MeshOptions(method=method or "none"), section_overrides(set_items, "mesh", MeshOptions))


def check_pipeline_weights(options: PipelineOptions) -> None:
    """Load the network weights a fast or full run will use (the second network's too for full)."""
    from engine.confidence.weights import DEFAULT_REFINED_WEIGHTS, DEFAULT_WEIGHTS  # lazy: torch

    check_weights(Path(options.confidence.weights or DEFAULT_WEIGHTS))
    if options.pipeline == "full":
        check_weights(Path(options.confidence.refined_weights or DEFAULT_REFINED_WEIGHTS))


_CHECKED_WEIGHTS: set[tuple[str, int, int]] = set()


def check_weights(path: Path) -> None:
    """Load the weights once (network built, every tensor checked) so that bad weights fail before anything
    runs; a suite naming the same file many times checks it once (keyed by size and modification time)."""
    from engine.confidence.weights import load_weights  # lazy: torch

    try:
        stat = path.stat()
        key = (str(path), stat.st_size, stat.st_mtime_ns)
    except OSError:
        key = None
    if key is None or key not in _CHECKED_WEIGHTS:
        load_weights(path)
        _CHECKED_WEIGHTS.add(key)
