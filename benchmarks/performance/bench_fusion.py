"""Fusion benchmark: ours (numba, sequential) vs COLMAP's own fusion (pycolmap, 1 thread) on the same maps.

Maps: the GT depth of fountain_p11 at the working resolution (default 768x512), normals derived from
the depth (``support.gt_normals.depth_normals``; pixels without a normal are dropped from both). COLMAP
gets a workspace whose cameras carry our index-space intrinsics, so both un-project identically.

    .venv/bin/python benchmarks/performance/bench_fusion.py [--scene DIR] [--max-image-size 768] [--preset deepc]
        [--repeats 3] [--json benchmarks/results/bench_fusion.json]

Reported: wall time of ``fuse`` (best of N, after JIT warm-up, packing included) and of the
``pycolmap.stereo_fusion`` call (reads the workspace, fuses, writes fused.ply; best of N), point
counts, and the median nearest-neighbour distance between the two clouds in pixel footprints
(camera-frame depth / focal length of the seed view).

A preset with ``point_per_pixel`` (the default ``pixels``) has no COLMAP counterpart: COLMAP fuses the
same thresholds with one median point per cluster, and the comparison of clouds is made on ours in that
mode (the same clusters). The speed-up is COLMAP's time over ours with the preset as given, the work
a user waits for; the per-pixel cloud must hold exactly the pixels of the merged cloud's clusters.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from engine.fusion import FUSION_PRESETS, fuse, views_from_scene
from engine.scene import SceneOptions, load_scene
from support import bench
from support.colmap_fusion import run_colmap_fusion, write_colmap_workspace
from support.gt_normals import depth_normals

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"scene": str, "views": int, "map_size": list, "valid_pixels": int, "preset": str, "options": dict,
          "ours_seconds_best": float, "ours_seconds_all": list, "ours_first_call_seconds": float,
          "colmap_seconds_best": float, "colmap_seconds_all": list, "ours_cpu_seconds_best": float,
          "colmap_cpu_seconds_best": float, "speedup": float, "speedup_cpu": float, "ours_points": int,
          "colmap_points": int, "point_count_difference_percent": float, "median_nn_ours_to_colmap_footprints": float,
          "median_nn_colmap_to_ours_footprints": float, "p90_nn_ours_to_colmap_footprints": float,
          "median_footprint": float, "ours_num_views_median": float, "colmap_num_views_median": float,
          "load_average": float, "cpu_count": int, "compared_in_median_mode?": bool,
          "ours_median_mode_seconds_best?": float, "ours_per_pixel_points?": int,
          "per_pixel_points_equal_cluster_pixels?": bool}



def summary(result: dict) -> list[dict]:
    """Wall and CPU seconds (best of runs) and points of ours and COLMAP's fusion, and the speed-up."""
    return [{"preset": result["preset"], "maps": f"{result['views']} x {result['map_size'][0]}x{result['map_size'][1]}",
             "ours s": result["ours_seconds_best"], "COLMAP s": result["colmap_seconds_best"],
             "speed-up": result["speedup"], "speed-up CPU": result["speedup_cpu"], "ours points": result["ours_points"],
             "COLMAP points": result["colmap_points"]}]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default=str(bench.SHARED_DATA / "fountain_p11"))
    ap.add_argument("--max-image-size", type=int, default=768)
    ap.add_argument("--preset", default="deepc", choices=sorted(FUSION_PRESETS))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--colmap-repeats", type=int, default=2)
    ap.add_argument("--json", default=bench.results_path(__file__))
    args = ap.parse_args(argv)

    scene_dir = Path(args.scene)
    if not scene_dir.is_dir():
        scene_dir = bench.REPO_ROOT / "sample_scenes" / "fountain_p11"
        print(f"scene {args.scene} not found; using {scene_dir}")
    scene = load_scene(scene_dir, SceneOptions(max_image_size=args.max_image_size))
    depths, normals = [], []
    for i, v in enumerate(scene.views):
        d = scene.gt_depth(i)
        if d is None:
            raise SystemExit(f"{scene_dir}: view {v.name} has no GT depth")
        n = depth_normals(v.camera, d)
        depths.append(np.where(np.abs(n).sum(-1) > 0, d, 0).astype(np.float32))
        normals.append(n)
    views = views_from_scene(scene, depths, normals)
    opts = FUSION_PRESETS[args.preset]
    merged_opts = opts.replace(point_per_pixel=False)  # what COLMAP computes
    w, h = views[0].camera.size
    n_valid = int(sum((v.depth > 0).sum() for v in views))

    with bench.Stopwatch() as first:
        fuse(views, opts)  # JIT compile or cache load
    warmup = first.wall
    times, cpu = [], []
    for _ in range(args.repeats):
        with bench.Stopwatch() as watch:
            ours = fuse(views, opts)
        times.append(watch.wall)
        cpu.append(watch.cpu)
    per_pixel, merged_times = None, []
    if opts.point_per_pixel:  # the clouds are compared in median mode, the mode COLMAP has
        per_pixel = ours
        for _ in range(args.repeats):
            with bench.Stopwatch() as watch:
                ours = fuse(views, merged_opts)
            merged_times.append(watch.wall)

    with tempfile.TemporaryDirectory() as tmp:
        write_colmap_workspace(scene, views, tmp)
        ctimes, ccpu = [], []
        for _ in range(args.colmap_repeats):
            with bench.Stopwatch() as watch:
                ref = run_colmap_fusion(tmp, merged_opts, num_threads=1)  # in-process: CPU time is comparable
            ctimes.append(watch.wall)
            ccpu.append(watch.cpu)

    # Pixel footprint of every point of ours: depth in its seed view / fx.
    fx = np.array([v.camera.fx for v in views])
    z = np.empty(len(ours))
    for k, v in enumerate(views):
        sel = ours.source_view == k
        z[sel] = v.camera.world_to_camera(ours.xyz[sel])[:, 2]
    footprint = z / fx[ours.source_view]
    d_ours, _ = cKDTree(ref.xyz).query(ours.xyz)
    d_ref, nn = cKDTree(ours.xyz).query(ref.xyz)
    ratio_ours = d_ours / footprint
    ratio_ref = d_ref / footprint[nn]

    result = {
        "scene": scene.name, "views": len(views), "map_size": [w, h], "valid_pixels": n_valid,
        "preset": args.preset, "options": opts.to_dict(),
        "ours_seconds_best": min(times), "ours_seconds_all": times, "ours_first_call_seconds": warmup,
        "colmap_seconds_best": min(ctimes), "colmap_seconds_all": ctimes,
        "ours_cpu_seconds_best": min(cpu), "colmap_cpu_seconds_best": min(ccpu),
        "speedup": min(ctimes) / min(times), "speedup_cpu": min(ccpu) / min(cpu),
        "ours_points": len(ours), "colmap_points": len(ref),
        "point_count_difference_percent": 100.0 * (len(ours) - len(ref)) / max(len(ref), 1),
        "median_nn_ours_to_colmap_footprints": float(np.median(ratio_ours)),
        "median_nn_colmap_to_ours_footprints": float(np.median(ratio_ref)),
        "p90_nn_ours_to_colmap_footprints": float(np.percentile(ratio_ours, 90)),
        "median_footprint": float(np.median(footprint)),
        "ours_num_views_median": float(np.median(ours.num_views)),
        "colmap_num_views_median": float(np.median(ref.num_views)),
        "load_average": os.getloadavg()[0], "cpu_count": os.cpu_count(),
    }
    if per_pixel is not None:
        result.update({
            "compared_in_median_mode": True, "ours_median_mode_seconds_best": min(merged_times),
            "ours_per_pixel_points": len(per_pixel),
            "per_pixel_points_equal_cluster_pixels": bool(len(per_pixel) == int(ours.num_pixels.sum())),
        })
    print(f"\nfusion of {len(views)} views at {w}x{h} ({n_valid} valid pixels), preset {args.preset}")
    print(f"{'':<28}{'ours':>14}{'COLMAP 1 thread':>18}")
    print(f"{'seconds (best of runs)':<28}{min(times):>14.3f}{min(ctimes):>18.3f}")
    if per_pixel is not None:
        print(f"{'  ours, median points':<28}{min(merged_times):>14.3f}")
        print(f"{'per-pixel points':<28}{len(per_pixel):>14d}  (= pixels of the clusters below: "
              f"{result['per_pixel_points_equal_cluster_pixels']})")
    print(f"{'CPU seconds (best)':<28}{min(cpu):>14.3f}{min(ccpu):>18.3f}")
    print(f"{'points':<28}{len(ours):>14d}{len(ref):>18d}")
    print(f"{'median num_views':<28}{np.median(ours.num_views):>14.1f}{np.median(ref.num_views):>18.1f}")
    print(f"speed-up {result['speedup']:.2f}x wall, {result['speedup_cpu']:.2f}x CPU; "
          f"point counts differ by {result['point_count_difference_percent']:+.2f}%")
    print(f"median NN distance: ours->COLMAP {result['median_nn_ours_to_colmap_footprints']:.4f}, "
          f"COLMAP->ours {result['median_nn_colmap_to_ours_footprints']:.4f} pixel footprints "
          f"(median footprint {result['median_footprint'] * 1000:.2f} mm)")
    print(f"first call (JIT/cache) {warmup:.2f} s; load average {result['load_average']:.2f}")
    bench.write_result(result, args.json)
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
