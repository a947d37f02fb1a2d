"""Depth and fused-cloud quality of the paper schedule with and without the active set and convergence-driven passes.

    .venv/bin/python benchmarks/experiments/active_set.py [--scenes tiny,small,synth_01000,synth_01001] [--seeds 0,1]
        [--share 0.1] [--converge 0.8] [--schedule paper] [--json benchmarks/results/active_set.json]

Configurations (``deepc run --pipeline vanilla`` with the runner of ``support/option_sweep.py``): ``full`` updates
every pixel in every iteration (``active_share`` -1, ``converge_ratio`` 0); ``active`` re-evaluates only pixels whose
neighbourhood moved plus a random ``--share`` (``engine.patchmatch.kernels``); ``active_converge`` also ends a view's
pass once the changed share falls to ``--converge`` of the previous iteration's (``engine.patchmatch.convergence``).
Reports depth within 1 %, fused F1 at 1 / 2 / 5 cm and PatchMatch seconds per scene and seed (runs one after
another on a shared machine: compare times within one table).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from support import bench
from support.option_sweep import sweep, sweep_summary

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"schedule": str, "seeds": list, "share": float, "converge": float, "rows": list}



def summary(result: dict) -> list[dict]:
    """Per scene and configuration (seeds averaged): depth within 1 %, fused F1 at 1 / 2 cm, PatchMatch seconds."""
    return sweep_summary(result.get("rows", []))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="tiny,small,synth_01000,synth_01001")
    ap.add_argument("--seeds", default="0", help="comma-separated PatchMatch seeds")
    ap.add_argument("--share", type=float, default=0.1, help="active_share of the active configurations")
    ap.add_argument("--converge", type=float, default=0.8, help="converge_ratio of active_converge")
    ap.add_argument("--schedule", default="paper", choices=("acmm", "paper"))
    ap.add_argument("--work", type=Path, default=None, help="scenes and runs (default: a temporary folder)")
    ap.add_argument("--json", type=Path, default=bench.results_path(__file__))
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    configs = {"full": {"active_share": -1, "converge_ratio": 0},
               "active": {"active_share": args.share, "converge_ratio": 0},
               "active_converge": {"active_share": args.share, "converge_ratio": args.converge}}
    rows = sweep(args.scenes.split(","), configs, seeds, args.schedule, args.work)
    bench.write_result({"schedule": args.schedule, "seeds": seeds, "share": args.share, "converge": args.converge,
                        "rows": rows}, args.json)
    bench.print_table(summary({"rows": rows}), title="means over the seeds")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
