"""Plain-Python fusion, the reference that ``engine.fusion.fuse`` is tested against."""

from __future__ import annotations

import math

import numpy as np

from engine.fusion.cloud import FusedCloud, FusionView
from engine.fusion.kernel import reprojection_limit_sq, round_half_away
from engine.fusion.options import FusionOptions
from engine.fusion.packing import check_view, rgb_uint8


def fuse_reference(views: list[FusionView], options: FusionOptions | None = None) -> FusedCloud:
    """Slow, straightforward implementation of :func:`fuse` used to test the numba kernel."""
    options = (options or FusionOptions()).validate()
    n_views = len(views)
    if n_views == 0:
        return FusedCloud.empty()
    for i, v in enumerate(views):
        check_view(i, v, n_views)
    overlap = []
    for i, v in enumerate(views):
        lst = []
        for j in v.overlap:
            if j != i and j not in lst:
                lst.append(j)
        overlap.append(lst[:options.check_num_images])
    depth = [np.asarray(v.depth, np.float64) for v in views]
    normals = [np.asarray(v.normal, np.float64) for v in views]
    colours = [rgb_uint8(v.rgb) for v in views]
    Ps = [np.hstack([v.camera.K_idx @ v.camera.R, (v.camera.K_idx @ v.camera.t)[:, None]]) for v in views]
    consumed = [np.zeros(d.shape, bool) for d in depth]
    fused = [False] * n_views
    min_cos = math.cos(math.radians(options.max_normal_error))
    out: dict[str, list] = {k: [] for k in ("xyz", "nrm", "rgb", "nv", "conf", "src", "npx")}

    def backproject(k, row, col, d):
        cam = views[k].camera
        Xc = d * (np.linalg.inv(cam.K_idx) @ np.array([col, row, 1.0]))
        return cam.R.T @ (Xc - cam.t)

    img = 0
    while img >= 0:
        H, W = depth[img].shape
        for row0 in range(H):
            for col0 in range(W):
                if consumed[img][row0, col0] or depth[img][row0, col0] <= 0:
                    continue
                stack = [(img, row0, col0, 0)]
                pts, nrms, cols, vis, confs, views_of = [], [], [], set(), [], []
                ref = ref_n = None
                while stack:
                    k, row, col, lvl = stack.pop()
                    d = depth[k][row, col]
                    if consumed[k][row, col] or d <= 0:
                        continue
                    if lvl > 0:
                        p = Ps[k] @ np.append(ref, 1.0)
                        if abs((p[2] - d) / d) > options.max_depth_error:
                            continue
                        if (p[0] / p[2] - col) ** 2 + (p[1] / p[2] - row) ** 2 > reprojection_limit_sq(options):
                            continue
                    nw = views[k].camera.R.T @ normals[k][row, col]
                    if lvl > 0 and float(ref_n @ nw) < min_cos:
                        continue
                    X = backproject(k, row, col, d)
                    consumed[k][row, col] = True
                    pts.append(X)
                    nrms.append(nw)
                    cols.append(colours[k][row, col].astype(np.float64))
                    vis.add(k)
                    views_of.append(k)
                    if views[k].confidence is not None and not math.isnan(views[k].confidence[row, col]):
                        confs.append(float(views[k].confidence[row, col]))
                    if lvl == 0:
                        ref, ref_n = X, nw
                    if len(pts) >= options.max_num_pixels:
                        break
                    if lvl >= options.max_traversal_depth - 1:
                        continue
                    for j in overlap[k]:
                        if fused[j]:
                            continue
                        q = Ps[j] @ np.append(X, 1.0)
                        if q[2] <= 0:
                            continue
                        u, v_ = q[0] / q[2], q[1] / q[2]
                        if not (-1 < u < views[j].camera.width and -1 < v_ < views[j].camera.height):
                            continue
                        nc, nr = round_half_away(u), round_half_away(v_)
                        if 0 <= nc < views[j].camera.width and 0 <= nr < views[j].camera.height:
                            stack.append((j, nr, nc, lvl + 1))
                if len(pts) < max(options.min_num_pixels, 1):
                    continue
                mn = np.median(np.array(nrms), axis=0)
                norm = float(np.linalg.norm(mn))
                if norm < 1.1920929e-07:
                    continue
                if options.point_per_pixel:
                    for X, nw, c, k in zip(pts, nrms, cols, views_of, strict=True):
                        out["xyz"].append(X)
                        out["nrm"].append(nw)
                        out["rgb"].append(c)
                        out["nv"].append(len(vis))
                        out["conf"].append(np.mean(confs) if confs else np.nan)
                        out["src"].append(k)
                        out["npx"].append(len(pts))
                    continue
                out["xyz"].append(np.median(np.array(pts), axis=0))
                out["nrm"].append(mn / norm)
                out["rgb"].append([min(255, round_half_away(c)) for c in np.median(np.array(cols), axis=0)])
                out["nv"].append(len(vis))
                out["conf"].append(np.mean(confs) if confs else np.nan)
                out["src"].append(img)
                out["npx"].append(len(pts))
        fused[img] = True
        nxt = next((j for j in overlap[img] if not fused[j]), -1)
        if nxt < 0:
            nxt = next((j for j in range(n_views) if not fused[j]), -1)
        img = nxt
    if not out["xyz"]:
        return FusedCloud.empty()
    return FusedCloud(np.array(out["xyz"]), np.array(out["nrm"], np.float32), np.array(out["rgb"], np.uint8),
                      np.array(out["nv"], np.int32), np.array(out["conf"], np.float32),
                      np.array(out["src"], np.int32), np.array(out["npx"], np.int32))

