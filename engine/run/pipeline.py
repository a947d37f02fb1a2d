"""The whole chain for one scene: PatchMatch -> counter maps -> ... -> outputs and metrics.

Every stage is also callable on its own; this module only sequences them, times them, writes the
run folder (:mod:`engine.run.folder`) and assembles its ``metrics.json``. Stages that a pipeline does not run
report 0 seconds.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from engine import __version__
from engine.confidence.options import ConfidenceOptions
from engine.consistency import CounterOptions, compute_counter_maps
from engine.core.errors import DeepCError
from engine.core.heap_trim import release_free_memory
from engine.core.interrupt import check_interrupt
from engine.core.observer import ObserverList
from engine.core.options import Options, option
from engine.evaluation import EvaluationOptions, PointIndex, evaluate_point_chunks, evaluate_points
from engine.fusion import (
    DEFAULT_PRESET,
    FUSION_PRESETS,
    DiskCloud,
    FusedCloud,
    FusionOptions,
    views_from_scene,
)
from engine.fusion.stream import fuse_views_to_ply
from engine.io.ply import read_points
from engine.meshing import MeshOptions, evaluate_mesh, mesh_run, write_mesh_ply
from engine.patchmatch import PatchMatchOptions, PatchMatchView, ViewMaps, run_patchmatch
from engine.patchmatch.convergence import EarlyStops
from engine.refinement.options import RefinementOptions
from engine.refinement.views import refine_views
from engine.run.distributed import Executor
from engine.run.distributed.driver import run_confidence_tasks, run_patchmatch_tasks, run_refinement_tasks
from engine.run.distributed.streamed import fuse_run_folder, read_view_map, streamed_metrics
from engine.run.folder import (
    file_sha256,
    maps_digest,
    read_map,
    refinement_key,
    write_map,
    write_metrics,
    write_refined_maps,
    write_stamp,
)
from engine.run.fused_maps import (
    PIPELINES,
    FusionRule,
    RunViewMaps,
    candidate_maps,
    fused_maps,
    fused_view,
    read_run_view,
)
from engine.run.per_view import SceneView, patchmatch_view, view_confidence
from engine.run.probe_output import finish_probe
from engine.run.scores import confidence_auc, depth_block
from engine.run.view_shares import view_shares
from engine.scene import Scene

STAGES = ("patchmatch", "confidence", "refinement", "fusion")


@dataclasses.dataclass
class PipelineOptions(Options):
    """Which pipeline to run and the options of each stage."""

    pipeline: str = option("vanilla", "vanilla: PatchMatch + fusion; fast: + confidence filtering; full: + "
                           "refinement", source="ours", choices=PIPELINES)
    patchmatch: PatchMatchOptions = option(PatchMatchOptions(), "PatchMatch options", cli=False)
    counter: CounterOptions = option(CounterOptions(), "counter-map options", cli=False)
    confidence: ConfidenceOptions = option(ConfidenceOptions(), "confidence network and filtering (fast, full)",
                                           cli=False)
    refinement: RefinementOptions = option(RefinementOptions(), "confidence-guided refinement (full)", cli=False)
    fusion: FusionOptions = option(FUSION_PRESETS[DEFAULT_PRESET], "fusion options", cli=False)
    evaluation: EvaluationOptions = option(EvaluationOptions(), "evaluation options", cli=False)


@dataclasses.dataclass
class PipelineResult:
    """In-memory results of a run (the same data as the output folder)."""

    maps: list[ViewMaps]
    counter: list[np.ndarray]
    confidence: list[np.ndarray] | None
    cloud: FusedCloud
    metrics: dict[str, Any]


def patchmatch_views(scene: Scene) -> list[PatchMatchView]:
    """The PatchMatch inputs of every view of ``scene`` at its working resolution."""
    return [patchmatch_view(scene, v.index) for v in scene.views]


def run_pipeline(scene: Scene, out_dir: str | Path, options: PipelineOptions | None = None,
                 observer: Any = None, progress: Callable[[str, int, int], None] | None = None,
                 checkpoint: Any = None, mesh: MeshOptions | None = None, probe: Any = None,
                 history: Any = None, executor: Executor | None = None) -> PipelineResult:
    """Run ``options.pipeline`` on ``scene`` and write the outputs into ``out_dir``.

    ``checkpoint`` (an :class:`engine.run.checkpoint.PatchMatchCheckpoint`) saves PatchMatch states as it
    goes and reuses those of an interrupted run; it is cleared once metrics.json is written. ``mesh``, unless
    its method is ``none``, adds ``mesh.ply`` made from the fused cloud or the maps fusion used. ``probe`` (an
    :class:`engine.patchmatch.probe.pixel_probe.PixelProbe`) traces pixels of one view and writes ``OUT/probes/``;
    ``history`` (an :class:`engine.run.pass_history.PassHistory`) keeps what re-running one view needs
    (``engine.run.probe``).
    ``executor`` (an :class:`engine.run.distributed.Executor`) runs PatchMatch, counter maps and confidence as per-view
    tasks on it (``engine/run/distributed/``; same maps; no probe, no pass history); None keeps them in this process.
    With an executor, ``vanilla`` and ``fast`` stream the later stages from the run folder
    (``engine.run.distributed.streamed``: fusion through a bounded cache of views, metrics view by view; same cloud
    and numbers) and the result holds no maps (empty lists); ``full`` reads the maps back (its refined maps'
    counter and confidence stages run in this process).
    """
    options = (options or PipelineOptions()).validate()
    rule = FusionRule.from_options(options)  # what fusion (and a TSDF mesh) gets: engine.run.fused_maps
    out_dir = Path(out_dir)
    seconds = dict.fromkeys(STAGES, 0.0)
    start = time.perf_counter()
    notify = getattr(observer, "on_stage", None)

    model = refined_model = weights_sha256 = None
    if options.pipeline in ("fast", "full"):
        # Loaded (and checked) before PatchMatch and kept in memory: bad weights fail at once, and a weights
        # file moved or overwritten while PatchMatch runs cannot end a long run at its last stage.
        from engine.confidence.weights import DEFAULT_REFINED_WEIGHTS, DEFAULT_WEIGHTS, load_weights  # lazy: torch
        model = load_weights(options.confidence.weights or None)
        weights_sha256 = file_sha256(options.confidence.weights or DEFAULT_WEIGHTS)  # for the refined maps' stamp
        if options.pipeline == "full":
            refined_model = load_weights(options.confidence.refined_weights or DEFAULT_REFINED_WEIGHTS)

    # An executor's driver of vanilla or fast never holds every view's maps (engine/run/distributed/streamed.py)
    streamed = executor is not None and options.pipeline != "full"
    # images read when needed in the driver of per-view tasks
    views = patchmatch_views(scene) if executor is None else [SceneView(scene, i) for i in range(len(scene.views))]
    # PatchMatch reads the grey images alone: the colour images (12 B a pixel, 52 MB at fountain_p11 768) would sit in
    # the cache through its peak; the stages after it read them again from their files (0.6 s there)
    scene.forget_images()
    t = time.perf_counter()
    if executor is None:
        early_stops = EarlyStops()
        # EarlyStops sums every iteration's work (its events share the maps: no copies)
        watch = early_stops if observer is None else ObserverList([observer, early_stops])
        maps = run_patchmatch(views, options.patchmatch, observer=watch, progress=progress, checkpoint=checkpoint,
                              probe=probe, history=history)
        counter = compute_counter_maps(views, maps, options.counter)
        seconds["patchmatch"] = time.perf_counter() - t
        for view, m, k in zip(scene.views, maps, counter, strict=True):
            check_interrupt()  # stop requests are honoured between kernels and files (engine/core/interrupt.py)
            write_map(out_dir, "depth", view.name, m.depth)
            write_map(out_dir, "normal", view.name, m.normal)
            write_map(out_dir, "cost", view.name, m.cost)
            write_map(out_dir, "counter", view.name, k)
        if history is not None:  # the states the run recorded become the probe's (engine.run.probe_states)
            history.states.finish(lambda i: history.view_key(i, read_map(out_dir, "depth", scene.views[i].name)))
    else:  # one task per view and pass, then per view (engine/distributed); the tasks write the maps
        if probe is not None or history is not None:
            raise DeepCError("the pixel probe and the pass history need --executor local")
        maps = run_patchmatch_tasks(scene, out_dir, options.patchmatch, options.counter, executor,
                                    observer=observer, progress=progress, checkpoint=checkpoint,
                                    read_back=not streamed)
        maps, counter = maps if maps is not None else ([], [])  # streamed: the maps stay in the run folder
        seconds["patchmatch"] = time.perf_counter() - t
    if notify:
        notify("patchmatch", **({} if streamed else {"maps": maps, "counter": counter}))

    confidence = refined = fusion_confidence = None
    # what fusion gets (engine.run.fused_maps): vanilla's are these; fast and full filter them below
    depths, normals = [m.depth for m in maps], [m.normal for m in maps]
    if options.pipeline in ("fast", "full"):
        t = time.perf_counter()
        raw_confidence: list[np.ndarray] | None = [] if options.pipeline == "full" else None  # refinement's
        if executor is None:
            confidence = confidence_stage(scene, maps, counter, options.confidence, model, raw=raw_confidence)
            for view, c in zip(scene.views, confidence, strict=True):
                check_interrupt()
                write_map(out_dir, "confidence", view.name, c)
        else:  # the tasks write the maps
            # the refinement's weights before the back-facing rule stay in the run folder until its tasks read them
            confidence, raw_confidence = run_confidence_tasks(
                scene, out_dir, options.confidence, executor,
                options.pipeline == "full" and not options.refinement.backfacing_rule, read_back=not streamed)
        fusion_confidence = confidence
        if options.pipeline == "fast" and not streamed:  # streamed: each view is filtered as fusion loads it
            fused = fused_maps(scene, rule, [RunViewMaps(m.depth, m.normal, confidence=c)
                                             for m, c in zip(maps, confidence, strict=True)])
            depths, normals = [f.depth for f in fused], [f.normal for f in fused]
        seconds["confidence"] = time.perf_counter() - t
        if notify:
            notify("confidence", **({} if streamed else {"confidence": confidence, "depth": [m.depth for m in maps]}))
    if options.pipeline == "full":
        t = time.perf_counter()
        refined = refinement_stage(scene, maps, refinement_confidence(confidence, raw_confidence, options.refinement),
                                   options.refinement, executor=executor, out_dir=out_dir)
        seconds["refinement"] = time.perf_counter() - t
        t = time.perf_counter()
        # Kuhn et al. 2020, §4.2: the refined maps get their own counter maps and confidence before filtering; all are
        # written, with a stamp, so the run also serves as training data of that second network
        refined_counter = compute_counter_maps(views, refined, options.counter)
        refined_confidence = confidence_stage(scene, refined, refined_counter, options.confidence, refined_model)
        names = [v.name for v in scene.views]
        write_refined_maps(out_dir, names, refined, refined_counter, refined_confidence)
        inputs = maps_digest(names, [m.depth for m in maps], [m.normal for m in maps], counter)
        key = refinement_key(scene, weights_sha256, options, inputs)
        write_stamp(out_dir, key, options.confidence.weights or DEFAULT_WEIGHTS,
                    {"refinement": seconds["refinement"], "counter_and_confidence": time.perf_counter() - t})
        run_views = [RunViewMaps(m.depth, m.normal, confidence=c1, refined_depth=r.depth, refined_normal=r.normal,
                                 refined_confidence=c2)
                     for m, c1, r, c2 in zip(maps, confidence, refined, refined_confidence, strict=True)]
        fused = fused_maps(scene, rule, run_views)
        fusion_confidence = [f.confidence for f in fused]
        depths, normals = [f.depth for f in fused], [f.normal for f in fused]
        seconds["confidence"] += time.perf_counter() - t
        if notify:
            notify("refinement")

    if probe is None:  # the grey images (4 B a pixel, 17 MB at fountain_p11 768): only the probe's report reads them
        views = None
    check_interrupt()
    t = time.perf_counter()
    if streamed:  # fused.ply written as fusion goes; the cloud stays in it (engine/fusion/stream.py)
        cloud = fuse_run_folder(scene, out_dir, options.fusion, rule, ply=out_dir / "fused.ply")
    else:
        fusion_views = views_from_scene(scene, depths, normals, fusion_confidence, options.fusion.check_num_images)
        cloud = fuse_views_to_ply(out_dir / "fused.ply", fusion_views, options.fusion)  # the cloud stays on disk
        del fusion_views
        scene.forget_images()  # fusion took the colours; the evaluation needs no image (52 MB at fountain_p11 768)
        release_free_memory()  # fusion's packed maps (engine/core/heap_trim.py)
    seconds["fusion"] = time.perf_counter() - t
    if notify:
        notify("fusion", cloud=cloud, pipeline=options.pipeline)
    surface = mesh_info = None
    if mesh is not None and mesh.method != "none":
        check_interrupt()
        if streamed:  # the maps fusion used (TSDF reads them; Poisson does not)
            depths = ([fused_view(scene, v.index, rule, read_run_view(out_dir, v.name, rule.kinds())).depth
                       for v in scene.views] if mesh.method == "tsdf" else [])
        surface, mesh_info = mesh_run(scene, cloud, depths, mesh)
        write_mesh_ply(out_dir / "mesh.ply", surface)
        seconds["mesh"] = mesh_info["seconds"]
        if notify:
            notify("mesh", mesh=surface, pipeline=options.pipeline)

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
    pm = options.patchmatch
    if (pm.converge_ratio > 0 or pm.active_share >= 0) and executor is None:  # tasks report no stage events
        metrics["patchmatch_early_stops"] = early_stops.summary()
    if scene.has_gt_points:
        metrics["eval"] = evaluate_cloud(scene, cloud, options.evaluation).to_dict()
        if surface is not None:
            mesh_info["eval"] = evaluate_mesh(scene, surface, options.evaluation).to_dict()
    if mesh_info is not None:
        metrics["mesh"] = mesh_info
    if streamed:  # the same entries, view by view from the run folder
        metrics.update(streamed_metrics(scene, out_dir, rule))
    elif scene.has_gt_depth:
        metrics["depth"], metrics["depth_per_view"] = depth_block(scene, lambda i: maps[i].depth)
        if confidence is not None:
            auc = confidence_auc(scene, lambda i: maps[i].depth, lambda i: confidence[i])
            metrics["confidence_auc"] = auc["pooled"]
            metrics["confidence_auc_per_view"] = auc["per_view"]
        if refined is not None:
            metrics["refined_depth"], metrics["refined_depth_per_view"] = depth_block(scene, lambda i: refined[i].depth)
            mixed = [candidate_maps(rule, v) for v in run_views]  # what full fuses, before its filters
            metrics["full_depth"], _ = depth_block(scene, lambda i: mixed[i].depth)
            auc = confidence_auc(scene, lambda i: refined[i].depth, lambda i: refined_confidence[i])
            metrics["refined_confidence_auc"] = auc["pooled"]
            metrics["refined_confidence_auc_per_view"] = auc["per_view"]
    names = [v.name for v in scene.views]
    if streamed:  # the counter maps the tasks wrote, view by view
        metrics["views"] = view_shares(names, cloud.source_view,
                                       lambda i: read_view_map(out_dir, "counter", names[i]))
    else:
        metrics["views"] = view_shares(names, cloud.source_view, lambda i: counter[i])
    if confidence is not None and not streamed:
        kept = sum(int((d > 0).sum()) for d in depths)
        before = refined if refined is not None else maps
        metrics["confidence_kept_pct"] = 100.0 * kept / max(1, sum(int((m.depth > 0).sum()) for m in before))
    metrics["options"] = {"scene": scene.options.to_dict(), **options.to_dict()}
    metrics["version"] = __version__
    check_interrupt()
    write_metrics(out_dir, metrics)
    if probe is not None:
        finish_probe(probe, scene, views, maps, counter, confidence, options.counter, out_dir)
    if checkpoint is not None:
        checkpoint.clear()
    return PipelineResult(maps, counter, confidence, cloud, metrics)


def confidence_stage(scene: Scene, maps: list[ViewMaps], counter: list[np.ndarray],
                     options: ConfidenceOptions, model: Any = None,
                     raw: list[np.ndarray] | None = None) -> list[np.ndarray]:
    """(H, W) float32 confidence in [0, 1] per view from the network (Kuhn et al. 2020, §3.2); ``model``: a loaded
    :class:`engine.confidence.network.ConfidenceNet` (default: load ``options.weights`` now). ``raw``, when
    given, also receives each view's confidence before the back-facing rule (``zero_backfacing``)."""
    from engine.confidence.inference import torch_threads  # lazy: torch
    from engine.confidence.weights import load_weights  # lazy: torch

    if model is None:
        model = load_weights(options.weights or None)
    out = []
    with torch_threads(options.num_threads):
        for view, m, k in zip(scene.views, maps, counter, strict=True):
            check_interrupt()
            c, c_raw = view_confidence(scene.image(view.index), m, k, len(view.source_views), options, model)
            if raw is not None:
                raw.append(c_raw)
            out.append(c)
    return out


