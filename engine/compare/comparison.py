"""Two runs of one scene compared view by view and overall (``deepc compare``).

Views are matched by image name (:func:`engine.compare.sources.match_names`); each view's two depth maps and its GT
depth are brought to the pair's common working size (the smaller of the two maps; ``engine.core.resample``, which
never averages across a depth edge) and compared pixel by pixel (:mod:`engine.compare.pixels`). Where both runs
have a fused cloud and the scene has GT points, both clouds are scored as ``deepc eval`` scores them (ETH3D's
accuracy, completeness and F1 at every tolerance, ``engine.evaluation``); when asked, so are both runs' maps fused
by our fusion (:mod:`engine.compare.our_fusion`).
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from engine.compare.our_fusion import fuse_run
from engine.compare.pixels import TOLERANCE, PixelCounts, compare_pixels
from engine.compare.sources import SourceRun, match_names
from engine.core.errors import DeepCError
from engine.core.resample import resample_depth
from engine.evaluation import EvaluationOptions, PointIndex, evaluate_points
from engine.io.dense import read_depth_map
from engine.io.ply import read_points
from engine.run.folder import read_run_metrics
from engine.scene import Scene, SceneOptions, load_scene


@dataclasses.dataclass
class ViewComparison:
    """One view: its name, the common size (width, height) in pixels, whether it has GT depth, the counts, the
    (H, W) bool maps of :data:`engine.compare.pixels.CASES` and the image names A and B store it under."""

    index: int
    name: str
    size: tuple[int, int]
    has_gt: bool
    counts: PixelCounts
    maps: dict[str, np.ndarray]
    keys: tuple[str, str] = ("", "")

    @property
    def difference(self) -> float:
        """Percent of the counted pixels where the runs differ (:meth:`PixelCounts.shares`), 0 when none counted."""
        value = self.counts.shares()["difference"]
        return 0.0 if math.isnan(value) else value


@dataclasses.dataclass
class Comparison:
    """Runs A and B compared on ``scene``.

    Attributes:
        views: the views both runs have, in scene order; only_a, only_b: scene views only one run has a map of.
        total: the counts of every compared view together.
        fused: "a" / "b" -> the ``eval`` block (tolerances, accuracy, completeness, f1 in percent) of the run's
            fused cloud, or None; fused_notes: why a cloud was not scored.
        ours_fused: the same for each run's maps fused by our fusion (:mod:`engine.compare.our_fusion`), when asked.
    """

    a: SourceRun
    b: SourceRun
    scene: Scene
    tolerance: float
    views: list[ViewComparison]
    only_a: list[str]
    only_b: list[str]
    total: PixelCounts
    fused: dict[str, dict[str, list[float]] | None]
    fused_notes: list[str]
    ours_fused: dict[str, dict[str, list[float]] | None] = dataclasses.field(
        default_factory=lambda: {"a": None, "b": None})

    def most_different(self, count: int) -> list[ViewComparison]:
        """The ``count`` views where the runs differ most, most first."""
        return sorted(self.views, key=lambda v: -v.difference)[:count]

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready summary (no maps): per view and ``overall``, the :class:`PixelCounts` and their shares in
        percent (``a_right_pct``, ..., ``disagree_pct``, ``difference_pct``)."""

        def run(r: SourceRun) -> dict[str, Any]:
            return {"path": str(r.path), "kind": r.kind, "description": r.description,
                    "fused": None if r.fused is None else str(r.fused)}

        return {"scene": self.scene.name, "scene_path": str(self.scene.root), "tolerance": self.tolerance,
                "a": run(self.a), "b": run(self.b), "only_a": self.only_a, "only_b": self.only_b,
                "overall": _counts_dict(self.total),
                "views": [{"view": v.name, "size": list(v.size), "has_gt": v.has_gt, **_counts_dict(v.counts)}
                          for v in self.views],
                "fused": self.fused, "fused_notes": self.fused_notes, "ours_fused": self.ours_fused}


