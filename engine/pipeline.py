"""The whole chain for one scene: PatchMatch -> counter maps -> ... -> outputs and metrics.

Every stage is also callable on its own; this module only sequences them, times them, writes the
outputs of CONTRACT.md §4 and assembles ``metrics.json`` (§5). Stages that a pipeline does not run
report 0 seconds.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from engine import __version__
from engine.consistency import CounterOptions, compute_counter_maps
from engine.evaluation import EvaluationOptions, evaluate_points
from engine.fusion import FUSION_PRESETS, FusedCloud, FusionOptions, fuse, views_from_scene, write_fused_ply
from engine.io.outputs import write_map, write_metrics
from engine.io.ply import read_points
from engine.metrics import depth_metrics
from engine.options import Options, option
from engine.patchmatch import PatchMatchOptions, PatchMatchView, ViewMaps, run_patchmatch
from engine.scene import Scene

PIPELINES = ("vanilla", "fast", "full")
STAGES = ("patchmatch", "confidence", "refinement", "fusion")


@dataclasses.dataclass
class PipelineOptions(Options):
    """Which pipeline to run and the options of each stage."""

    pipeline: str = option("vanilla", "vanilla: PatchMatch + fusion; fast: + confidence filtering; "
                           "full: + refinement", choices=PIPELINES)
    patchmatch: PatchMatchOptions = option(PatchMatchOptions(), "PatchMatch options", cli=False)
    counter: CounterOptions = option(CounterOptions(), "counter-map options", cli=False)
    fusion: FusionOptions = option(FUSION_PRESETS["deepc"], "fusion options", cli=False)
    evaluation: EvaluationOptions = option(EvaluationOptions(), "evaluation options", cli=False)

    def validate(self) -> PipelineOptions:
        super().validate()
        for stage in (self.patchmatch, self.counter, self.fusion, self.evaluation):
            stage.validate()
        return self


@dataclasses.dataclass
class PipelineResult:
    """In-memory results of a run (the same data as the output folder)."""

    maps: list[ViewMaps]
    counter: list[np.ndarray]
    cloud: FusedCloud
    metrics: dict[str, Any]


def patchmatch_views(scene: Scene) -> list[PatchMatchView]:
    """The PatchMatch inputs of every view of ``scene`` at its working resolution."""
    return [PatchMatchView(v.name, scene.gray(v.index), v.camera, v.depth_range[0], v.depth_range[1],
                           list(v.source_views)) for v in scene.views]


def run_pipeline(scene: Scene, out_dir: str | Path, options: PipelineOptions | None = None,
                 observer: Any = None, progress: Callable[[str, int, int], None] | None = None,
                 checkpoint: Any = None) -> PipelineResult:
    """Run ``options.pipeline`` on ``scene`` and write the outputs into ``out_dir``.

    ``checkpoint`` (an :class:`engine.checkpoint.PatchMatchCheckpoint`) saves PatchMatch states as it
    goes and reuses those of an interrupted run; it is cleared once metrics.json is written.
    """
    options = (options or PipelineOptions()).validate()
    out_dir = Path(out_dir)
    seconds = dict.fromkeys(STAGES, 0.0)
    start = time.perf_counter()
    notify = getattr(observer, "on_stage", None)

    views = patchmatch_views(scene)
    t = time.perf_counter()
    maps = run_patchmatch(views, options.patchmatch, observer=observer, progress=progress, checkpoint=checkpoint)
    counter = compute_counter_maps(views, maps, options.counter)
    seconds["patchmatch"] = time.perf_counter() - t
    for view, m, k in zip(scene.views, maps, counter, strict=True):
        write_map(out_dir, "depth", view.name, m.depth)
        write_map(out_dir, "normal", view.name, m.normal)
        write_map(out_dir, "cost", view.name, m.cost)
        write_map(out_dir, "counter", view.name, k)
    if notify:
        notify("patchmatch", maps=maps, counter=counter)

    t = time.perf_counter()
    fusion_views = views_from_scene(scene, [m.depth for m in maps], [m.normal for m in maps], None,
                                    options.fusion.check_num_images)
    cloud = fuse(fusion_views, options.fusion)
    write_fused_ply(out_dir / "fused.ply", cloud)
    seconds["fusion"] = time.perf_counter() - t
    if notify:
        notify("fusion", cloud=cloud, pipeline=options.pipeline)

    seconds["total"] = time.perf_counter() - start
    metrics: dict[str, Any] = {
        "scene": scene.name,
        "scene_path": str(scene.root.resolve()),
        "pipeline": options.pipeline,
        "num_images": len(scene.views),
        "image_size": [max(v.camera.width for v in scene.views), max(v.camera.height for v in scene.views)],
        "seconds": seconds,
        "fused_points": len(cloud),
    }
    if scene.has_gt_points:
        metrics["eval"] = evaluate_cloud(scene, cloud, options.evaluation).to_dict()
    if scene.has_gt_depth:
        metrics["depth"], metrics["depth_per_view"] = _depth_block(scene, maps)
    metrics["options"] = {"scene": scene.options.to_dict(), **options.to_dict()}
    metrics["version"] = __version__
    write_metrics(out_dir, metrics)
    if checkpoint is not None:
        checkpoint.clear()
    return PipelineResult(maps, counter, cloud, metrics)


def evaluate_cloud(scene: Scene, cloud: FusedCloud, options: EvaluationOptions):
    """ETH3D-style scores of a fused cloud against the scene's GT points; GT depth maps, when present,
    enable the unobserved-space rule (SPEC.md §9.1)."""
    return evaluate_points(np.asarray(cloud.xyz, np.float64), read_points(scene.gt_points_path), options,
                           scene.gt_views() or None)


def _depth_block(scene: Scene, maps: list[ViewMaps]) -> tuple[dict[str, float], list[dict[str, Any]]]:
    """Depth metrics pooled over all pixels of all views, and per view."""
    per_view, pooled_est, pooled_gt = [], [], []
    for view, m in zip(scene.views, maps, strict=True):
        gt = scene.gt_depth(view.index)
        if gt is None:
            continue
        per_view.append({"view": view.name, **depth_metrics(m.depth, gt)})
        pooled_est.append(m.depth.ravel())
        pooled_gt.append(gt.ravel())
    pooled = depth_metrics(np.concatenate(pooled_est), np.concatenate(pooled_gt))
    keys = ("abs_rel", "within_1pct", "within_5pct", "valid_fraction")
    return {k: pooled[k] for k in keys}, per_view
