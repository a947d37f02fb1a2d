"""Probe traces -> rerun: one probed pixel's PatchMatch history on the iteration timelines.

Entity tree, beside the run stream's (``workbench/rerun/stream.py``), per probed pixel ``<view>/<x>_<y>``::

    probe/<view>/<x>_<y>/cost, depth             Scalars after each iteration (gt_depth: the GT, a flat line)
    probe/<view>/<x>_<y>/candidates              Points3D: every candidate on the pixel's ray at its depth,
                                                 coloured by origin, the winner larger; labels name origin and cost
    probe/<view>/<x>_<y>/ray                     LineStrips3D: the pixel's ray over the view's depth range (static)
    probe/<view>/<x>_<y>/gt                      Points3D: the GT point on the ray (static, with GT)
    probe/<view>/<x>_<y>/windows                 Image: the pixel's window in each source image under the plane
    probe/<view>/<x>_<y>/candidates_table        TextDocument (markdown): the iteration's candidates
    probe/<view>/<x>_<y>/summary                 TextDocument (markdown): the final estimate (static)

Trace entry ``n`` (run order) sits at ``view_iteration`` n and at the ``pass`` of its (level, pass), so
scrubbing the run's maps and the probe together shows the pixel's state in the maps of the same iteration.
The ``probe`` layout (``layouts/__init__.py``) shows these panels.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr

from engine.scene import Scene
from layouts import LAYOUTS, Contents
from workbench.rerun.recording import Recording
from workbench.rerun.stream import RerunStream, entity_name
from workbench.trace.figures import ORIGIN_COLOURS, candidate_table_markdown, summary_markdown
from workbench.trace.windows import ray_points, window_thumbnails


def probe_entity(scene: Scene, trace: dict) -> str:
    """``probe/<view entity>/<x>_<y>`` of a trace (the view named as the run stream names it)."""
    index = next(v.index for v in scene.views if v.name == trace["view"])
    return f"probe/{entity_name(index, trace['view'])}/{trace['x']}_{trace['y']}"


def _ray_points(scene: Scene, index: int, x: int, y: int, depths) -> np.ndarray:
    return ray_points(scene.views[index].camera, x, y, depths)


def log_probe(rec: rr.RecordingStream, scene: Scene, trace: dict, window: int = 11) -> str:
    """Log one trace (``engine.run.probe`` schema) under :func:`probe_entity`; returns that entity path.

    Args:
        rec: an open recording stream.
        scene: the run's scene (cameras and images at the maps' resolution).
        trace: the probe trace.
        window: the matching window side the run used (``PatchMatchOptions.window``), for the thumbnails.
    """
    base = probe_entity(scene, trace)
    index = next(v.index for v in scene.views if v.name == trace["view"])
    view = scene.views[index]
    x, y = trace["x"], trace["y"]
    final = trace.get("final") or {}
    lo, hi = view.depth_range
    rec.log(f"{base}/ray", rr.LineStrips3D([_ray_points(scene, index, x, y, np.array([lo, hi]))],
                                           colors=[(255, 255, 255)], radii=rr.Radius.ui_points(1.0)), static=True)
    gt = final.get("gt_depth")
    if gt:
        rec.log(f"{base}/gt", rr.Points3D(_ray_points(scene, index, x, y, np.array([gt])), colors=[(40, 200, 80)],
                                          radii=rr.Radius.ui_points(6.0), labels=["GT"]), static=True)
    rec.log(f"{base}/summary", rr.TextDocument(summary_markdown(trace, f"{index}: {view.name}"),
                                               media_type=rr.MediaType.MARKDOWN), static=True)
    by_name = {v.name: v.index for v in scene.views}
    names = [view.name, *[n for n in trace.get("source_views") or [] if n in by_name]]
    images = [(np.asarray(scene.image(by_name[n])) * 255 + 0.5).astype(np.uint8) for n in names]
    cameras = [scene.views[by_name[n]].camera for n in names]
    passes: list[tuple[int, int]] = []
    for n, step in enumerate(trace.get("iterations") or []):
        key = (step["level"], step["pass"])
        if key not in passes:
            passes.append(key)
        rec.set_time("view_iteration", sequence=n)
        rec.set_time("pass", sequence=passes.index(key))
        after = step["after"]
        for name in ("cost", "depth"):
            if after.get(name) is not None:
                rec.log(f"{base}/{name}", rr.Scalars(float(after[name])))
        if gt:
            rec.log(f"{base}/gt_depth", rr.Scalars(float(gt)))
        candidates = step.get("candidates") or []
        shown = [c for c in candidates if c.get("depth") and c["depth"] > 0]
        if shown:
            colours = [ORIGIN_COLOURS.get(str(c["origin"]).split(":")[0], (255, 255, 255)) for c in shown]
            radii = [rr.Radius.ui_points(7.0 if c is candidates[step["winner"]] else 3.5) for c in shown]
            labels = [f"{c['origin']} {'–' if c.get('cost') is None else format(c['cost'], '.3f')}" for c in shown]
            rec.log(f"{base}/candidates", rr.Points3D(_ray_points(scene, index, x, y, [c["depth"] for c in shown]),
                                                      colors=colours, radii=[float(r) for r in radii], labels=labels))
        rec.log(f"{base}/candidates_table", rr.TextDocument(candidate_table_markdown(trace, n),
                                                            media_type=rr.MediaType.MARKDOWN))
        winner = candidates[step["winner"]] if candidates else {}
        if after.get("depth"):
            half = (window // 2) * 2 ** int(step["level"])
            costs = winner.get("view_costs") or None
            rec.log(f"{base}/windows", rr.Image(window_thumbnails(
                images, cameras, names, x, y, float(after["depth"]), after.get("normal"), half,
                set(step.get("selected_views") or winner.get("selected_views") or []), costs)))
    return base


def write_probe_recording(path: str | Path, scene: Scene, traces: list[dict], window: int = 11,
                          maps: dict[int, dict[str, np.ndarray]] | None = None) -> Path:
    """A recording of the cameras, ``traces`` and ``maps`` (view index -> {kind: uint8 RGB map}, e.g. the probed
    view's depth and error) with the ``probe`` layout on the first trace's view."""
    names = [entity_name(v.index, v.name) for v in scene.views]
    bases = [probe_entity(scene, t) for t in traces]
    entities = {f"/{b}/summary" for b in bases} | {f"/maps/{names[i]}/{kind}" for i, kinds in (maps or {}).items()
                                                   for kind in kinds}
    recording = Recording(path, LAYOUTS["probe"](Contents(names, entities), bases[0].split("/")[1] if bases else
                                                 names[0]))
    try:
        RerunStream(recording.rec, [(v.name, v.camera, scene.image(v.index), v.source_views) for v in scene.views])
        for i, kinds in (maps or {}).items():
            for kind, image in kinds.items():  # static: beside every iteration of the trace
                recording.rec.log(f"maps/{names[i]}/{kind}", rr.Image(image), static=True)
        for trace in traces:
            log_probe(recording.rec, scene, trace, window)
    except BaseException:
        recording.abandon()
        raise
    return recording.finish()
