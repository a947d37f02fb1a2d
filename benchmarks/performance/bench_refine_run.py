"""Cost of refining a finished run (engine.run.refine.refine_run), i.e. of making the training data of
the second confidence network (``deepc train --refined``), and what the refinement does to the labels.

    nice -n 5 .venv/bin/python benchmarks/performance/bench_refine_run.py RUN
        [--json benchmarks/results/bench_refine_run.json]

RUN is a finished vanilla run (e.g. runs/train_cache/runs/synth_00000); it is copied to a temporary folder
first, so nothing in it changes. Default options (those of ``deepc train --refined``), shipped network-1
weights. Prints per view the refinement seconds and the labels (SPEC.md §4.3) of the vanilla and the
refined depth: labelled pixels and inlier share.
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from engine.confidence.data import load_run
from engine.run.refine import refine_run
from support import bench

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"run": str, "views": int, "size": list, "seconds": dict, "seconds_per_view": float,
          "refinement_seconds_per_view": float, "cpu_count": int, "load_average": list, "per_view": list}



def summary(result: dict) -> list[dict]:
    """Seconds per stage over the run's views and per view, labelled pixels and inliers before and after."""
    rows = [{"views": f"{result['views']} x {result['size'][0]}x{result['size'][1]}",
             **{f"{stage} s": s for stage, s in result["seconds"].items()},
             "s per view": result["seconds_per_view"]}]
    for i, maps in enumerate(("vanilla", "refined")):
        rows[0][f"labelled % {maps}"] = float(np.mean([r["labelled_pct"][i] for r in result["per_view"]]))
        rows[0][f"inliers % {maps}"] = float(np.mean([r["inlier_pct"][i] for r in result["per_view"]]))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path)
    parser.add_argument("--json", type=Path, default=bench.results_path(__file__))
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp) / args.run.name
        shutil.copytree(args.run, run, ignore=shutil.ignore_patterns("refined", "fused.ply", "cost_maps"))
        from engine.confidence.weights import load_weights
        model = load_weights()  # loading is not part of the per-run cost (deepc train loads once)
        stamps = [time.perf_counter()]
        result = refine_run(run, model=model, log=lambda line: stamps.append(time.perf_counter()))
        per_view = np.diff(stamps).tolist()  # the first interval also holds the confidence stage
        vanilla, refined = load_run(run), load_run(run, refined=True)

    rows = []
    print(f"{'view':<18}{'seconds':>9}{'labelled vanilla':>18}{'refined':>9}{'inliers vanilla':>17}{'refined':>9}")
    for i, (v, r) in enumerate(zip(vanilla, refined, strict=True)):
        seconds = per_view[i] - (result.seconds["confidence"] if i == 0 else 0.0)
        row = {"view": v.view, "refine_seconds": seconds,
               "labelled_pct": [100 * v.labelled_fraction, 100 * r.labelled_fraction],
               "inlier_pct": [100 * float((s.labels == 1).sum() / max(1, (s.labels >= 0).sum())) for s in (v, r)]}
        rows.append(row)
        print(f"{v.view:<18}{seconds:>9.1f}{row['labelled_pct'][0]:>17.1f}%{row['labelled_pct'][1]:>8.1f}%"
              f"{row['inlier_pct'][0]:>16.1f}%{row['inlier_pct'][1]:>8.1f}%")
    shape = vanilla[0].labels.shape
    record = {"run": str(args.run), "views": len(rows), "size": [shape[1], shape[0]],
               "seconds": result.seconds, "seconds_per_view": sum(result.seconds.values()) / len(rows),
               "refinement_seconds_per_view": result.seconds["refinement"] / len(rows),
               "cpu_count": os.cpu_count(), "load_average": os.getloadavg(), "per_view": rows}
    print(f"{len(rows)} views of {shape[1]}x{shape[0]}: " + ", ".join(f"{k} {v:.1f} s" for k, v in
                                                                   result.seconds.items())
          + f"; {record['seconds_per_view']:.1f} s per view in all (load average {os.getloadavg()[0]:.1f})")
    bench.write_result(record, args.json)


if __name__ == "__main__":
    main()
