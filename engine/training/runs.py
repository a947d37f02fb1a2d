"""Engine runs of training scenes, made once and cached.

:func:`ensure_run` runs the pipeline on a scene with GT depth and keeps the output folder; a cached run is
reused only when its metrics.json names the same scene folder and the same map-determining options and all
its maps exist (:func:`engine.run.folder.run_is_complete`).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from engine.core.errors import DeepCError
from engine.run.folder import run_is_complete
from engine.run.pipeline import run_pipeline
from engine.scene import SceneOptions, load_scene


def ensure_run(scene_dir: str | Path, runs_root: str | Path, scene_options: SceneOptions, pipeline_options,
               log: Callable[[str], None] = print, name: str | None = None,
               require_gt: bool = True) -> Path:
    """The cached vanilla run of ``scene_dir`` under ``runs_root/<name>`` (default: the scene's name); runs the
    engine when the cache is missing, incomplete or made with other options."""
    scene = load_scene(scene_dir, scene_options)
    if require_gt and not scene.has_gt_depth:
        raise DeepCError("scene has no ground-truth depth maps (ground_truth/depth_maps/): "
                         "it cannot give training labels", scene.root)
    run_dir = Path(runs_root) / (name or scene.name)
    expected = {"scene": scene.options.to_dict(), **pipeline_options.to_dict()}  # the working size resolved
    if run_is_complete(run_dir, scene.root, expected):
        return run_dir
    log(f"running the engine on {scene.root} -> {run_dir}")
    run_pipeline(scene, run_dir, pipeline_options)
    return run_dir