def refinement_confidence(confidence: list[np.ndarray], raw: list[np.ndarray],
                          options: RefinementOptions) -> list[np.ndarray]:
    """The data-term weights of the refinement: the network's confidence before the back-facing rule unless
    ``options.backfacing_rule`` (see there)."""
    return confidence if options.backfacing_rule else raw


def refinement_stage(scene: Scene, maps: list[ViewMaps], confidence: list[np.ndarray],
                     options: RefinementOptions, progress: Callable[[int, int, Any], None] | None = None,
                     executor: Executor | None = None, out_dir: str | Path | None = None) -> list[ViewMaps]:
    """Refined dense depth and normals per view (Rossi et al. 2020) as :class:`ViewMaps` (cost and selected views
    zero); a view without data to refine from stays empty (a warning names it). ``progress(i, n, result)``
    after each view (result None for an empty one). With ``executor``, one task per view reading the maps the
    PatchMatch tasks wrote into ``out_dir``."""

    if executor is None:
        refined = refine_views(scene, [m.depth for m in maps], [m.normal for m in maps], confidence, options,
                               progress)
    else:
        refined = run_refinement_tasks(scene, out_dir, confidence, options, executor, progress)
    out = []
    for m, r in zip(maps, refined, strict=True):
        depth = np.zeros_like(m.depth) if r is None else np.asarray(r.depth, np.float32)
        normal = np.zeros_like(m.normal) if r is None else np.asarray(r.normal, np.float32)
        out.append(ViewMaps(depth, np.where(depth[..., None] > 0, normal, 0).astype(np.float32),
                            np.zeros_like(m.cost), np.zeros_like(m.selected_views)))
    return out


def evaluate_cloud(scene: Scene, cloud: FusedCloud, options: EvaluationOptions):
    """ETH3D-style scores of a fused cloud against the scene's GT points; GT depth maps, when present,
    enable the unobserved-space rule (Schöps et al. 2017). A cloud on disk (a streamed run's) is scored a chunk of
    points at a time (``engine.evaluation.chunked``: the same numbers)."""
    # each GT depth map is read while it is packed for the free-space rule, not all held at once besides the pack
    gt_views = [(v.camera, functools.partial(scene.gt_depth, v.index)) for v in scene.views
                if scene.gt_depth_paths[v.index] is not None] or None
    gt = PointIndex(read_points(scene.gt_points_path))  # the index holds its own copy: the array read goes now
    if isinstance(cloud, DiskCloud):
        return evaluate_point_chunks(len(cloud), cloud.read_xyz, gt, options, gt_views, scratch=cloud.path.parent)
    return evaluate_points(np.asarray(cloud.xyz, np.float64), gt, options, gt_views)
