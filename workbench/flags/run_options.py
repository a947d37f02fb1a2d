"""The options a run computes with, made from the flags of ``workbench/flags/run.py``.

Shared by ``deepc run`` and the entries of a regression suite. Bad weights fail here, before PatchMatch.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from engine.confidence.options import ConfidenceOptions
from engine.core.errors import DeepCError
from engine.fusion import DEFAULT_PRESET, FUSION_PRESETS, FusionOptions
from engine.meshing.options import MeshOptions
from engine.patchmatch import PatchMatchOptions
from engine.refinement.options import RefinementOptions
from engine.run.pipeline import PipelineOptions
from engine.scene import SceneOptions
from workbench.flags.options import options_from_args, section_overrides
from workbench.flags.run import SET_SECTIONS
from workbench.rerun.options import StreamOptions


def run_options_from_args(args: argparse.Namespace) -> tuple[SceneOptions, PipelineOptions, StreamOptions]:
    """(SceneOptions, PipelineOptions, StreamOptions) from the flags of :func:`add_run_option_flags`;
    shared by ``deepc run`` and the entries of a regression suite. Bad weights fail here, before PatchMatch."""
    for item in args.set:
        section = item.partition("=")[0].partition(".")[0]
        if section not in SET_SECTIONS:
            raise DeepCError(f"--set {item!r}: unknown stage {section!r} (one of {', '.join(SET_SECTIONS)})")
    scene_options = options_from_args(SceneOptions, args)
    patchmatch = options_from_args(PatchMatchOptions, args,
                                   **section_overrides(args.set, "patchmatch", PatchMatchOptions))
    preset = args.fusion_preset or DEFAULT_PRESET
    fusion = options_from_args(FusionOptions, args, base=FUSION_PRESETS[preset],
                               **section_overrides(args.set, "fusion", FusionOptions))
    confidence = ConfidenceOptions(**section_overrides(args.set, "confidence", ConfidenceOptions))
    if getattr(args, "weights", None):
        confidence = confidence.replace(weights=str(Path(args.weights).resolve()))
    refinement = RefinementOptions(**section_overrides(args.set, "refinement", RefinementOptions))
    options = PipelineOptions(pipeline=args.pipeline, patchmatch=patchmatch, confidence=confidence,
                              refinement=refinement, fusion=fusion).validate()
    stream = section_overrides(args.set, "stream", StreamOptions)
    if getattr(args, "stream_confidence_every", None) is not None:
        stream["confidence_every"] = args.stream_confidence_every
    stream_options = StreamOptions(**stream).validate()
    if options.pipeline in ("fast", "full"):
        check_pipeline_weights(options)
    return scene_options, options, stream_options


def mesh_options(method: str | None, set_items: list[str]) -> MeshOptions:
    """MeshOptions from a method (``deepc run --mesh``, ``deepc mesh --method``; None = none) and
    ``--set mesh.NAME=VALUE`` items."""
    return MeshOptions(**{"method": method or "none", **section_overrides(set_items, "mesh", MeshOptions)}).validate()


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
