"""Probe traces made by hand, in the schema of ``engine.run.probe`` (see ``workbench/trace/figures.py``), for
the inspector's tests: a pixel that converges from a random depth to the run's depth map over two levels,
and a region "re-run" that replaces the box's depths by GT depth. They check the viewer and the rerun stream
without replaying PatchMatch; the engine's own probe is tested against the kernels in its own tests."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from engine.core.errors import DeepCError
from engine.run.folder import read_map
from engine.run.probe import RegionResult
from engine.scene import Scene

ORIGINS = ("current", "pattern:0", "pattern:3", "perturbation", "random", "combination")


def _find_view(scene: Scene, view: str | int):
    for v in scene.views:
        if view in (v.name, v.index):
            return v
    raise DeepCError(f"no view {view!r} in scene {scene.name} (views: {', '.join(v.name for v in scene.views)})")


def _check_pixel(v, x: int, y: int) -> None:
    if not (0 <= x < v.camera.width and 0 <= y < v.camera.height):
        raise DeepCError(f"pixel ({x}, {y}) is outside view {v.name} ({v.camera.width}x{v.camera.height})")


def make_trace(scene: Scene, view: str | int, x: int, y: int, final_depth: float, seed: int = 0) -> dict:
    """A trace of pixel (x, y) of ``view`` that ends at ``final_depth``: two levels of two passes, three
    iterations each, six candidates per iteration with a cost per source view."""
    v = _find_view(scene, view)
    _check_pixel(v, x, y)
    rng = np.random.default_rng(seed + 7919 * x + y)
    sources = [scene.views[j].name for j in v.source_views]
    lo, hi = v.depth_range
    depth = float(rng.uniform(lo, hi))
    normal = [0.0, 0.0, -1.0]
    steps = []
    schedule = [(level, pass_, it) for level in (1, 0) for pass_ in (0, 1) for it in range(3)]
    for n, (level, pass_, it) in enumerate(schedule):
        target = final_depth + (depth - final_depth) * 0.5 ** (n + 1)
        if n == len(schedule) - 1:
            target = final_depth
        candidates = []
        for k, origin in enumerate(ORIGINS):
            d = target if k == 1 else float(target * rng.uniform(0.9, 1.1))
            costs = [None if rng.random() < 0.1 else float(rng.uniform(0.05, 1.5)) for _ in sources]
            selected = [name for name, c in zip(sources, costs, strict=True) if c is not None and c < 0.8]
            cost = float(np.mean([c for c in costs if c is not None] or [2.0]))
            candidates.append({"origin": origin, "depth": d, "normal": normal, "cost": cost if k != 1 else 0.2,
                               "view_costs": costs, "selected_views": selected,
                               "view_weights": [1.0 if name in selected else 0.0 for name in sources]})
        before = {"depth": depth, "normal": normal, "cost": 0.2 + 0.5 ** n}
        depth = target
        steps.append({"level": level, "pass": pass_, "iteration": it, "colour": "red" if (x + y) % 2 == 0 else "black",
                      "x_level": x >> level, "y_level": y >> level, "before": before,
                      "after": {"depth": depth, "normal": normal, "cost": 0.2 + 0.5 ** (n + 1)},
                      "candidates": candidates, "winner": 1, "decided_by": "lowest cost"})
    gt = scene.gt_depth(v.index) if scene.has_gt_depth else None
    gt_depth = float(gt[y, x]) if gt is not None and gt[y, x] > 0 else None
    error = abs(final_depth - gt_depth) / gt_depth if gt_depth else None
    return {"view": v.name, "x": x, "y": y, "source_views": sources, "iterations": steps,
            "final": {"depth": final_depth, "normal": normal, "cost": steps[-1]["after"]["cost"],
                      "counter_verdicts": {name: ("consistent" if i % 2 == 0 else "geometric")
                                           for i, name in enumerate(sources)},
                      "counter_details": {name: {"verdict": "geometric", "reprojection_px": 3.5}
                                          for i, name in enumerate(sources) if i % 2},
                      "confidence": 0.42, "gt_depth": gt_depth,
                      "label": None if error is None else int(error < 0.01),
                      "error": error}}


class HandProbe:
    """``probe_run`` and ``rerun_region`` of a run folder, answered from its depth maps (see module doc).

    ``calls`` records each call; ``delay_s`` makes a call take that long (the worker must not block the GUI)."""

    def __init__(self, scene: Scene, run_dir: Path, delay_s: float = 0.0):
        self.scene = scene
        self.run_dir = Path(run_dir)
        self.delay_s = delay_s
        self.calls: list[tuple] = []
        self.region_depth: dict[str, np.ndarray] = {}  # view name -> depth map after the last re-run

    def _depth(self, name: str) -> np.ndarray:
        if name in self.region_depth:
            return self.region_depth[name]
        return read_map(self.run_dir, "depth", name)

    def probe(self, run_dir, view, pixels, progress=None) -> list[dict]:
        self.calls.append(("probe", view, tuple(pixels)))
        v = _find_view(self.scene, view)
        depth = self._depth(v.name)
        out = []
        for i, (x, y) in enumerate(pixels):
            _check_pixel(v, x, y)
            if progress is not None:
                progress(i, len(pixels))
            time.sleep(self.delay_s)
            out.append(make_trace(self.scene, v.name, int(x), int(y), float(depth[y, x])))
        return out

    def rerun(self, run_dir, view, box, level=0, pass_index=0, overrides=None, probe_pixels=()) -> RegionResult:
        self.calls.append(("region", view, tuple(box), level, pass_index, dict(overrides or {})))
        v = _find_view(self.scene, view)
        x0, y0, w, h = box
        if w <= 0 or h <= 0 or x0 < 0 or y0 < 0 or x0 + w > v.camera.width or y0 + h > v.camera.height:
            raise DeepCError(f"box {tuple(box)} is not inside view {v.name} ({v.camera.width}x{v.camera.height})")
        time.sleep(self.delay_s)
        depth = self._depth(v.name).copy()
        gt = self.scene.gt_depth(v.index)
        window = (slice(y0, y0 + h), slice(x0, x0 + w))
        before = depth[window].copy()
        after = np.where(gt[window] > 0, gt[window], before).astype(np.float32)
        depth[window] = after
        self.region_depth[v.name] = depth

        def error(d):
            g = gt[window]
            return np.where((g > 0) & (d > 0), np.abs(d - g) / np.where(g > 0, g, 1), np.nan).astype(np.float32)

        def within(e):
            has = gt[window] > 0
            return 100.0 * float(np.nansum(e[has] < 0.01)) / max(1, int(has.sum()))

        traces = [make_trace(self.scene, v.name, x, y, float(depth[y, x]), seed=1) for x, y in probe_pixels]
        eb, ea = error(before), error(after)
        return RegionResult(tuple(box), before, after, eb, ea, within(eb), within(ea), traces, self.delay_s)
