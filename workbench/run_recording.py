"""The rerun recording of one pipeline run: the default layout and a stream over the scene's views.

``deepc run --record`` (and its live stream) and ``deepc regress --record`` open their recordings here, so
both log the same entities with the same blueprint. Importing this module imports rerun.
"""

from __future__ import annotations

from engine.pipeline import PipelineOptions
from engine.scene import Scene
from layouts import DEFAULT, LAYOUTS, Contents
from workbench.recording import Recording
from workbench.stream import RerunStream, StreamOptions, entity_name


def open_run_recording(path: str | None, scene: Scene, options: PipelineOptions, stream_options: StreamOptions,
                       live_url: str | None = None) -> Recording:
    """A :class:`Recording` to ``path`` (and/or the live viewer at ``live_url``) whose ``stream`` is the
    :class:`RerunStream` observer to hand to ``run_pipeline``."""
    names = [entity_name(v.index, v.name) for v in scene.views]
    focus = names[stream_options.view] if stream_options.view is not None and stream_options.view < len(names) \
        else names[0]
    blueprint = LAYOUTS[DEFAULT](Contents(names), focus)
    recording = Recording(path, blueprint, live_url)
    views = [(v.name, v.camera, scene.image(v.index), v.source_views) for v in scene.views]
    gt = [scene.gt_depth(v.index) for v in scene.views]
    recording.stream = RerunStream(recording.rec, views, gt, stream_options,
                                   pass_iterations=options.patchmatch.pass_iterations)
    recording.stream.set_depth_ranges([v.depth_range for v in scene.views])
    return recording
