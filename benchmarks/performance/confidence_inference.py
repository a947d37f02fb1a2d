"""Confidence-network inference time and peak memory on a 768×512 map (target: ≤ 2 s on 2 cores, ≤ 3 GB).

    .venv/bin/python benchmarks/performance/confidence_inference.py [--weights FILE] [--threads 2] [--repeat 3]

Runs each configuration in a fresh subprocess so that the peak resident set size (ru_maxrss) belongs to
it alone; reports the median wall time of ``--repeat`` runs after one warm-up, the peak RSS and the RSS
after loading torch and the weights (the part the inference itself adds is the difference). CPU time
(all threads) is reported too: on a shared, loaded machine, CPU seconds / threads is the wall time the
same work takes on idle cores.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

from support import bench

REPO = bench.REPO_ROOT
# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"size": list, "threads": int, "rows": list, "loadavg": list, "target": dict}
# The shipped networks this script runs by default: their sha256 is recorded with every result.
WEIGHTS = ("deepc_middle.pt",)

CHILD = r"""
import json, resource, statistics, sys, time
import numpy as np, torch
from engine.confidence.inference import predict_confidence
from engine.confidence.weights import load_weights
weights, threads, repeat, tile = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
bf16 = sys.argv[5] == "1"
torch.set_num_threads(threads)
model = load_weights(weights or None)
x = np.random.default_rng(0).random((6, 512, 768)).astype(np.float32)
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
predict_confidence(model, x, tile=tile, bf16=bf16)
times, cpu = [], []
for _ in range(repeat):
    t, c = time.perf_counter(), time.process_time()
    predict_confidence(model, x, tile=tile, bf16=bf16)
    times.append(time.perf_counter() - t)
    cpu.append(time.process_time() - c)
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps({"seconds_median": statistics.median(times), "seconds": times, "cpu_seconds": cpu,
                  "cpu_seconds_median": statistics.median(cpu), "peak_rss_mb": peak,
                  "rss_before_inference_mb": base}))
"""


def summary(result: dict) -> list[dict]:
    """Per configuration: median wall and CPU seconds of one 768x512 map, peak memory."""
    return [{"config": r["config"], "wall s": r["seconds_median"], "CPU s": r["cpu_seconds_median"],
             "peak RSS MiB": r["peak_rss_mb"]} for r in result["rows"]]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--weights", default="")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--out", type=Path, default=bench.results_path(__file__))
    args = parser.parse_args()
    rows = []
    for name, tile, bf16 in (("bf16, one tile", 1024, True), ("fp32, one tile", 1024, False),
                             ("bf16, 512-px tiles (default)", 512, True)):
        env = {**os.environ, "PYTHONPATH": str(REPO)}
        result = subprocess.run([sys.executable, "-c", CHILD, args.weights, str(args.threads), str(args.repeat),
                                 str(tile), "1" if bf16 else "0"], capture_output=True, text=True, env=env,
                                cwd=REPO, timeout=1200)
        if result.returncode != 0:
            raise SystemExit(result.stderr)
        row = {"config": name, "tile": tile, "bf16": bf16, **json.loads(result.stdout.strip().splitlines()[-1])}
        rows.append(row)
        print(f"{name:<26} {row['seconds_median']:6.2f} s wall, {row['cpu_seconds_median']:6.2f} s CPU   "
              f"peak RSS {row['peak_rss_mb']:7.0f} MB "
              f"(before inference {row['rss_before_inference_mb']:.0f} MB)", flush=True)
    load = os.getloadavg()
    bench.write_result({"size": [768, 512], "threads": args.threads, "rows": rows, "loadavg": list(load),
                        "target": {"seconds": 2.0, "peak_rss_mb": 3072}}, args.out)
    print(f"load average during the run: {load[0]:.1f} (2 cores; times are inflated by other processes)")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
