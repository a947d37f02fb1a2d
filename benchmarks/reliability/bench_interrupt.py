"""Interrupt `deepc run` at random moments, resume, and count what survived (issue 9's table).

    .venv/bin/python benchmarks/reliability/bench_interrupt.py [--runs 10] [--seed 0] [--scene sample_scenes/tiny]
                                                   [--out benchmarks/results/bench_interrupt.json]

One uninterrupted reference run, then ``--runs`` runs each killed with SIGINT or SIGTERM (alternating)
after a random number of saved view states (or, one run in four, as soon as the first map is written),
plus a random delay. After every kill: no partial or temporary file (every map, PLY and JSON parses);
then ``--resume`` must end with outputs byte-identical to the reference. Data lost = states the killed
run had left partial, plus outputs that differ from the reference or are missing after the resume.
"""

from __future__ import annotations

import argparse
import random
import re
import signal
import tempfile
import time
from pathlib import Path

from support import bench
from support.interruption import check_no_partial, differences, kill_when, saved_states, start_run

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"runs": int, "interrupted": int, "resumed_identically": int, "partial_files": int, "data_lost": int,
          "rows": list}


TOTAL_STATES = 20  # FAST schedule: 2 levels x 2 passes x 5 views


def summary(result: dict) -> list[dict]:
    """Runs killed, resumed to byte-identical outputs, partial files left, outputs lost."""
    return [{"runs": result["runs"], "interrupted": result["interrupted"],
             "resumed identically": result["resumed_identically"], "partial files": result["partial_files"],
             "data lost": result["data_lost"]}]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--scene", type=Path, default=bench.REPO_ROOT / "sample_scenes" / "tiny")
    parser.add_argument("--out", default=bench.results_path(__file__))
    args = parser.parse_args()
    rng = random.Random(args.seed)
    root = Path(tempfile.mkdtemp(prefix="bench-interrupt-"))
    reference = root / "reference"
    proc = start_run(args.scene, reference)
    _, err = proc.communicate(timeout=900)
    if proc.returncode != 0:
        raise SystemExit(f"reference run failed: {err[-500:]}")
    rows = []
    print(f"{'run':>3} {'signal':<7} {'moment':>8} {'exit':>4} {'saved':>5} {'reused':>6} {'files ok':>8} "
          f"{'resumed':>8} {'identical':>9} {'s':>6}")
    for run in range(args.runs):
        sig = (signal.SIGINT, signal.SIGTERM)[run % 2]
        out = root / f"run{run}"
        moment = "writing" if run % 4 == 3 else rng.randint(1, TOTAL_STATES - 1)
        if moment == "writing":
            def condition(out=out):
                return any((out / "stereo" / "depth_maps").glob("*.bin"))
        else:
            def condition(out=out, moment=moment):
                return saved_states(out) >= moment
        start = time.perf_counter()
        code, _ = kill_when(start_run(args.scene, out), condition, sig, delay=rng.uniform(0, 0.2))
        saved = saved_states(out)
        try:
            files = check_no_partial(out)
            partial = None
        except AssertionError as exc:
            files, partial = 0, str(exc)
        resumed = start_run(args.scene, out, "--resume")
        _, err = resumed.communicate(timeout=900)
        match = re.search(r"resumed: (\d+) saved PatchMatch view states reused, (\d+) rejected", err)
        reused, rejected = (int(match.group(1)), int(match.group(2))) if match else (0, 0)
        diff = differences(reference, out) if resumed.returncode == 0 else ["resume failed"]
        row = {"signal": sig.name, "moment": moment, "exit": code, "interrupted": code == 130,
               "states_saved_before_kill": saved, "files_checked": files, "partial": partial,
               "resume_exit": resumed.returncode, "states_reused": reused,
               "states_rejected": rejected, "differences": diff,
               "identical": not diff, "seconds": time.perf_counter() - start}
        rows.append(row)
        print(f"{run:>3} {sig.name:<7} {moment!s:>8} {code:>4} {saved:>5} {reused:>6} {files:>8} "
              f"{resumed.returncode:>8} {not diff!s:>9} {row['seconds']:>6.1f}")
    interrupted = sum(r["interrupted"] for r in rows)
    record = {"runs": len(rows), "interrupted": interrupted,
               "resumed_identically": sum(r["identical"] for r in rows if r["interrupted"]),
               "partial_files": sum(r["partial"] is not None for r in rows),
               "data_lost": sum(len(r["differences"]) for r in rows), "rows": rows}
    print(f"interrupted {interrupted}/{len(rows)}, resumed identically {record['resumed_identically']}, "
          f"partial files {record['partial_files']}, data lost {record['data_lost']}")
    bench.write_result(record, args.out)


if __name__ == "__main__":
    main()
