"""Latency of a region re-run (the inspector's "Re-run region") on a finished run with its pass history.

    .venv/bin/python benchmarks/performance/bench_region.py RUN_DIR [--view 0] [--box 96] [--repeats 3]
        [--json benchmarks/results/bench_region.json]

RUN_DIR: a run made by ``deepc run`` (history kept, the default), e.g. fountain_p11 at 768 px. A ``--box`` square
at the view's centre is re-run by ``engine.run.probe.rerun_region`` from level 0, pass 0 and pass 1, with the
run's own schedule and with the paper's (8 iterations a pass: the default options); the first call replays the
view from the history (reported apart), the others are the interactive latency (median of ``--repeats``).
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

from engine.run.folder import read_run_metrics
from engine.run.probe import rerun_region
from support import bench

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"scene": str, "size": list, "box": list, "run_schedule": str, "first_call_s": float, "rows": list}



def summary(result: dict) -> list[dict]:
    """One row per schedule and starting pass: median and all latencies."""
    return [{"run": f"{result['scene']} {result['size'][0]}x{result['size'][1]}", "box": result["box"][2],
             "schedule": r["schedule"], "from pass": r["pass_index"], "median s": r["median_s"],
             "all s": ", ".join(f"{s:.2f}" for s in r["seconds"])} for r in result["rows"]]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path)
    parser.add_argument("--view", type=int, default=0)
    parser.add_argument("--box", type=int, default=96)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", type=Path, default=bench.results_path(__file__))
    args = parser.parse_args()
    metrics = read_run_metrics(args.run)
    w, h = metrics.image_size
    box = (max(0, w // 2 - args.box // 2), max(0, h // 2 - args.box // 2), min(args.box, w), min(args.box, h))
    own = metrics.options["patchmatch"]["schedule"]
    t0 = time.perf_counter()
    rerun_region(args.run, args.view, box)  # replays the view from the history once (cached in this process)
    first = time.perf_counter() - t0
    rows = []
    for schedule in dict.fromkeys((own, "paper")):
        for pass_index in (0, 1):
            seconds = []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                r = rerun_region(args.run, args.view, box, 0, pass_index, overrides={"schedule": schedule})
                seconds.append(time.perf_counter() - t0)
            rows.append({"schedule": schedule, "pass_index": pass_index, "seconds": seconds,
                         "median_s": statistics.median(seconds), "within_1pct_before": r.within_1pct_before,
                         "within_1pct_after": r.within_1pct_after})
    result = {"scene": metrics.scene, "size": [w, h], "box": list(box), "run_schedule": own,
              "first_call_s": first, "rows": rows}
    bench.print_table(summary(result))
    print(f"first call (replay of the view): {first:.1f} s")
    print(f"wrote {bench.write_result(result, args.json)}")


if __name__ == "__main__":
    main()
