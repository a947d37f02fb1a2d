"""Confidence of one engine run scored as benchmarks/paper/confidence_real.py does, shared with
benchmarks/paper/confidence_lofo.py: the pooled ROC-AUC of each network alone and with the back-facing rule, and
fusion of the unfiltered maps (vanilla), of the maps filtered at each τ (``fast``), with mask 1 / mask 2, and what
``--pipeline full`` makes of the run, scored at :data:`support.scoring.TOLERANCES` against the scene's GT points.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from engine.confidence.apply import auc_report, predict_samples
from engine.confidence.data import load_run
from engine.confidence.inference import facing_away
from engine.confidence.options import ConfidenceOptions
from engine.confidence.weights import load_weights
from engine.evaluation import EvaluationOptions
from engine.filtering import filter_by_confidence, filter_by_counter
from engine.fusion import FUSION_PRESETS, fuse, views_from_scene
from engine.run.folder import run_scene
from engine.run.pipeline import evaluate_cloud
from support.scoring import TOLERANCES, score_columns
from workbench.viewer.session import ViewerSession


def fused_row(session: ViewerSession, depths: list, normals: list, preset: str) -> dict:
    """Fuse (depth, normal) maps of a run's scene and score the cloud at :data:`TOLERANCES`."""
    scene, options = session.scene, FUSION_PRESETS[preset]
    total = sum(int((d.depth > 0).sum()) for d in session.data)
    cloud = fuse(views_from_scene(scene, depths, normals, None, options.check_num_images), options)
    result = evaluate_cloud(scene, cloud, EvaluationOptions(tolerances=TOLERANCES))
    return {"pixels_kept_pct": 100.0 * sum(int((d > 0).sum()) for d in depths) / max(1, total),
            "points": len(cloud), **score_columns(result)}


def ground_plane_masks(scene, samples: list, band: float = 0.15, distance: float = 0.10,
                       seed: int = 0) -> list[np.ndarray]:
    """(H, W) bool per view: pixels whose GT surface point lies within ``distance`` (scene units) of the
    dominant plane of the GT points in the bottom ``band`` of the images (RANSAC, 500 draws)."""
    from engine.core.resample import resample_depth

    points, clouds = [], []
    for v, s in zip(scene.views, samples, strict=True):
        h, w = s.labels.shape
        gt = scene.gt_depth(v.index)
        gt = gt if gt.shape == (h, w) else resample_depth(gt, (w, h))
        cam = v.camera if (v.camera.width, v.camera.height) == (w, h) else v.camera.rescaled(w, h)
        xyz = cam.camera_to_world(cam.pixel_rays() * gt[..., None]).reshape(h, w, 3)
        clouds.append((xyz, gt > 0))
        bottom = gt > 0
        bottom[:int((1 - band) * h)] = False
        points.append(xyz[bottom][::50])
    p = np.concatenate(points)
    rng, best = np.random.default_rng(seed), (-1, None, None)
    for _ in range(500):
        a, b, c = p[rng.choice(len(p), 3, replace=False)]
        n = np.cross(b - a, c - a)
        if np.linalg.norm(n) < 1e-12:
            continue
        n /= np.linalg.norm(n)
        count = int((np.abs((p - a) @ n) < distance / 2).sum())
        if count > best[0]:
            best = (count, n, a)
    _, n, a = best
    return [(np.abs((xyz - a) @ n) < distance) & valid for xyz, valid in clouds]


