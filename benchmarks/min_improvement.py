"""Depth and fused-cloud quality and PatchMatch time against ``PatchMatchOptions.min_improvement``.

    .venv/bin/python benchmarks/min_improvement.py [--values 0,0.003,0.01] [--scenes tiny,small,synth_01000,synth_01001]
        [--seeds 0] [--schedule acmm|paper] [--json benchmarks/results/min_improvement.json]

Near convergence most pixels swap their hypothesis in every iteration for one that is cheaper by a
noise-level amount, and every swap voids the cached costs of the pixel and of the neighbours that sample
it. ``min_improvement`` keeps a hypothesis unless a candidate beats it by more than the margin. This runs
``deepc run --pipeline vanilla`` for each margin on the sample scenes and on held-out synthetic scenes (as
``ncc_sharpness.py``, whose runner it uses) and reports depth metrics, fused F1 at 1 / 2 / 5 cm and the
PatchMatch seconds (the scenes run one after another on a shared machine: compare times within one table).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import ncc_sharpness  # noqa: E402

from engine.io.atomic import write_json  # noqa: E402


def config_name(value: float) -> str:
    return f"min_improvement_{value:g}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--values", default="0,0.003,0.01", help="comma-separated margins")
    ap.add_argument("--scenes", default="tiny,small,synth_01000,synth_01001")
    ap.add_argument("--seeds", default="0", help="comma-separated PatchMatch seeds")
    ap.add_argument("--schedule", default="acmm", choices=("acmm", "paper"))
    ap.add_argument("--work", type=Path, default=None, help="scenes and runs (default: a temporary folder)")
    ap.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "min_improvement.json")
    args = ap.parse_args()
    values = [float(v) for v in args.values.split(",")]
    seeds = [int(s) for s in args.seeds.split(",")]
    for v in values:
        # the runner passes each configuration's options to `deepc run --set patchmatch.NAME=VALUE`
        ncc_sharpness.CONFIGS[config_name(v)] = {"min_improvement": v}
    rows = ncc_sharpness.sweep(args.scenes.split(","), [config_name(v) for v in values], seeds, args.schedule,
                               args.work)
    for r in rows:
        r["min_improvement"] = r["options"]["min_improvement"]
    write_json(args.json, {"schedule": args.schedule, "seeds": seeds, "values": values, "rows": rows})
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
