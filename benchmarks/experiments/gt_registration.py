"""Is the GT registered to the cameras? Per-view depth bias of GT against geometry the cameras triangulate.

    .venv/bin/python benchmarks/experiments/gt_registration.py SCENE [--run RUN_DIR]
        [--json benchmarks/results/gt_registration_fountain_p11.json]

The scene's sparse points are real SIFT features triangulated with the scene's (GT) cameras held fixed, so
they lie where the cameras and images say the surface is. For every view this prints the median signed
relative difference z_sparse / z_gt - 1 at the points' observations (|difference| < 1 %, so occlusions do
not count), and the same for a run's PatchMatch depth maps (``--run``). A bias that changes sign across the
views means the GT surface is displaced from the geometry the cameras see; no photo-consistent method can
then match it to better than that bias.

It then registers the GT surface to the sparse points (trimmed point-to-plane ICP, 7-DoF similarity) and
reports the bias left after registration and, with ``--run``, the run's cloud (its fused.ply) scored under
the OpenMVS peer's rule (every valid GT depth pixel a GT point, unobserved space ignored): as it is, after
moving the cloud by the same similarity into the GT's frame, and against GT depth maps each scaled by its
own view's bias against the sparse points. The corrected scores are diagnostics, not a replacement
for the contract's metric: the peer numbers were measured against the unregistered GT.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from engine.evaluation import EvaluationOptions, evaluate_points
from engine.fusion import read_fused_ply
from engine.run.folder import read_map, read_metrics
from engine.scene import SceneOptions, load_scene
from support import bench
from support.gt_normals import depth_normals

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"scene": str, "sparse_points": int, "gt_points": int, "sparse_vs_gt": list, "similarity": dict,
          "sparse_vs_registered_gt": list, "run": str, "patchmatch_vs_gt": list, "peer_rule": dict,
          "peer_rule_registered": dict, "peer_rule_per_view_corrected": dict}



def view_bias(scene, points: np.ndarray, depth_of_view) -> list[dict]:
    """Per view: median signed z / z_ref - 1 (%) of ``points`` seen by the view, against ``depth_of_view(i)``."""
    rows = []
    for view in scene.views:
        ref = depth_of_view(view.index)
        pix, z = view.camera.project(points)
        pix = np.nan_to_num(pix, nan=-1.0, posinf=-1.0, neginf=-1.0)
        col, row = np.rint(pix[:, 0]).astype(np.int64), np.rint(pix[:, 1]).astype(np.int64)
        h, w = ref.shape
        inside = (z > 0) & (col >= 0) & (row >= 0) & (col < w) & (row < h)
        zr = np.zeros(len(z))
        zr[inside] = ref[row[inside], col[inside]]
        ok = zr > 0
        rel = z[ok] / zr[ok] - 1.0
        rel = rel[np.abs(rel) < 0.01]
        rows.append({"view": view.name, "points": int(len(rel)),
                     "median_pct": float(100 * np.median(rel)) if len(rel) else float("nan")})
    return rows


def gt_surface(scene, step: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """GT depth pixels of every view (every ``step``-th row and column) as world points and world normals."""
    points, normals = [], []
    for cam, depth in scene.gt_views():
        n_cam = depth_normals(cam, depth)[::step, ::step]
        X = cam.backproject(depth)[::step, ::step]
        ok = np.linalg.norm(n_cam, axis=-1) > 0
        points.append(X[ok])
        normals.append(n_cam[ok] @ cam.R)  # camera -> world: R^T n, as row vectors n R
    return np.concatenate(points), np.concatenate(normals)


def register_similarity(moving: np.ndarray, fixed: np.ndarray, normal: np.ndarray, iterations: int = 40,
                        start_radius: float = 0.1) -> tuple[float, np.ndarray, np.ndarray, dict]:
    """Similarity (s, R, t) minimising point-to-plane distances of s R moving + t to ``fixed`` (trimmed ICP).

    Pairs farther than max(3 x median distance, 5 mm) (at first ``start_radius``) are left out.
    Returns s, R (3, 3), t (3,) and the final residual statistics (metres)."""
    tree = cKDTree(fixed)
    s, R, t = 1.0, np.eye(3), np.zeros(3)
    radius = start_radius
    for _ in range(iterations):
        cur = s * moving @ R.T + t
        dist, idx = tree.query(cur)
        keep = dist < radius
        p, q, n = cur[keep], fixed[idx[keep]], normal[idx[keep]]
        # linearised residual n.(p + w x p + sigma p + dt - q): unknowns w (3), dt (3), sigma (1)
        a = np.concatenate([np.cross(p, n), n, np.einsum("ij,ij->i", n, p)[:, None]], axis=1)
        r = np.einsum("ij,ij->i", n, q - p)
        x, *_ = np.linalg.lstsq(a, r, rcond=None)
        w, dt, sigma = x[:3], x[3:6], x[6]
        dR = Rotation.from_rotvec(w).as_matrix()
        # new map: (1 + sigma) dR (s R m + t) + dt
        s, R, t = s * (1 + sigma), dR @ R, (1 + sigma) * dR @ t + dt
        radius = max(3.0 * float(np.median(np.abs(r))), 0.005)
    cur = s * moving @ R.T + t
    _, idx = tree.query(cur)
    plane = np.abs(np.einsum("ij,ij->i", normal[idx], cur - fixed[idx]))
    return s, R, t, {"pairs": int(keep.sum()), "median_plane_distance_m": float(np.median(plane)),
                     "within_1cm_pct": float(100 * np.mean(plane < 0.01))}


def summary(result: dict) -> list[dict]:
    """Per view: median bias (%) of the sparse points against the GT, after registration, and of the run."""
    rows = []
    for i, row in enumerate(result["sparse_vs_gt"]):
        out = {"view": row["view"], "sparse vs GT %": row["median_pct"],
               "after registration %": result["sparse_vs_registered_gt"][i]["median_pct"]}
        if "patchmatch_vs_gt" in result:
            out["PatchMatch vs GT %"] = result["patchmatch_vs_gt"][i]["median_pct"]
        rows.append(out)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", type=Path)
    parser.add_argument("--run", type=Path, default=None)
    parser.add_argument("--json", type=Path, default=None,
                        help="default: benchmarks/results/gt_registration_<scene>.json")
    args = parser.parse_args()
    scene_options = SceneOptions()
    if args.run is not None:
        scene_options = SceneOptions.from_dict(read_metrics(args.run)["options"]["scene"])
    scene = load_scene(args.scene, scene_options)
    if not scene.has_gt_depth or not scene.has_gt_points:
        raise SystemExit(f"{args.scene}: needs ground_truth/depth_maps and ground_truth/points.ply")
    sparse = np.asarray(scene.model.points, np.float64)
    gt_points, gt_normals = gt_surface(scene)
    out = {"scene": scene.name, "sparse_points": len(sparse), "gt_points": len(gt_points)}

    out["sparse_vs_gt"] = view_bias(scene, sparse, scene.gt_depth)
    s, R, t, fit = register_similarity(sparse, gt_points, gt_normals)
    angle = float(np.degrees(Rotation.from_matrix(R).magnitude()))
    out["similarity"] = {"scale": s, "rotation_deg": angle, "translation_m": t.tolist(), **fit}
    moved = s * sparse @ R.T + t
    # moved points lie on the GT surface if the similarity explains the bias: seen through the cameras,
    # their depth should then match the GT depth maps (bias ~0)
    out["sparse_vs_registered_gt"] = view_bias(scene, moved, scene.gt_depth)

    print(f"{scene.name}: {len(sparse):,} sparse points, {len(gt_points):,} GT depth-pixel points "
          "(every 2nd row / column)")
    print(f"similarity GT <- cameras' geometry: scale {s:.5f}, rotation {angle:.3f} deg, "
          f"translation {np.round(t * 100, 2).tolist()} cm; point-to-plane residual median "
          f"{fit['median_plane_distance_m'] * 1000:.1f} mm")
    if args.run is not None:
        names = [v.name for v in scene.views]
        depth = {i: read_map(args.run, "depth", n) for i, n in enumerate(names)}
        out["run"] = str(args.run)
        rows = []
        for v in scene.views:
            d, g = depth[v.index], scene.gt_depth(v.index)
            ok = (d > 0) & (g > 0)
            rel = d[ok] / g[ok] - 1.0
            rel = rel[np.abs(rel) < 0.01]
            rows.append({"view": v.name, "median_pct": float(100 * np.median(rel))})
        out["patchmatch_vs_gt"] = rows
        cloud = np.asarray(read_fused_ply(args.run / "fused.ply").xyz, np.float64)
        gt_views = scene.gt_views()
        gt_pixels = np.concatenate([cam.backproject(dm)[dm > 0] for cam, dm in gt_views])
        options = EvaluationOptions(tolerances=(0.01, 0.02, 0.05))
        out["peer_rule"] = evaluate_points(cloud, gt_pixels, options, gt_views).to_dict()
        out["peer_rule_registered"] = evaluate_points(s * cloud @ R.T + t, gt_pixels, options, gt_views).to_dict()
        # each view's GT depth scaled by its own bias against the sparse points (engine-independent evidence)
        corrected = [(cam, dm * np.float32(1.0 + b["median_pct"] / 100.0))
                     for (cam, dm), b in zip(gt_views, out["sparse_vs_gt"], strict=True)]
        corrected_pixels = np.concatenate([cam.backproject(dm)[dm > 0] for cam, dm in corrected])
        out["peer_rule_per_view_corrected"] = evaluate_points(cloud, corrected_pixels, options, corrected).to_dict()

    print(f"{'view':<10} {'sparse vs GT %':>15} {'after reg. %':>13}" + (f" {'PatchMatch vs GT %':>19}"
                                                                         if args.run else ""))
    for i, view in enumerate(scene.views):
        line = (f"{view.name:<10} {out['sparse_vs_gt'][i]['median_pct']:>15.3f} "
                f"{out['sparse_vs_registered_gt'][i]['median_pct']:>13.3f}")
        if args.run is not None:
            line += f" {out['patchmatch_vs_gt'][i]['median_pct']:>19.3f}"
        print(line)
    if args.run is not None:
        for key in ("peer_rule", "peer_rule_registered", "peer_rule_per_view_corrected"):
            r = out[key]
            print(f"{key:<28} F1 1/2/5 cm " + " / ".join(f"{f:.1f}" for f in r["f1"]) + "  accuracy "
                  + " / ".join(f"{f:.1f}" for f in r["accuracy"]) + "  completeness "
                  + " / ".join(f"{f:.1f}" for f in r["completeness"]))
    print(f"wrote {bench.write_result(out, args.json or bench.results_path(__file__, scene.name))}")


if __name__ == "__main__":
    main()
