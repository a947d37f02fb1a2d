"""Estimated vs measured peak memory of `deepc run` (issue 9 target: within 30 %).

    .venv/bin/python benchmarks/performance/bench_memory.py [--scenes tiny,small,fountain_p11] [--iterations 1]
                                                [--large] [--args "--num-source-views 5 --schedule acmm"]
                                                [--out benchmarks/results/bench_memory.json]

Each scene runs headless in a child process; its estimate is the ``memory: estimated peak`` line that
`deepc run` prints before PatchMatch (engine/run/memory.py), its measured peak the child's ru_maxrss.
``--iterations 1`` keeps it short: the arrays PatchMatch holds do not depend on the iteration count
(checked with ``--check-iterations``, which runs tiny with 1 and 3). ``--large`` adds
../shared/data/fountain_p11 at 768 px (several minutes); ``--args`` adds `deepc run` flags to every run (issue 34
compares with OpenMVS at ``--pipeline vanilla --num-source-views 5 --schedule acmm``).
"""

from __future__ import annotations

import argparse
import os
import re
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from support import bench

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"iterations": int, "args": list, "rows": dict, "worst_relative_error": float}


REPO = bench.REPO_ROOT

_ESTIMATE = re.compile(r"memory: estimated peak ([\d,]+) MiB")


def measure(scene: Path, iterations: int, extra: list[str]) -> dict:
    """Run `deepc run` in a fresh child (via a wrapper so ru_maxrss is this run's alone)."""
    with tempfile.TemporaryDirectory(prefix="bench-memory-") as tmp:
        code = ("import resource, subprocess, sys; p = subprocess.run(sys.argv[1:], capture_output=True, text=True); "
                "sys.stderr.write(p.stderr); "
                "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss); sys.exit(p.returncode)")
        argv = [sys.executable, "-c", code, sys.executable, "-m", "workbench.cli", "run", str(scene), "--out",
                str(Path(tmp) / "out"), "--headless", "--iterations", str(iterations), *extra]
        env = {**os.environ, "PYTHONPATH": str(REPO), "NUMBA_THREADING_LAYER": "workqueue"}
        start = time.perf_counter()
        proc = subprocess.run(argv, capture_output=True, text=True, env=env, cwd=REPO)
        if proc.returncode != 0:
            raise RuntimeError(f"{scene}: deepc run failed: {proc.stderr[-500:]}")
        match = _ESTIMATE.search(proc.stderr)
        measured = int(proc.stdout.split()[-1]) / 1024  # KiB -> MiB
        estimate = float(match.group(1).replace(",", ""))
    return {"estimated_mb": estimate, "measured_mb": measured, "ratio": estimate / measured,
            "seconds": time.perf_counter() - start, "line": match.group(0)}


def summary(result: dict) -> list[dict]:
    """Per scene: estimated and measured peak memory of `deepc run` and their ratio."""
    return [{"scene": name, "estimated MiB": r["estimated_mb"], "measured MiB": r["measured_mb"], "ratio": r["ratio"],
             "seconds": r["seconds"]} for name, r in result["rows"].items()]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default="tiny,small,fountain_p11")
    parser.add_argument("--iterations", type=int, default=1)
    parser.add_argument("--large", action="store_true", help="also ../shared/data/fountain_p11 at 768 px")
    parser.add_argument("--check-iterations", action="store_true")
    parser.add_argument("--args", default="", help="extra `deepc run` flags for every run")
    parser.add_argument("--out", default=bench.results_path(__file__))
    args = parser.parse_args()
    flags = shlex.split(args.args)
    cases = [(name, REPO / "sample_scenes" / name, flags) for name in args.scenes.split(",") if name]
    if args.large:
        cases.append(("fountain_p11@768", bench.SHARED_DATA / "fountain_p11", ["--max-image-size", "768", *flags]))
    rows = {}
    print(f"{'scene':<18} {'estimated MiB':>14} {'measured MiB':>13} {'ratio':>6} {'s':>7}")
    for name, scene, extra in cases:
        row = measure(scene, args.iterations, extra)
        rows[name] = row
        print(f"{name:<18} {row['estimated_mb']:>14.0f} {row['measured_mb']:>13.0f} {row['ratio']:>6.2f} "
              f"{row['seconds']:>7.1f}")
    if args.check_iterations:
        three = measure(REPO / "sample_scenes" / "tiny", 3, flags)
        rows["tiny_3_iterations"] = three
        print(f"{'tiny, 3 iterations':<18} {three['estimated_mb']:>14.0f} {three['measured_mb']:>13.0f} "
              f"{three['ratio']:>6.2f} {three['seconds']:>7.1f}")
    worst = max(abs(r["ratio"] - 1) for r in rows.values())
    print(f"worst |estimate/measured - 1| = {worst:.2f} (target <= 0.30)")
    bench.write_result({"iterations": args.iterations, "args": flags, "rows": rows, "worst_relative_error": worst},
                       args.out)


if __name__ == "__main__":
    main()