def _counts_dict(counts: PixelCounts) -> dict[str, Any]:
    """Counts under their names, shares (percent) under ``<name>_pct``."""
    return {**dataclasses.asdict(counts), **{f"{k}_pct": v for k, v in counts.shares().items()}}


def reference_scene(a: SourceRun, b: SourceRun, scene_root: str | Path | None = None) -> Scene:
    """The scene both runs are of: ``scene_root`` if given, else a deepc run's scene, else a foreign run's folder
    when it holds a COLMAP scene; loaded with a deepc run's scene options (the defaults otherwise)."""
    ours = [r for r in (a, b) if r.kind == "deepc"]
    options = SceneOptions.from_dict(ours[0].scene_options) if ours else SceneOptions()
    root = scene_root or next((r.scene_root for r in (*ours, a, b) if r.scene_root is not None), None)
    if root is None:
        raise DeepCError(f"neither {a.path} nor {b.path} names its scene: give --scene SCENE (the COLMAP workspace "
                         "the runs were made from)")
    return load_scene(root, options)


def common_size(size_a: tuple[int, int], size_b: tuple[int, int], name: str) -> tuple[int, int]:
    """The smaller of two (width, height) sizes of one image; sizes of other shapes are a :class:`DeepCError`."""
    (wa, ha), (wb, hb) = size_a, size_b
    if abs(wa * hb - wb * ha) > max(wa, wb, ha, hb):  # the same aspect ratio, up to a pixel of rounding
        raise DeepCError(f"view {name}: depth maps of {wa}x{ha} and {wb}x{hb} pixels are not of the same image")
    return size_a if wa * ha <= wb * hb else size_b


def common_depths(a: SourceRun, b: SourceRun, keys: tuple[str, str], size: tuple[int, int]
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) depth of A's map stored as ``keys[0]`` and of B's stored as ``keys[1]``, both at ``size`` (width,
    height): the maps the comparison compares (0 = none)."""
    return resample_depth(a.depth(keys[0]), size), resample_depth(b.depth(keys[1]), size)


def _gt_at(scene: Scene, index: int, size: tuple[int, int]) -> np.ndarray | None:
    """(H, W) GT depth of view ``index`` resampled from its file to ``size`` (one resampling), or None."""
    path = scene.gt_depth_paths[index]
    return None if path is None else resample_depth(read_depth_map(path), size)


def score_clouds(clouds: dict[str, Path | np.ndarray], scene: Scene, options: EvaluationOptions | None = None
                 ) -> dict[str, dict[str, list[float]]]:
    """The ``eval`` block of each cloud (a PLY, or (N, 3) points) against the scene's GT points, with its GT depth
    maps for the unobserved-space rule, as ``deepc eval`` scores a cloud; the GT is indexed once for all."""
    if not clouds:
        return {}
    gt = PointIndex(read_points(scene.gt_points_path))
    gt_views = scene.gt_views() or None
    return {key: evaluate_points(read_points(c) if isinstance(c, Path) else c, gt, options or EvaluationOptions(),
                                 gt_views).to_dict() for key, c in clouds.items()}


def saved_score(run: SourceRun, scene: Scene, options: EvaluationOptions) -> dict[str, list[float]] | None:
    """A deepc run's own score of its fused cloud (``metrics.json``'s ``eval``) when it is what
    :func:`score_clouds` would compute: the same evaluation options, the run's scene at the options the run used,
    and ``fused.ply`` not written after ``metrics.json``; else None (scoring a 768 px cloud takes seconds)."""
    if run.kind != "deepc" or run.fused is None:
        return None
    metrics = read_run_metrics(run.path)
    if metrics.eval is None or metrics.options.get("evaluation") != json.loads(json.dumps(options.to_dict())):
        return None
    if Path(metrics.scene_path).resolve() != Path(scene.root).resolve() or \
            SceneOptions.from_dict(run.scene_options) != scene.options:
        return None
    if run.fused.stat().st_mtime > (run.path / "metrics.json").stat().st_mtime:
        return None
    return metrics.eval


def fused_scores(a: SourceRun, b: SourceRun, scene: Scene, options: EvaluationOptions | None = None
                 ) -> tuple[dict[str, dict[str, list[float]] | None], list[str]]:
    """The ``eval`` block of each run's own fused cloud ("a" / "b" -> block or None; a deepc run's saved one when
    it holds, :func:`saved_score`) and a note for each run not scored."""
    if not scene.has_gt_points:
        return {"a": None, "b": None}, [f"scene {scene.name} has no GT points: fused clouds not scored"]
    runs = {"a": a, "b": b}
    notes = [f"{key.upper()} ({run.path}) has no fused cloud" for key, run in runs.items() if run.fused is None]
    saved = {key: saved_score(run, scene, options or EvaluationOptions()) for key, run in runs.items()}
    scores = score_clouds({key: run.fused for key, run in runs.items() if run.fused is not None and saved[key] is None},
                          scene, options)
    return {key: saved[key] or scores.get(key) for key in runs}, notes


def ours_fused_scores(a: SourceRun, b: SourceRun, scene: Scene, options: EvaluationOptions | None = None
                      ) -> tuple[dict[str, dict[str, list[float]] | None], list[str]]:
    """The ``eval`` block of each run's maps fused by our fusion, and a note for each run that could not be."""
    if not scene.has_gt_points:
        return {"a": None, "b": None}, []
    clouds, notes = {}, []
    for key, run in (("a", a), ("b", b)):
        try:
            clouds[key] = fuse_run(run, scene).xyz
        except DeepCError as exc:
            notes.append(f"{key.upper()}'s maps not fused by ours: {exc}")
    scores = score_clouds(clouds, scene, options)
    return {key: scores.get(key) for key in ("a", "b")}, notes


