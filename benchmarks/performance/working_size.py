"""What the default working size (half, within 640..2560 px, never above full size; ``engine.scene``) saves: the
estimated peak memory (``engine/run/memory.py``) and PatchMatch time of a few workspaces at full size, at the default
and at a quarter, without running them.

The time is extrapolated from a calibration: ``benchmarks/results/profile_patchmatch_passes.json`` (fountain_p11,
11 views of 768x512, ACMM's schedule, on this 2-core machine): PatchMatch seconds per million view pixels, which
grows linearly with the pixels at a fixed schedule (the window and the source views are per pixel). The memory
baseline is fixed (250 MiB, a process with the kernels loaded) so the numbers do not depend on this process.

With ``--runs RUN ...`` it records instead what finished runs of one scene at several sizes gave (their
metrics.json: F1, accuracy and completeness at 2 and 5 cm, points, the per-view shares), to say what halving costs:

    python benchmarks/performance/working_size.py [--json OUT]
    python benchmarks/performance/working_size.py --runs RUN_A RUN_B --json OUT_fountain.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from engine.core.camera import rescaled_size
from engine.run.memory import estimate_run_memory
from engine.run.pipeline import PipelineOptions
from engine.scene import default_image_size
from support import bench

# (name, views, width, height): the two workspaces and fountain_p11 as ../shared/data holds it
WORKSPACES = [("7 video frames", 7, 1251, 703), ("56 photos", 56, 1920, 1440), ("fountain_p11", 11, 1536, 1024),
              ("12 photos 6000 px", 12, 6000, 4000)]
# the estimates, or with --runs the runs' results
SCHEMA = {"seconds_per_mpx_acmm?": float, "baseline_mib?": int, "rows?": list, "runs?": list}
BASELINE = 250 << 20
SOURCES = 10  # SceneOptions.num_source_views


def calibration() -> float:
    """PatchMatch seconds per million view pixels with ACMM's schedule, from the profile of fountain_p11 at 768."""
    data = json.loads((bench.RESULTS / "profile_patchmatch_passes.json").read_text())
    width, height = data["size"]
    return data["total_seconds"] / (data["views"] * width * height / 1e6)


def fake_scene(views: int, width: int, height: int, size: int) -> SimpleNamespace:
    """What ``estimate_run_memory`` reads of a scene: views at ``size`` with their original size and sources."""
    w, h = rescaled_size(width, height, size)
    view = SimpleNamespace(camera=SimpleNamespace(width=w, height=h), original_size=(width, height),
                           source_views=list(range(min(SOURCES, views - 1))))
    return SimpleNamespace(views=[view] * views, gt_points_path=None)


def summary(result: dict) -> list[dict]:
    """Per workspace and size: working size, estimated peak memory and PatchMatch minutes (ACMM's schedule); or per
    run (``--runs``): size, F1 at 2 and 5 cm, points and the mean per-view shares."""
    if "runs" in result:
        return [{"run": r["size"], "F1 2 cm": r["f1@0.02"], "F1 5 cm": r["f1@0.05"], "points": r["fused_points"],
                 "fused %": r["fused_pct_mean"], "confirmed %": r["confirmed_pct_mean"]} for r in result["runs"]]
    return [{"workspace": r["workspace"], "size": r["size"], "working": r["working"], "memory MiB": r["memory_mib"],
             "PatchMatch min": r["patchmatch_min_acmm"]} for r in result["rows"]]


def run_row(folder: Path) -> dict:
    """What a finished run's metrics.json says of its quality at its working size, ground truth and none."""
    metrics = json.loads((folder / "metrics.json").read_text())
    row = {"size": "x".join(map(str, metrics["image_size"])), "pipeline": metrics["pipeline"],
           "options": metrics["options"]["patchmatch"]["schedule"], "fused_points": metrics["fused_points"]}
    e = metrics["eval"]
    for t in (0.02, 0.05):
        k = e["tolerances"].index(t)
        for name in ("f1", "accuracy", "completeness"):
            row[f"{name}@{t}"] = e[name][k]
    views = metrics["views"]
    fused = [v["fused_pct"] for v in views]
    median = float(np.median(fused))
    row.update(fused_pct_mean=float(np.mean(fused)), confirmed_pct_mean=float(np.mean([v["confirmed_pct"]
                                                                                        for v in views])),
               fused_to_median={v["view"]: v["fused_pct"] / median for v in views}, views=views)
    return row


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", default=None, help="result file (default: benchmarks/results/working_size.json)")
    parser.add_argument("--runs", nargs="+", default=None, help="finished runs of one scene to record instead")
    args = parser.parse_args(argv)
    if args.runs:
        runs = [run_row(Path(r)) for r in args.runs]
        bench.print_table([{k: v for k, v in r.items() if k not in ("views", "fused_to_median")} for r in runs])
        bench.write_result({"runs": runs}, args.json)
        return
    per_mpx = calibration()
    options = PipelineOptions()
    rows = []
    for name, views, width, height in WORKSPACES:
        longest = max(width, height)
        default = default_image_size(longest)
        for label, size in (("full", 0), ("default", default), ("quarter", max(1, longest // 4))):
            w, h = rescaled_size(width, height, size)
            estimate = estimate_run_memory(fake_scene(views, width, height, size), options, baseline=BASELINE,
                                           available=None)
            rows.append({"workspace": name, "size": label, "max_image_size": size, "working": f"{w}x{h}",
                         "memory_mib": estimate.peak / (1 << 20),
                         "patchmatch_min_acmm": views * w * h / 1e6 * per_mpx / 60})
    print(f"calibration: {per_mpx:.1f} s of PatchMatch per million view pixels (ACMM schedule, 2 cores)")
    bench.print_table(rows, digits=1)
    bench.write_result({"seconds_per_mpx_acmm": per_mpx, "baseline_mib": BASELINE >> 20, "rows": rows}, args.json)


if __name__ == "__main__":
    main()
