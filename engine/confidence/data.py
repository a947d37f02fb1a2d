"""Training / validation data: engine runs on scenes with GT depth, turned into network inputs and labels.

A *run* is the output folder of ``deepc run`` (:mod:`engine.run.folder`); :func:`engine.training.runs.ensure_run`
makes and caches them. :func:`load_run` reads a run's maps and computes the label maps (Kuhn et al. 2020, §3.2).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from engine.confidence.inputs import NORMAL, network_inputs
from engine.confidence.labels import label_map
from engine.core.errors import DeepCError
from engine.core.resample import resample_depth
from engine.io.images import resize_area
from engine.run.folder import map_path, read_map, run_scene
from engine.scene import Scene


@dataclasses.dataclass(eq=False)
class ViewSample:
    """One reference view: (6, H, W) float16 inputs and (H, W) int8 labels (1 / 0 / -1 unlabeled)."""

    scene: str
    view: str
    inputs: np.ndarray
    labels: np.ndarray

    @property
    def labelled_fraction(self) -> float:
        return float((self.labels >= 0).mean())


def flip_horizontal(inputs: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mirror a (6, H, W) input and its (H, W) labels left-right. Mirroring negates n_x, so the polar
    angle φ becomes π − φ: its encoding e = (φ + π)/(2π) becomes 1.5 − e (wrapped into [0, 1));
    θ is unchanged and invalid pixels (0, 0) stay invalid."""
    x = inputs[:, :, ::-1].copy()
    theta, e = x[NORMAL.start], x[NORMAL.start + 1]
    valid = (theta != 0) | (e != 0)
    flipped = 1.5 - e.astype(np.float32)
    flipped = np.where(flipped >= 1.0, flipped - 1.0, flipped)
    x[NORMAL.start + 1] = np.where(valid, flipped, 0).astype(x.dtype)
    return x, labels[:, ::-1].copy()


def load_run(run_dir: str | Path, scene: Scene | None = None, label_px: float = 2.0,
             require_gt: bool = True, refined: bool = False) -> list[ViewSample]:
    """Inputs and labels of every view of a run (views without GT depth get all-unlabeled maps).

    ``refined``: the refined depth, normal and counter maps of ``RUN/refined/`` instead (the inputs of the
    full pipeline's second confidence network; see :mod:`engine.run.refine`), labelled by comparing
    the refined depth with GT depth."""
    run_dir = Path(run_dir)
    scene = scene or run_scene(run_dir)
    if require_gt and not scene.has_gt_depth:
        raise DeepCError("scene has no ground-truth depth maps (ground_truth/depth_maps/): "
                         "it cannot give training labels", scene.root)
    samples = []
    prefix = "refined_" if refined else ""
    for v in scene.views:
        maps = {kind: read_map(run_dir, prefix + kind, v.name) for kind in ("depth", "normal", "counter")}
        for kind, m in maps.items():
            if m is None:
                hint = " (refine the run first: engine.run.refine.refine_run, deepc train --refined)" \
                    if refined else ""
                raise DeepCError(f"run has no {prefix.replace('_', ' ')}{kind} map for view {v.name}{hint}",
                                 map_path(run_dir, prefix + kind, v.name))
        depth = maps["depth"]
        cam = v.camera if (v.camera.width, v.camera.height) == depth.shape[::-1] else v.camera.rescaled(
            depth.shape[1], depth.shape[0])
        rgb = scene.image(v.index)
        if rgb.shape[:2] != depth.shape:
            rgb = resize_area(rgb, cam.size)
        labels = view_labels(scene, v.index, depth, label_px)
        if labels is None:
            labels = np.full(depth.shape, -1, np.int8)
        inputs = network_inputs(rgb, maps["normal"], maps["counter"], len(v.source_views)).astype(np.float16)
        samples.append(ViewSample(scene.name, v.name, inputs, labels))
    return samples


def view_labels(scene: Scene, index: int, depth: np.ndarray, label_px: float = 2.0, gt: np.ndarray | None = None
                ) -> np.ndarray | None:
    """Label map (Kuhn et al. 2020, §3.2) of ``depth`` estimated for view ``index``; None without GT depth.
    ``gt``: the view's GT depth, if already read (read from the scene otherwise)."""

    v = scene.views[index]
    if gt is None:
        gt = scene.gt_depth(index)
    if gt is None:
        return None
    h, w = depth.shape
    cam = v.camera if (v.camera.width, v.camera.height) == (w, h) else v.camera.rescaled(w, h)
    if gt.shape != depth.shape:
        gt = resample_depth(gt, cam.size)
    sources = [scene.views[j].camera for j in v.source_views]
    return label_map(depth, gt, cam, sources, max_depth=v.depth_range[1], threshold_px=label_px)
