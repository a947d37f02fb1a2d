"""Fuzz every file reader with many damaged inputs and count the outcomes per reader.

    .venv/bin/python benchmarks/reliability/fuzz_readers.py [--examples 2000] [--targets dense_bin,ply,...] [--seed 0]
                                                [--cli 20] [--out benchmarks/results/fuzz_readers.json]

In-process with hypothesis (mutations of valid files, support/fuzzing.py): every input must load or raise
one DeepCError line naming the file. ``--cli N`` also feeds N damaged inputs per target through the
command line (``deepc info`` for scenes, ``deepc eval`` for point clouds) and checks exit status 2 with
one ``deepc: error:`` line naming the file (a native crash or hang of pycolmap would show here).
Failures are listed; the JSON holds inputs tried, loaded, refused and failed per reader.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from hypothesis import HealthCheck, given, seed, settings

from support import bench
from support.fuzzing import TARGETS, FuzzCounts, FuzzTarget, check_input, damaged_inputs, materialise

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"examples_per_reader": int, "seed": int, "readers": dict}


REPO = bench.REPO_ROOT

# command line per target: argv after "deepc" for a materialised input folder
CLI = {
    "colmap_text": lambda root: ["info", str(root)],
    "colmap_binary": lambda root: ["info", str(root)],
    "ply": lambda root: ["eval", str(root / "binary.ply"), str(root / "ascii.ply")],
    "eth3d_mlp": lambda root: ["eval", str(root / "scan1.ply"), str(root / "scan_alignment.mlp")],
    "regress_suite": lambda root: ["regress", "--suite", str(root / "suite.toml"), "--report", str(root / "report")],
    "confidence_weights": lambda root: ["run", str(REPO / "sample_scenes" / "tiny"), "--out", str(root / "out"),
                                        "--pipeline", "fast", "--weights", str(root / "weights.pt"), "--headless"],
}
# inputs that load would start a whole regression suite or run: only those the reader refuses go through the
# command line, which must refuse them too, before anything runs (no output folder)
CLI_REFUSED_ONLY = {"regress_suite", "confidence_weights"}


def fuzz_in_process(target: FuzzTarget, examples: int, seed_value: int) -> FuzzCounts:
    counts = FuzzCounts()

    @seed(seed_value)
    @settings(max_examples=examples, deadline=None, database=None, suppress_health_check=list(HealthCheck))
    @given(damage=damaged_inputs(target))
    def fuzz(damage):
        try:
            check_input(target, damage, counts)
        except AssertionError:
            pass  # recorded in counts.failures; keep going to count every kind of failure

    fuzz()
    return counts


def fuzz_cli(target: FuzzTarget, runs: int) -> dict:
    """Damaged inputs through ``python -m workbench.cli``: exit 0, or 2 with one line naming the file."""
    strategy = damaged_inputs(target)
    result = {"tried": 0, "exit_0": 0, "exit_2": 0, "failures": []}
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    for _ in range(runs):
        damage = strategy.example()
        if target.name in CLI_REFUSED_ONLY:
            for _attempt in range(100):
                try:
                    if check_input(target, damage) == "error":
                        break
                except AssertionError:
                    break  # a reader failure: let the command line show it too
                damage = strategy.example()
        with tempfile.TemporaryDirectory(prefix=f"fuzzcli-{target.name}-") as tmp:
            folder = materialise(target, damage, Path(tmp))
            try:
                proc = subprocess.run([sys.executable, "-m", "workbench.cli", *CLI[target.name](folder)],
                                      capture_output=True, text=True, timeout=120, env=env, cwd=REPO)
            except subprocess.TimeoutExpired:
                result["failures"].append(f"hang (>120 s) on damage of {sorted(damage)}")
                continue
            result["tried"] += 1
            lines = [line for line in proc.stderr.splitlines() if line.strip() and "warning" not in line]
            if proc.returncode == 0:
                result["exit_0"] += 1
            elif target.name in CLI_REFUSED_ONLY and any((Path(tmp) / d).exists() for d in ("out", "report")):
                result["failures"].append(f"exit {proc.returncode} after starting to write: {proc.stderr[-300:]!r}")
            elif proc.returncode == 2 and len(lines) == 1 and lines[0].startswith("deepc: error: ") and tmp in lines[0]:
                result["exit_2"] += 1
            else:
                result["failures"].append(f"exit {proc.returncode}: {proc.stderr[-300:]!r}")
    return result


def summary(result: dict) -> list[dict]:
    """Per reader: damaged inputs tried, loaded, refused with one clear error, failed; the same via the CLI."""
    return [{"reader": name, "tried": r["tried"], "loaded": r["loaded"], "refused clearly": r["refused_clearly"],
             "failed": r["failed"], "CLI tried": r["cli"]["tried"] if r.get("cli") else None,
             "CLI failed": len(r["cli"]["failures"]) if r.get("cli") else None}
            for name, r in result["readers"].items()]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--examples", type=int, default=2000, help="in-process inputs per reader")
    parser.add_argument("--targets", default=",".join(TARGETS))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cli", type=int, default=20, help="inputs per reader through the command line")
    parser.add_argument("--out", default=bench.results_path(__file__))
    args = parser.parse_args()
    rows = {}
    print(f"{'reader':<15} {'tried':>7} {'loaded':>7} {'refused':>8} {'failed':>7} {'cli':>5} {'cli fail':>8} {'s':>7}")
    for name in args.targets.split(","):
        with tempfile.TemporaryDirectory(prefix=f"fuzz-{name}-") as tmp:
            target = TARGETS[name](Path(tmp))
            start = time.perf_counter()
            counts = fuzz_in_process(target, args.examples, args.seed)
            cli = fuzz_cli(target, args.cli) if name in CLI and args.cli else None
            seconds = time.perf_counter() - start
        rows[name] = {"tried": counts.tried, "loaded": counts.loaded, "refused_clearly": counts.clear_errors,
                      "failed": len(counts.failures), "failures": counts.failures[:20], "cli": cli,
                      "seconds": seconds}
        print(f"{name:<15} {counts.tried:>7} {counts.loaded:>7} {counts.clear_errors:>8} {len(counts.failures):>7} "
              f"{cli['tried'] if cli else '-':>5} {len(cli['failures']) if cli else '-':>8} {seconds:>7.1f}")
        for failure in counts.failures[:5] + (cli["failures"][:5] if cli else []):
            print("   ", failure[:300])
    out = Path(args.out)
    if out.is_file():  # --targets runs some readers: keep the others' earlier counts
        earlier = json.loads(out.read_text()).get("readers", {})
        rows = {**{k: v for k, v in earlier.items() if k in TARGETS}, **rows}
    bench.write_result({"examples_per_reader": args.examples, "seed": args.seed, "readers": rows}, out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