def score_scene(run: Path, models: dict, taus: list[float], rules: list[bool], preset: str,
                fusion: bool, exclude_ground: bool = False, full: tuple[Path, Path] | None = None) -> dict:
    samples = load_run(run)
    out: dict = {"views": len(samples), "variants": {}}
    offground = None
    if exclude_ground:  # the same views with the GT ground plane unlabelled (fountain_p11: its GT ground is off)
        masks = ground_plane_masks(run_scene(run), samples)
        offground = [dataclasses.replace(s, labels=np.where(m, -1, s.labels).astype(np.int8))
                     for s, m in zip(samples, masks, strict=True)]
        out["ground_pct"] = 100.0 * sum(int((m & (s.labels >= 0)).sum()) for s, m in zip(samples, masks,
                                                                                      strict=True)) / max(
            1, sum(int((s.labels >= 0).sum()) for s in samples))
    session = ViewerSession.open(run) if fusion else None
    if fusion and session.scene.has_gt_points:
        out["vanilla"] = fused_row(session, [d.depth for d in session.data], [d.normal for d in session.data],
                                   preset)
        for k in (1, 2):
            filtered = [filter_by_counter(d.depth, d.normal, d.counter, k) for d in session.data]
            out[f"mask{k}"] = fused_row(session, [f[0] for f in filtered], [f[1] for f in filtered], preset)
    for name, model in models.items():
        t = time.perf_counter()
        raw = predict_samples(model, samples, ConfidenceOptions(zero_backfacing=False))
        ruled = [np.where(facing_away(s.inputs), np.float32(0), c) for s, c in zip(samples, raw, strict=True)]
        row = {"auc_network": auc_report(samples, raw)["auc"], "auc_rule": auc_report(samples, ruled)["auc"],
               "inlier_pct": auc_report(samples, raw)["inlier_pct"], "fast": {}}
        if offground is not None:
            row["auc_network_offground"] = auc_report(offground, raw)["auc"]
            row["auc_rule_offground"] = auc_report(offground, ruled)["auc"]
        if fusion and session.scene.has_gt_points:
            for rule in rules:
                conf = ruled if rule else raw
                for tau in taus:
                    filtered = [filter_by_confidence(d.depth, d.normal, c, tau)
                                for d, c in zip(session.data, conf, strict=True)]
                    row["fast"][f"{'rule' if rule else 'network'}@{tau}"] = fused_row(
                        session, [f[0] for f in filtered], [f[1] for f in filtered], preset)
        row["seconds"] = time.perf_counter() - t
        out["variants"][name] = row
    if full is not None and fusion and session.scene.has_gt_points:
        out["full"] = score_full(run, session, *full, preset)
    return out


def score_full(run: Path, session: ViewerSession, weights: Path, refined_weights: Path, preset: str) -> dict:
    """What ``--pipeline full`` computes from this run with these networks (default options): refinement guided
    by network 1 (cached in RUN/refined/), the refined maps' confidence from network 2, PatchMatch's confident
    estimates kept (``refinement.keep_confident``), the filter at ``refinement.refined_confidence_tau`` and the sky
    filter; plus the depth of vanilla, refined and fused-by-full maps against GT. Row ``refined + conf``: the
    refined maps alone, filtered (the paper's Table 3 row)."""
    from engine.confidence.data import load_run as load_samples
    from engine.refinement.guard import keep_confident
    from engine.refinement.views import sky_filter_views
    from engine.run.folder import read_map
    from engine.run.pipeline import PipelineOptions
    from engine.run.refine import refine_run
    from engine.run.scores import depth_block

    options = PipelineOptions(pipeline="full").validate()
    t = time.perf_counter()
    done = refine_run(run, weights=weights, options=options)
    scene, data = session.scene, session.data
    names = [v.name for v in scene.views]
    refined = [(read_map(run, "refined_depth", n), read_map(run, "refined_normal", n)) for n in names]
    samples = load_samples(run, refined=True, require_gt=False)
    conf2 = predict_samples(load_weights(refined_weights), samples, options.confidence)
    conf1 = predict_samples(load_weights(weights), load_run(run), options.confidence)
    tau2 = options.refinement.refined_confidence_tau
    guarded = [keep_confident(v.depth, v.normal, c1, d, n, c2, options.refinement.keep_confident)
               for v, c1, (d, n), c2 in zip(data, conf1, refined, conf2, strict=True)]
    unguarded = [filter_by_confidence(d, n, c, tau2) for (d, n), c in zip(refined, conf2, strict=True)]
    kept = [filter_by_confidence(d, n, c, tau2) for d, n, c in guarded]
    sky_d, sky_n, _ = sky_filter_views(scene, [k[0] for k in kept], [k[1] for k in kept], [d.depth for d in data],
                                       conf1)

    out = {"refine_seconds": done.seconds, "reused": done.reused,
           "refined": fused_row(session, [d for d, _ in refined], [n for _, n in refined], preset),
           f"refined + conf {tau2}": fused_row(session, [k[0] for k in unguarded], [k[1] for k in unguarded],
                                              preset),
           "full": fused_row(session, sky_d, sky_n, preset),
           "auc_refined": auc_report(samples, conf2)["auc"] if any((s.labels >= 0).any() for s in samples) else None}
    if scene.has_gt_depth:
        out["depth_vanilla"] = depth_block(scene, lambda i: data[i].depth)[0]
        out["depth_refined"] = depth_block(scene, lambda i: refined[i][0])[0]
        out["depth_full"] = depth_block(scene, lambda i: guarded[i][0])[0]
    out["seconds"] = time.perf_counter() - t
    return out
