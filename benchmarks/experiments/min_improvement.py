"""Depth and fused-cloud quality and PatchMatch time against ``PatchMatchOptions.min_improvement``.

    .venv/bin/python benchmarks/experiments/min_improvement.py [--values 0,0.003,0.01]
        [--scenes tiny,small,synth_01000,synth_01001] [--seeds 0] [--schedule acmm|paper]
        [--json benchmarks/results/min_improvement.json]

Near convergence most pixels swap their hypothesis in every iteration for one that is cheaper by a
noise-level amount, and every swap voids the cached costs of the pixel and of the neighbours that sample
it. ``min_improvement`` keeps a hypothesis unless a candidate beats it by more than the margin. This runs
``deepc run --pipeline vanilla`` for each margin on the sample scenes and on held-out synthetic scenes (as
``ncc_sharpness.py``, with the runner of ``support/option_sweep.py``) and reports depth metrics, fused F1 at
1 / 2 / 5 cm and the PatchMatch seconds (the scenes run one after another on a shared machine: compare times
within one table).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from support import bench
from support.option_sweep import sweep, sweep_summary

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"schedule": str, "seeds": list, "values": list, "rows": list}



def config_name(value: float) -> str:
    return f"min_improvement_{value:g}"


def summary(result: dict) -> list[dict]:
    """Per scene and margin (seeds averaged): depth within 1 %, fused F1 at 1 / 2 cm, PatchMatch seconds."""
    return sweep_summary(result["rows"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--values", default="0,0.003,0.01", help="comma-separated margins")
    ap.add_argument("--scenes", default="tiny,small,synth_01000,synth_01001")
    ap.add_argument("--seeds", default="0", help="comma-separated PatchMatch seeds")
    ap.add_argument("--schedule", default="acmm", choices=("acmm", "paper"))
    ap.add_argument("--work", type=Path, default=None, help="scenes and runs (default: a temporary folder)")
    ap.add_argument("--json", type=Path, default=bench.results_path(__file__))
    args = ap.parse_args()
    values = [float(v) for v in args.values.split(",")]
    seeds = [int(s) for s in args.seeds.split(",")]
    # the runner passes each configuration's options to `deepc run --set patchmatch.NAME=VALUE`
    configs = {config_name(v): {"min_improvement": v} for v in values}
    rows = sweep(args.scenes.split(","), configs, seeds, args.schedule, args.work)
    for r in rows:
        r["min_improvement"] = r["options"]["min_improvement"]
    bench.write_result({"schedule": args.schedule, "seeds": seeds, "values": values, "rows": rows}, args.json)
    bench.print_table(summary({"rows": rows}), title="means over the seeds")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
