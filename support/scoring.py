"""Maps of a finished run, fused and scored against GT: the pieces the quality benchmarks share.

Rows hold F1, completeness and accuracy in percent per tolerance as ``f1@0.02``, ``completeness@0.02``,
``accuracy@0.02`` (the keys of the committed Table 2 / Table 3 / fusion results).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from engine.confidence.options import ConfidenceOptions
from engine.confidence.weights import DEFAULT_REFINED_WEIGHTS, DEFAULT_WEIGHTS
from engine.evaluation import EvaluationOptions
from engine.fusion import fuse, views_from_scene
from engine.patchmatch import ViewMaps
from engine.refinement.options import RefinementOptions
from engine.run.folder import read_map
from engine.run.fused_maps import FusionRule, RunViewMaps, fused_maps
from engine.run.pipeline import PipelineOptions, confidence_stage, evaluate_cloud

TOLERANCES = (0.02, 0.05)
TAU = 0.05  # the fast and full pipelines' default confidence threshold


def score_columns(result, tolerances: Sequence[float] = TOLERANCES) -> dict[str, float]:
    """``f1@t``, ``completeness@t``, ``accuracy@t`` of an evaluation result at each tolerance."""
    row = {}
    for tol in tolerances:
        at = result.at(tol)
        row.update({f"f1@{tol}": at["f1"], f"completeness@{tol}": at["completeness"],
                    f"accuracy@{tol}": at["accuracy"]})
    return row


def fuse_and_score(scene, depths: list, normals: list, options, tolerances: Sequence[float] = TOLERANCES) -> dict:
    """Fuse the maps with fusion ``options`` and score the cloud against the scene's GT points
    (unobserved-space rule, as ``deepc eval``)."""
    t = time.perf_counter()
    cloud = fuse(views_from_scene(scene, depths, normals, None, options.check_num_images), options)
    result = evaluate_cloud(scene, cloud, EvaluationOptions(tolerances=tuple(tolerances)))
    return {"points": len(cloud), "pixels": int(sum(int((d > 0).sum()) for d in depths)),
            "seconds": time.perf_counter() - t, **score_columns(result, tolerances)}


def score_cells(row: dict) -> str:
    """F1, completeness and accuracy of a row at 2 cm | 5 cm, as table cells."""
    return " | ".join(f"{row[f'f1@{t}']:>6.2f} {row[f'completeness@{t}']:>7.2f} {row[f'accuracy@{t}']:>6.2f}"
                      for t in (0.02, 0.05))


def network_confidence(scene, depths: list, normals: list, counter: list, weights: Path) -> list[np.ndarray]:
    """Confidence of maps as ``--pipeline fast|full`` computes it (tiled bf16, back-facing rule)."""
    empty = [np.zeros(d.shape, np.float32) for d in depths]
    maps = [ViewMaps(d, n, e, e.astype(np.uint32)) for d, n, e in zip(depths, normals, empty, strict=True)]
    return confidence_stage(scene, maps, counter, ConfidenceOptions(weights=str(weights)))


def pipeline_maps(scene, run_dir: Path, full_tau: float = TAU) -> dict[str, tuple[list, list]]:
    """{pipeline: (depth maps, normal maps)} as the pipelines handed them to fusion when the fusion-preset and
    refined-fusion results were made: fast at τ 0.05; full (only when the run has refined maps) network 2 at
    ``full_tau`` on every refined pixel (no ``keep_confident``) and the sky filter; shipped weights."""
    options = PipelineOptions(confidence=ConfidenceOptions(tau=TAU),
                              refinement=RefinementOptions(refined_confidence_tau=full_tau, keep_confident=None))
    maps = shipped_pipeline_maps(scene, run_dir, options)
    return {name: (depth, normal) for name, (depth, normal, _) in maps.items()}


def shipped_pipeline_maps(scene, run_dir: Path, options: PipelineOptions | None = None
                          ) -> dict[str, tuple[list, list, list | None]]:
    """{pipeline: (depth maps, normal maps, confidence maps or None)} as today's pipelines hand them to fusion,
    with the shipped weights and ``options`` (default: the defaults) - vanilla: PatchMatch maps; fast: network 1
    at ``confidence.tau``; full (only when the run has refined maps): network 2 on the refined maps (the run's own
    refined confidence when it stored one), PatchMatch's estimate where network 1 gives it at least
    ``refinement.keep_confident``, ``refinement.refined_confidence_tau``, the sky filter."""
    options = options or PipelineOptions()
    names = [v.name for v in scene.views]
    depth, normal, counter = ([read_map(run_dir, kind, n) for n in names] for kind in ("depth", "normal", "counter"))
    if any(m is None for m in depth + normal + counter):
        raise SystemExit(f"{run_dir}: depth, normal or counter maps missing")
    conf = network_confidence(scene, depth, normal, counter, DEFAULT_WEIGHTS)
    views = [RunViewMaps(d, n, confidence=c) for d, n, c in zip(depth, normal, conf, strict=True)]
    fast = fused_maps(scene, FusionRule.of("fast", options.confidence, options.refinement), views)
    out = {"vanilla": (depth, normal, None), "fast": ([f.depth for f in fast], [f.normal for f in fast], conf)}
    refined = [[read_map(run_dir, kind, n) for n in names]
               for kind in ("refined_depth", "refined_normal", "refined_counter")]
    if all(m is not None for maps in refined for m in maps):
        conf2 = [read_map(run_dir, "refined_confidence", n) for n in names]
        if any(c is None for c in conf2):
            conf2 = network_confidence(scene, *refined, DEFAULT_REFINED_WEIGHTS)
        for v, rd, rn, c2 in zip(views, refined[0], refined[1], conf2, strict=True):
            v.refined_depth, v.refined_normal, v.refined_confidence = rd, rn, c2
        full = fused_maps(scene, FusionRule.of("full", options.confidence, options.refinement), views)
        out["full"] = ([f.depth for f in full], [f.normal for f in full], [f.confidence for f in full])
    return out


def within_by_region(scene, run_dir: Path, masks_of_view: Callable[[int, np.ndarray], dict[str, np.ndarray]],
                     maps: str = "depth") -> dict[str, dict[str, Any]]:
    """Per region, pooled over the views: share of the GT pixels, within 1 % / 5 % and the 1 % misses as points
    of the total. ``masks_of_view(index, gt)`` gives {region: (H, W) bool}; "all" (every GT pixel) is added."""
    counts: dict[str, np.ndarray] = {}  # pixels, within 1 %, within 5 %
    for v in scene.views:
        gt = scene.gt_depth(v.index)
        depth = read_map(run_dir, maps, v.name)
        if gt is None or depth is None:
            continue
        has = gt > 0
        err = np.abs(depth - gt)
        w1 = has & (depth > 0) & (err <= 0.01 * gt)
        w5 = has & (depth > 0) & (err <= 0.05 * gt)
        for name, m in {**masks_of_view(v.index, gt), "all": has}.items():
            counts.setdefault(name, np.zeros(3, np.int64))
            counts[name] += [int(m.sum()), int((w1 & m).sum()), int((w5 & m).sum())]
    total = max(int(counts["all"][0]), 1) if counts else 1
    return {name: {"share_pct": 100 * n / total, "within_1pct": 100 * n1 / max(n, 1),
                   "within_5pct": 100 * n5 / max(n, 1), "misses_1pct_points": 100 * (n - n1) / total,
                   "pixels": int(n)} for name, (n, n1, n5) in counts.items()}
