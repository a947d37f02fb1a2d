"""Where PatchMatch depth errors are: near depth edges, where no source view sees the surface, elsewhere.

    .venv/bin/python benchmarks/experiments/patchmatch_error_regions.py RUN_DIR [RUN_DIR ...] [--edge-px 4]
        [--refined] [--json benchmarks/results/patchmatch_error_regions.json]

RUN_DIR is a ``deepc run`` output folder of a scene with GT depth. Regions come from GT only, so two runs of
the same scene are split identically and an A/B of an engine change shows where it helps:

    edge     GT pixels within ``--edge-px`` of a depth discontinuity (|∇ log z*| of the Sobel filter > 0.2)
    unseen   GT pixels whose surface point lands outside every other view, or behind that view's GT surface
             (GT depth there more than 2 % nearer): no photo-consistency can place them
    rest     every other GT pixel

Per region: its share of the GT pixels, within 1 % / 5 % (|z - z*| ≤ 0.01 z*, pixels without an estimate count
as misses) and the misses as points of the whole view set, so the rows add up to 100 - within 1 %.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy import ndimage

from support import bench
from support.scoring import within_by_region
from workbench.viewer.session import ViewerSession

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"runs": list}



def unseen_mask(scene, index: int, gt: np.ndarray) -> np.ndarray:
    """(H, W) GT pixels of view ``index`` that no other view of the scene observes."""
    cam = scene.views[index].camera
    has = gt > 0
    points = cam.camera_to_world(cam.pixel_rays()[has] * gt[has][:, None])
    seen = np.zeros(len(points), bool)
    for other in scene.views:
        if other.index == index:
            continue
        other_gt = scene.gt_depth(other.index)
        if other_gt is None:
            continue
        uv, z = other.camera.project(points)
        col, row = np.round(uv[:, 0]).astype(np.int64), np.round(uv[:, 1]).astype(np.int64)
        inside = (z > 0) & (col >= 0) & (row >= 0) & (col < other.camera.width) & (row < other.camera.height)
        there = np.zeros(len(points))
        there[inside] = other_gt[row[inside], col[inside]]
        seen |= inside & (np.abs(there - z) < 0.02 * z)
    out = np.zeros(gt.shape, bool)
    out[has] = ~seen
    return out


def edge_mask(gt: np.ndarray, edge_px: int) -> np.ndarray:
    """(H, W) pixels within ``edge_px`` of a GT depth discontinuity."""
    log_z = np.log(np.where(gt > 0, gt, np.nan))
    log_z = np.where(np.isfinite(log_z), log_z, np.nanmax(log_z) if np.isfinite(log_z).any() else 0.0)
    grad = np.hypot(ndimage.sobel(log_z, 0), ndimage.sobel(log_z, 1))
    return ndimage.binary_dilation(grad > 0.2, iterations=max(edge_px, 1))


def regions(run_dir: Path, edge_px: int, refined: bool) -> dict:
    scene = ViewerSession.open(run_dir).scene

    def masks(index: int, gt: np.ndarray) -> dict[str, np.ndarray]:
        has = gt > 0
        unseen = unseen_mask(scene, index, gt)
        edge = edge_mask(gt, edge_px) & has & ~unseen
        return {"edge": edge, "unseen": unseen, "rest": has & ~unseen & ~edge}

    table = within_by_region(scene, run_dir, masks, "refined_depth" if refined else "depth")
    size = f"{scene.views[0].camera.width}x{scene.views[0].camera.height}"
    return {"scene": scene.name, "size": size, "run": str(run_dir), "maps": "refined" if refined else "stereo",
            "edge_px": edge_px, "regions": table}


def summary(result: dict) -> list[dict]:
    """Per run and region: share of the GT pixels, within 1 % / 5 %, misses in points of the whole."""
    return [{"scene": res["scene"], "size": res["size"], "maps": res.get("maps", "stereo"), "region": name,
             "share %": row["share_pct"], "within 1 %": row["within_1pct"], "within 5 %": row["within_5pct"],
             "misses (points)": row["misses_1pct_points"]}
            for res in result["runs"] for name, row in res["regions"].items()]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path, nargs="+")
    parser.add_argument("--edge-px", type=int, default=4)
    parser.add_argument("--refined", action="store_true", help="score RUN/refined/ depth maps instead")
    parser.add_argument("--json", type=Path, default=bench.results_path(__file__))
    args = parser.parse_args()
    results = [regions(r, args.edge_px, args.refined) for r in args.runs]
    print(f"{'scene':<14} {'size':>9} {'region':<7} {'share %':>8} {'<1 %':>7} {'<5 %':>7} {'misses (pts)':>13}")
    for res in results:
        for name, row in res["regions"].items():
            print(f"{res['scene']:<14} {res['size']:>9} {name:<7} {row['share_pct']:>8.1f} {row['within_1pct']:>7.1f} "
                  f"{row['within_5pct']:>7.1f} {row['misses_1pct_points']:>13.1f}")
    bench.write_result({"runs": results}, args.json)
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