def compare_runs(a: SourceRun, b: SourceRun, scene: Scene, tolerance: float = TOLERANCE,
                 evaluate_fused: bool = True, options: EvaluationOptions | None = None,
                 fuse_ours: bool = False) -> Comparison:
    """Compare runs ``a`` and ``b`` of ``scene`` (:mod:`engine.compare.pixels` per view), then score their fused
    clouds (``evaluate_fused``) and their maps fused by our fusion (``fuse_ours``)."""
    names = [v.name for v in scene.views]
    keys_a, keys_b = match_names(list(a.keys), names), match_names(list(b.keys), names)
    views: list[ViewComparison] = []
    total = PixelCounts()
    for v in scene.views:
        if v.name not in keys_a or v.name not in keys_b:
            continue
        ka, kb = keys_a[v.name], keys_b[v.name]
        size = common_size(a.sizes[ka], b.sizes[kb], v.name)
        da, db = common_depths(a, b, (ka, kb), size)
        gt = _gt_at(scene, v.index, size)
        counts, maps = compare_pixels(da, db, gt, tolerance)
        views.append(ViewComparison(v.index, v.name, size, gt is not None, counts, maps, (ka, kb)))
        total = total + counts
    if not views:
        raise DeepCError(f"{a.path} and {b.path} have no view of scene {scene.name} in common (views are matched by "
                         "image name)")
    only_a = [n for n in names if n in keys_a and n not in keys_b]
    only_b = [n for n in names if n in keys_b and n not in keys_a]
    fused, notes = fused_scores(a, b, scene, options) if evaluate_fused else ({"a": None, "b": None}, [])
    ours, ours_notes = ours_fused_scores(a, b, scene, options) if fuse_ours else ({"a": None, "b": None}, [])
    return Comparison(a, b, scene, tolerance, views, only_a, only_b, total, fused, notes + ours_notes, ours)
