"""The rerun recording of one pipeline run: the default layout and a stream over the scene's views.

``deepc run --record`` (and its live stream) and ``deepc regress --record`` open their recordings here, so
both log the same entities with the same blueprint. Importing this module imports rerun.
"""

from __future__ import annotations

from engine.patchmatch import effective_levels
from engine.run.pipeline import PipelineOptions
from engine.scene import Scene
from layouts import DEFAULT, LAYOUTS, Contents
from workbench.rerun.budget import budget_plan
from workbench.rerun.confidence import LiveConfidence
from workbench.rerun.notes import log_notes
from workbench.rerun.recording import Recording
from workbench.rerun.stream import RerunStream, StreamOptions, entity_name

ITERATION_MAPS = ("depth", "normal", "cost", "selected_count", "counter")
ITERATION_STATS = ("mean_cost", "changed_pct", "seconds", "level", "pass", "pixel_scale")
LIVE_CONFIDENCE_STATS = ("confidence_kept_pct", "confidence_seconds")  # and confidence_auc with GT


def expected_contents(scene: Scene, options: PipelineOptions, stream_options: StreamOptions,
                      live_confidence: bool = False) -> Contents:
    """The entities a run with these options is going to record (for its layout before any data exists);
    ``live_confidence``: the stream scores the maps while PatchMatch runs (workbench/rerun/confidence.py)."""
    names = [entity_name(v.index, v.name) for v in scene.views]
    entities = {"/legend", f"/world/fused/{options.pipeline}"}
    confidence = live_confidence or options.pipeline in ("fast", "full")
    for view, name in zip(scene.views, names, strict=True):
        if stream_options.view is not None and view.index != stream_options.view:
            continue
        gt = scene.gt_depth_paths[view.index] is not None  # without reading the map
        kinds = [*ITERATION_MAPS, *(["error"] if gt else []), *(["confidence"] if confidence else []),
                 *(["label"] if gt and confidence else [])]
        entities |= {f"/maps/{name}/{kind}" for kind in kinds}
        entities |= {f"/stats/{name}/{stat}" for stat in (*ITERATION_STATS, *(["within_1pct"] if gt else []))}
        if live_confidence:
            entities |= {f"/stats/{name}/{stat}"
                         for stat in (*LIVE_CONFIDENCE_STATS, *(["confidence_auc"] if gt else []))}
    return Contents(names, entities)


def recording_plan(scene: Scene, options: PipelineOptions, stream_options: StreamOptions) -> StreamOptions:
    """``stream_options`` with ``max_size`` and ``every`` chosen, where unset, so that the recording stays within
    ``stream_options.budget_mb`` (:func:`workbench.rerun.budget.budget_plan`), from the views it logs, the pyramid
    levels and the passes' iterations."""
    pm = options.patchmatch
    logged = [v for v in scene.views if stream_options.view is None or v.index == stream_options.view]
    size, every = budget_plan([(v.camera.width, v.camera.height) for v in logged], effective_levels(scene.views, pm),
                              [pm.pass_iterations(p) for p in range(1 + pm.geom_passes)], stream_options.budget_mb,
                              stream_options.max_points, stream_options.max_size, stream_options.every)
    return stream_options.replace(max_size=size, every=every)


def open_run_recording(path: str | None, scene: Scene, options: PipelineOptions, stream_options: StreamOptions,
                       live_url: str | None = None) -> Recording:
    """A :class:`Recording` to ``path`` (and/or the live viewer at ``live_url``) whose ``stream`` is the
    :class:`RerunStream` observer to hand to ``run_pipeline``. Its layout shows the view the stream is thinned
    to (else the first), with a text panel in place of each map the run will not record. Counter and confidence
    maps are scored while PatchMatch runs every ``stream_options.confidence_k(live)`` iterations of a view (by default
    when streaming live, not to a file only), with the run's counter and confidence options. Without a
    ``stream_options.max_size`` or ``every``, they are chosen to keep the recording within its budget
    (:func:`recording_plan`; the stream's ``options`` say which)."""
    every = stream_options.confidence_k(live=live_url is not None)
    stream_options = recording_plan(scene, options, stream_options)  # sizes and thinning within the budget
    contents = expected_contents(scene, options, stream_options, live_confidence=every > 0)
    contents.live = live_url is not None  # a live viewer follows the run; the file alone opens paused
    names = contents.views
    focus = names[stream_options.view] if stream_options.view is not None and stream_options.view < len(names) \
        else names[0]
    recording = Recording(path, LAYOUTS[DEFAULT](contents, focus), live_url)
    views = [(v.name, v.camera, scene.image(v.index), v.source_views) for v in scene.views]
    gt = [scene.gt_depth(v.index) for v in scene.views]
    recording.stream = RerunStream(recording.rec, views, gt, stream_options,
                                   pass_iterations=options.patchmatch.pass_iterations)
    recording.stream.set_depth_ranges([v.depth_range for v in scene.views])
    if every > 0:
        recording.stream.companions.append(LiveConfidence(recording.stream, every, options.counter,
                                                          options.confidence))
    log_notes(recording.rec, contents, focus, DEFAULT, live=True)
    return recording
