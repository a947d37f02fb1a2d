"""Evaluation benchmark: 1M-vs-1M timing, and our ETH3D scores vs the official program.

    .venv/bin/python benchmarks/performance/bench_evaluation.py [--points 1000000] [--eth3d-binary PATH]
        [--work DIR] [--json benchmarks/results/bench_evaluation.json]

1. Timing: ``evaluate_points`` on N reconstructed vs N GT points (synthetic surfaces of
   ``support.synthetic_scan.SYNTHETIC_BOXES``; GT 1 mm noise, reconstruction 4 mm noise + 3 % outliers).
2. With ``--eth3d-binary`` (build it with ``benchmarks/performance/build_eth3d_evaluator.sh SRC BUILD``): synthetic
   ETH3D-format GT (two scans in scanner frames, 1.1 mrad rays = 2-3 mm apart), several
   reconstructions, F1/accuracy/completeness per tolerance from the official program and from
   ``evaluate_eth3d``. Also shows the double-coordinate PLY trap: the official program scores a
   ``property double x`` file as 0, ours reads it.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from engine.evaluation import EvaluationOptions, evaluate_eth3d, evaluate_points, load_eth3d_mlp
from engine.io.ply import read_points, write_ply
from support import bench
from support.synthetic_scan import make_synthetic_eth3d, sample_synthetic_reconstruction

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"timing": dict, "load_average": float, "cpu_count": int, "eth3d": dict}


TOL = (0.01, 0.02, 0.05, 0.1, 0.2, 0.5)
STEP_MRAD = 1.1  # scan ray step: 2.2-2.9 mm apart at the 2-2.7 m ranges of the synthetic scene


def run_official(binary: str, recon: Path, mlp: Path, tolerances=TOL) -> dict:
    out = subprocess.run([binary, "--reconstruction_ply_path", str(recon), "--ground_truth_mlp_path", str(mlp),
                          "--tolerances", ",".join(map(str, tolerances))], capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"official evaluator failed (rc {out.returncode}): {out.stderr[-500:]}")
    values = {}
    for key, name in (("Completenesses", "completeness"), ("Accuracies", "accuracy"), ("F1-scores", "f1")):
        m = re.search(rf"^{key}: (.*)$", out.stdout, re.M)
        values[name] = [100.0 * float(v) for v in m.group(1).split()]
    return values


def timing(n: int) -> dict:
    rng = np.random.default_rng(12)
    # The sampler drops the plate under the box (~6 %): oversample, then keep exactly n.
    gt = sample_synthetic_reconstruction(int(n * 1.1), noise=0.001, outlier_fraction=0.0, seed=10)
    recon = sample_synthetic_reconstruction(int(n * 1.1), noise=0.004, outlier_fraction=0.03, seed=11)
    gt = gt[rng.permutation(len(gt))[:n]]
    recon = recon[rng.permutation(len(recon))[:n]]
    evaluate_points(recon[:2000], gt[:2000])  # JIT / cache load of the helpers
    t0 = time.perf_counter()
    res = evaluate_points(recon, gt)
    seconds = time.perf_counter() - t0
    print(f"\nevaluate_points: {len(recon)} reconstructed vs {len(gt)} GT points: {seconds:.2f} s")
    print(res.format_table())
    return {"points_reconstruction": len(recon), "points_gt": len(gt), "seconds": seconds, "eval": res.to_dict()}


def eth3d_comparison(binary: str, work: Path) -> dict:
    t0 = time.perf_counter()
    mlp = make_synthetic_eth3d(work / "gt", step_mrad=STEP_MRAD)
    scans = load_eth3d_mlp(mlp)
    n_gt = sum(len(s.points) for s in scans)
    spacing = [float(np.median(np.linalg.norm(s.points, axis=1))) * STEP_MRAD * 1e-3 for s in scans]
    print(f"\nsynthetic ETH3D GT: {len(scans)} scans, {n_gt} points, median ray spacing "
          f"{', '.join(f'{1000 * s:.2f} mm' for s in spacing)} ({time.perf_counter() - t0:.1f} s)")
    merged = np.concatenate([s.points.astype(np.float64) @ s.global_T_scan[:3, :3].T + s.global_T_scan[:3, 3]
                             for s in scans])
    rng = np.random.default_rng(5)
    cases = {
        "noisy_4mm_outliers3pct": sample_synthetic_reconstruction(200_000, seed=1),
        "noisy_10mm_outliers10pct": sample_synthetic_reconstruction(150_000, noise=0.01, outlier_fraction=0.1,
                                                                    seed=2),
        "sparse_2mm": sample_synthetic_reconstruction(20_000, noise=0.002, outlier_fraction=0.01, seed=3),
        "gt_subset_jitter_15mm": (merged[rng.choice(len(merged), 100_000, replace=False)]
                                  + rng.normal(0, 0.015, (100_000, 3))),
    }
    rows = []
    for name, pts in cases.items():
        path = work / f"{name}.ply"
        write_ply(path, pts)  # float32 coordinates
        t0 = time.perf_counter()
        official = run_official(binary, path, mlp)
        t_official = time.perf_counter() - t0
        t0 = time.perf_counter()
        ours = evaluate_eth3d(read_points(path), scans, EvaluationOptions(tolerances=TOL))
        t_ours = time.perf_counter() - t0
        diff = [abs(a - b) for a, b in zip(ours.f1, official["f1"], strict=True)]
        rows.append({"case": name, "points": len(pts), "official": official, "ours": ours.to_dict(),
                     "max_abs_f1_difference": max(diff), "seconds_official": t_official, "seconds_ours": t_ours})
        print(f"\n{name} ({len(pts)} points; official {t_official:.1f} s, ours {t_ours:.1f} s)")
        print(f"{'tolerance':>10} {'F1 official':>12} {'F1 ours':>9} {'|diff|':>7} {'acc off':>8} {'acc ours':>9} "
              f"{'comp off':>9} {'comp ours':>10}")
        for i, t in enumerate(TOL):
            print(f"{t:>10g} {official['f1'][i]:>12.3f} {ours.f1[i]:>9.3f} {diff[i]:>7.3f} "
                  f"{official['accuracy'][i]:>8.3f} {ours.accuracy[i]:>9.3f} {official['completeness'][i]:>9.3f} "
                  f"{ours.completeness[i]:>10.3f}")
    # The double-PLY trap.
    pts = cases["noisy_4mm_outliers3pct"]
    dpath = work / "double.ply"
    write_ply(dpath, pts, coordinate_dtype="f8")
    official_double = run_official(binary, dpath, mlp)
    ours_double = evaluate_eth3d(read_points(dpath), scans, EvaluationOptions(tolerances=TOL))
    print("\ndouble-coordinate PLY: official F1 " + " ".join(f"{v:.2f}" for v in official_double["f1"])
          + "; ours " + " ".join(f"{v:.2f}" for v in ours_double.f1))
    worst = max(r["max_abs_f1_difference"] for r in rows)
    print(f"\nlargest |F1 ours - F1 official| over all cases and tolerances: {worst:.4f} points")
    return {"gt_points": n_gt, "ray_spacing_m": spacing, "cases": rows, "max_abs_f1_difference": worst,
            "double_ply": {"official_f1": official_double["f1"], "ours_f1": ours_double.f1}}


def summary(result: dict) -> list[dict]:
    """The 1M-vs-1M timing, and per ETH3D case the largest |F1 ours - F1 official| over the tolerances."""
    t = result["timing"]
    rows = [{"case": f"timing: {t['points_reconstruction']:,} vs {t['points_gt']:,} points", "seconds": t["seconds"]}]
    for c in result.get("eth3d", {}).get("cases", []):
        rows.append({"case": c["case"], "seconds": c["seconds_ours"], "official seconds": c["seconds_official"],
                     "max abs F1 difference": c["max_abs_f1_difference"]})
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--eth3d-binary", default=None, help="the official ETH3DMultiViewEvaluation binary")
    ap.add_argument("--work", default=None, help="folder for the synthetic data (default: a temporary one)")
    ap.add_argument("--json", default=bench.results_path(__file__))
    args = ap.parse_args(argv)
    result = {"timing": timing(args.points), "load_average": os.getloadavg()[0], "cpu_count": os.cpu_count()}
    if args.eth3d_binary:
        if args.work:
            Path(args.work).mkdir(parents=True, exist_ok=True)
            result["eth3d"] = eth3d_comparison(args.eth3d_binary, Path(args.work))
        else:
            with tempfile.TemporaryDirectory() as tmp:
                result["eth3d"] = eth3d_comparison(args.eth3d_binary, Path(tmp))
    else:
        print("\n(no --eth3d-binary: skipping the comparison with the official ETH3D program)")
    bench.write_result(result, args.json)
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
