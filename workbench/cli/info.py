"""``deepc info SCENE``: what a workspace is and what a run of it would take, in seconds, without decoding or
undistorting an image (``engine.scene.survey_scene``).

Prints the cameras (model, size, how many images share each, their undistorted and working sizes), the working size
and the flag that changes it, what undistortion would cost (images, size, whether it is cached), the estimated peak
memory of ``deepc run`` with the default pipeline (``engine/run/memory.py``) and the views with their depth ranges and
source views.
"""

from __future__ import annotations

import argparse
from collections import Counter
from types import SimpleNamespace

from engine.core.words import plural
from engine.io.undistort import cached_workspace
from engine.patchmatch.options import PatchMatchOptions
from engine.run.memory import estimate_run_memory, largest_fitting_size
from engine.scene import SceneOptions, SceneSurvey, survey_scene, views_table, working_size_line
from workbench.flags.options import options_from_args


def describe(survey: SceneSurvey, requested: int | None = None) -> list[str]:
    """The lines ``deepc info`` prints, memory aside; ``requested`` is the ``--max-image-size`` given (None: the
    default working size)."""
    model = survey.model
    has_gt_depth = any(p is not None for p in survey.gt_depth_paths)
    lines = [f"scene {survey.name}: {plural(len(survey.views), 'view')}, "
             f"{plural(len(model.points), 'sparse point')}, "
             f"GT depth: {'yes' if has_gt_depth else 'no'}, GT points: "
             f"{'yes' if survey.gt_points_path is not None else 'no'}  ({survey.model_dir})"]
    registered = {im.name for im in model.images}
    root = survey.root / "images"
    others = sum(1 for f in root.rglob("*") if f.is_file() and f.relative_to(root).as_posix() not in registered)
    if others:
        lines.append(f"{others} file(s) in images/ are not registered in the model: ignored")
    users = Counter(im.camera_id for im in model.images)
    working = {}
    for view, im in zip(survey.views, model.images, strict=True):
        working.setdefault(im.camera_id, view.camera.size)
    groups: dict[tuple, list[int]] = {}  # cameras alike (one per image is common): one line
    for camera_id in sorted(users):
        cam, pinhole = model.cameras[camera_id], survey.cameras[camera_id]
        undistorted = "-" if cam is pinhole else f"{pinhole.width}x{pinhole.height}"
        w, h = working[camera_id]
        groups.setdefault((cam.model, f"{cam.width}x{cam.height}", undistorted, f"{w}x{h}"), []).append(camera_id)
    lines.append(f"{'cameras':<12} {'model':<14} {'size':>11} {'images':>6}  {'undistorted':>11}  working size")
    for (kind, size, undistorted, work), ids in groups.items():
        names = str(ids[0]) if len(ids) == 1 else f"{len(ids)} ({ids[0]}..{ids[-1]})"
        lines.append(f"{names:<12} {kind:<14} {size:>11} {sum(users[c] for c in ids):>6}  {undistorted:>11}  {work}")
    lines.append(working_size_line(survey.views, requested, survey.image_sizes))
    if survey.distorted:
        key = survey.cache_key()
        state = "cached" if cached_workspace(survey.cache_root, key) else "not cached yet"
        lines.append(f"undistortion: {len(model.images)} images ({', '.join(survey.distorted)}) would be undistorted "
                     f"at {survey.undistorted_size()} px into {survey.cache_root / key} ({state})")
    else:
        lines.append("undistortion: none needed (pinhole cameras)")
    return lines + views_table(survey.views)


def memory_line(survey: SceneSurvey) -> str:
    """The estimated peak memory of ``deepc run`` on ``survey`` with the default pipeline options."""
    # the estimate reads the pipeline's PatchMatch options only; importing engine.run.pipeline for its
    # PipelineOptions would load every stage's kernels (numba, scipy) and double what deepc info takes
    options = SimpleNamespace(patchmatch=PatchMatchOptions())
    estimate = estimate_run_memory(survey, options)
    line = (f"{estimate.summary()} (default pipeline; the baseline is this process, without the compiled kernels "
            "deepc run adds)")
    if not estimate.fits:
        size = largest_fitting_size(survey, options, estimate)
        line += f"; does not fit: try --max-image-size {size}" if size else "; does not fit at any size"
    return line


def cmd_info(args: argparse.Namespace) -> int:
    options = options_from_args(SceneOptions, args)
    survey = survey_scene(args.scene, options)
    lines = describe(survey, options.max_image_size)
    lines.insert(-len(survey.views) - 1, memory_line(survey))
    print("\n".join(lines))
    return 0
