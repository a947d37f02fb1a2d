"""The end of a pixel probe's trace and where traces go: ``final`` (the counter map's per-view verdicts, the
confidence, GT depth, label and error) and ``OUT/probes/<view>/<x>_<y>.json`` (docs/probe_schema.md).

Used by the pipeline (``deepc run --probe``) and by ``engine.run.probe`` (a finished run, on demand).
The per-view verdicts follow ``consistency.counter_kernel`` for one pixel (Kuhn et al. 2020, §3.2; COLMAP's
checks), calling its numba functions from Python.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from engine.confidence.data import view_labels
from engine.consistency import CounterOptions
from engine.core.resample import resample_depth
from engine.io.atomic import atomic_write_text
from engine.patchmatch.context import build_context, fine_window_region
from engine.patchmatch.geometry import plane_vector, ray, reprojection
from engine.patchmatch.kernels import photometric_cost
from engine.patchmatch.multiscale import PatchMatchView
from engine.patchmatch.ncc import ncc_work
from engine.patchmatch.options import PatchMatchOptions

PROBES_DIR = "probes"
SCHEMA_VERSION = 1


def probe_path(out_dir: str | Path, view_name: str, x: int, y: int) -> Path:
    """OUT/probes/<view>/<x>_<y>.json (view names may contain '/')."""
    return Path(out_dir) / PROBES_DIR / view_name / f"{x}_{y}.json"


def write_traces(out_dir: str | Path, traces: list[dict[str, Any]]) -> list[Path]:
    """Write each trace atomically to :func:`probe_path`; returns the paths."""
    paths = []
    for t in traces:
        path = probe_path(out_dir, t["view"], t["x"], t["y"])
        atomic_write_text(path, json.dumps({"schema": SCHEMA_VERSION, **t}, allow_nan=False))
        paths.append(path)
    return paths


def counter_verdicts(views: list[PatchMatchView], index: int, depths: list[np.ndarray], normal: np.ndarray,
                     pixels: list[tuple[int, int]], options: CounterOptions | None = None,
                     ncc_options: PatchMatchOptions | None = None, region: np.ndarray | None = None
                     ) -> list[dict[str, dict[str, Any]]]:
    """Per pixel (x, y) of view ``index``: per source view name, ``verdict`` — "consistent", or the first check
    that failed: "geometric" (forward-backward reprojection error above ``reproj_px``, or no reprojection, or
    the relative depth check), "angle" (triangulation angle), "facing", "photometric" (NCC) — or "none" (no
    estimate) — with ``reprojection_px``, ``angle_deg`` and ``ncc_cost`` where computed. Same checks, order
    and inputs as ``consistency.compute_counter_maps`` (``depths``: every view's final depth, ``normal`` this
    view's). ``region``: :func:`final_region` of the view, if already made."""
    options = (options or CounterOptions()).validate()
    ncc_options = (ncc_options or PatchMatchOptions()).validate()
    v = views[index]
    src = list(v.source_views)
    depth = np.ascontiguousarray(depths[index], np.float32)
    normal = np.ascontiguousarray(normal, np.float32)
    names = [views[j].name for j in src]
    if not src:
        return [{} for _ in pixels]
    # a pixel's NCC reads its own reference terms alone: those of the probed pixels' bounding box suffice
    box = (min(p[0] for p in pixels), min(p[1] for p in pixels), max(p[0] for p in pixels) + 1,
           max(p[1] for p in pixels) + 1) if pixels else (0, 0, 0, 0)
    ctx = build_context(np.asarray(v.image_gray, np.float32), v.camera,
                        [np.asarray(views[j].image_gray, np.float32) for j in src], [views[j].camera for j in src],
                        ncc_options, [depths[j] for j in src],
                        final_region(depth, normal, v, ncc_options) if region is None else region, box=box)
    cos_tri_max = math.cos(math.radians(options.tri_angle_min_deg))
    max_cost = 1.0 - float(options.ncc_min)
    win, sidx = ncc_work(ctx.ox.shape[1])
    out = []
    for x, y in pixels:
        z = np.float64(depth[y, x])
        nx, ny, nz = (np.float64(c) for c in normal[y, x])
        rp = ray(ctx.kinv, x, y)
        m0, m1, m2, ok = plane_vector(ctx.kinv, rp, z, nx, ny, nz) if z > 0 else (0.0, 0.0, 0.0, False)
        res: dict[str, dict[str, Any]] = {}
        if not ok:
            out.append({name: {"verdict": "none"} for name in names})
            continue
        n = ctx.window_at(x, y, win)
        p = np.array([z * rp[0], z * rp[1], z * rp[2]])
        for j, name in enumerate(names):
            err, zr = reprojection(ctx.geo, j, ctx.sdepth, x, y, z)
            info: dict[str, Any] = {"reprojection_px": float(err) if err >= 0 else None}
            res[name] = info
            if err < 0.0 or err > options.reproj_px or (options.rel_depth and abs(zr - z) >= options.rel_depth * z):
                info["verdict"] = "geometric"
                continue
            a, b = -p, ctx.centers[j] - p
            na, nb = float(np.sqrt(a @ a)), float(np.sqrt(b @ b))
            cos = (a @ b) / (na * nb) if na > 0 and nb > 0 else 1.0
            info["angle_deg"] = math.degrees(math.acos(min(max(cos, -1.0), 1.0)))
            if na <= 0 or nb <= 0 or cos > cos_tri_max:
                info["verdict"] = "angle"
                continue
            if options.check_facing and nx * b[0] + ny * b[1] + nz * b[2] <= 0.0:
                info["verdict"] = "facing"
                continue
            cost = photometric_cost(ctx.flat, ctx.stride, ctx.plane, ctx.geo, j, win, n, ctx.mu_a[y, x],
                                    ctx.var_a[y, x], x, y, m0, m1, m2, float(ncc_options.min_var), sidx)
            info["ncc_cost"] = float(cost)
            info["verdict"] = "photometric" if cost > max_cost else "consistent"
        out.append(res)
    return out


def final_region(depth: np.ndarray, normal: np.ndarray, view: PatchMatchView,
                 ncc_options: PatchMatchOptions | None = None) -> np.ndarray | None:
    """Where the counter maps' NCC of ``view``'s final maps (depth (H, W), normal (H, W, 3)) may use the fine
    window (``context.fine_window_region`` of the final map), as :func:`counter_verdicts` reads it."""
    options = (ncc_options or PatchMatchOptions()).validate()
    return fine_window_region(np.ascontiguousarray(depth, np.float32), np.ascontiguousarray(normal, np.float32),
                              view.camera, options)


def final_entries(scene: Any, index: int, views: list[PatchMatchView], depths: list[np.ndarray],
                  normal: np.ndarray, cost: np.ndarray | None, counter: np.ndarray | None,
                  confidence: np.ndarray | None, pixels: list[tuple[int, int]],
                  counter_options: CounterOptions | None = None, gt: np.ndarray | None = None,
                  region: np.ndarray | None = None) -> list[dict[str, Any]]:
    """The ``final`` dict of each probed pixel (x, y) of view ``index``: ``depth``, ``normal``, ``cost`` (the
    written maps), ``counter`` and ``counter_verdicts`` (:func:`counter_verdicts`; the verdict strings, with
    the numbers under ``counter_details``), ``confidence`` (or None), ``gt_depth``, ``label`` (1 inlier, 0
    outlier, -1 unlabelled; Kuhn et al. 2020, §3.2) and ``error`` (relative |z - z_gt| / z_gt), None without
    GT or without an estimate. ``gt``: the view's GT depth at the maps' size (:func:`view_gt_depth`), and
    ``region`` its :func:`final_region`, if already made."""
    depth = depths[index]
    verdicts = counter_verdicts(views, index, depths, normal, pixels, counter_options, region=region)
    if gt is None:
        gt = view_gt_depth(scene, index, depth.shape)
    labels = None
    if gt is not None:
        # a label is a function of its own pixel's depth alone (Kuhn et al. 2020, §3.2): label the probed ones only
        probed = np.zeros_like(depth)
        cols, rows = np.array([p[0] for p in pixels], np.intp), np.array([p[1] for p in pixels], np.intp)
        probed[rows, cols] = depth[rows, cols]
        labels = view_labels(scene, index, probed, gt=gt)
    out = []
    for (x, y), ver in zip(pixels, verdicts, strict=True):
        z = float(depth[y, x])
        g = float(gt[y, x]) if gt is not None and np.isfinite(gt[y, x]) and gt[y, x] > 0 else None
        out.append({"depth": z, "normal": [float(c) for c in normal[y, x]],
                    "cost": float(cost[y, x]) if cost is not None else None,
                    "counter": int(counter[y, x]) if counter is not None else None,
                    "counter_verdicts": {k: d["verdict"] for k, d in ver.items()},
                    "counter_details": ver,
                    "confidence": float(confidence[y, x]) if confidence is not None else None,
                    "gt_depth": g, "label": int(labels[y, x]) if labels is not None else None,
                    "error": abs(z - g) / g if g is not None and z > 0 else None})
    return out


def view_gt_depth(scene: Any, index: int, shape: tuple[int, int]) -> np.ndarray | None:
    """View ``index``'s GT depth (H, W) resampled to ``shape`` (H, W) of its maps; None without GT depth."""
    gt = scene.gt_depth(index) if scene is not None and scene.has_gt_depth else None
    if gt is not None and gt.shape != tuple(shape):
        gt = resample_depth(gt, (shape[1], shape[0]))
    return gt


def finish_probe(probe: Any, scene: Any, views: list[PatchMatchView], maps: list[Any], counter: list[np.ndarray] | None,
                 confidence: list[np.ndarray] | None, counter_options: CounterOptions | None,
                 out_dir: str | Path | None) -> list[dict[str, Any]]:
    """Fill the ``final`` entries of a
    :class:`engine.patchmatch.probe.pixel_probe.PixelProbe` that ran with the PatchMatch of
    ``views`` (``maps``: every view's final ``ViewMaps``) and write its traces into ``out_dir`` (None: don't)."""
    i = probe.view
    finals = final_entries(scene, i, views, [m.depth for m in maps], maps[i].normal, maps[i].cost,
                           counter[i] if counter is not None else None,
                           confidence[i] if confidence is not None else None, probe.pixels, counter_options)
    for p, f in zip(probe.pixels, finals, strict=True):
        probe.set_final(p, f)
    traces = probe.traces()
    if out_dir is not None:
        write_traces(out_dir, traces)
    return traces
