"""PatchMatch and fusion speed of this tree against another checkout, side by side, with a bit-identity check.

    .venv/bin/python benchmarks/performance/speed_ab.py --baseline DIR [--scene sample_scenes/small] [--rounds 2]
        [--json benchmarks/results/speed_ab.json]

This machine's speed drifts by 5-30 %, so absolute times are not comparable between sessions: each round runs
the baseline tree and this tree alternately (A B A B ...), each in a fresh process with PYTHONPATH set to its
tree, after each tree has filled its own numba cache. A round is one ``deepc run --pipeline vanilla --schedule
acmm --seed 0 --headless`` (PatchMatch seconds and process CPU seconds from its metrics.json), then the run's
maps fused ``--fusions`` times in one process (best wall time). The table gives the best of the rounds per
tree and the ratio this / baseline; the md5 of every map and of ``fused.ply`` must be equal between the trees.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from support import bench

ROOT = bench.REPO_ROOT
# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"baseline_revision": str, "scene": str, "rounds": int, "best": dict, "ratio": dict, "bit_identical": bool,
          "per_round": dict}

FUSE = """
import sys, time
from pathlib import Path
import numpy as np
from engine.fusion import FUSION_PRESETS, fuse, views_from_scene
from engine.io.dense import read_dense_map
from engine.scene import load_scene
run, scene_dir, n = Path(sys.argv[1]), sys.argv[2], int(sys.argv[3])
scene = load_scene(scene_dir)
names = [v.name for v in scene.views]
depth = [read_dense_map(run / "stereo/depth_maps" / f"{m}.bin", channels=1) for m in names]
normal = [read_dense_map(run / "stereo/normal_maps" / f"{m}.bin", channels=3) for m in names]
views = views_from_scene(scene, depth, normal)
best = float("inf")
for _ in range(n):
    t = time.perf_counter()
    cloud = fuse(views, FUSION_PRESETS["pixels"])
    best = min(best, time.perf_counter() - t)
print(best, len(cloud))
"""


def summary(result: dict) -> list[dict]:
    """Best PatchMatch and fusion seconds of each tree, their ratio, and whether the outputs were identical."""
    best = result["best"]
    return [{"stage": k.removesuffix("_s"), "baseline s": best["baseline"][k], "this s": best["this"][k],
             "ratio": result["ratio"][k], "bit-identical": result["bit_identical"]}
            for k in ("patchmatch_s", "fusion_s")]


def _env(tree: Path) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(tree), "NUMBA_THREADING_LAYER": "workqueue"}


def _md5s(run: Path) -> dict[str, str]:
    files = sorted(p for p in run.rglob("*") if p.suffix in (".bin", ".ply") and p.is_file())
    return {str(p.relative_to(run)): hashlib.md5(p.read_bytes()).hexdigest() for p in files}


def one_round(tree: Path, scene: Path, out: Path, fusions: int) -> dict:
    cmd = [sys.executable, "-c", "import sys; from workbench.cli.main import main; sys.exit(main())", "run", str(scene),
           "--out", str(out), "--pipeline", "vanilla", "--schedule", "acmm", "--seed", "0", "--headless"]
    subprocess.run(cmd, cwd=tree, env=_env(tree), check=True, capture_output=True, timeout=1800)
    metrics = json.loads((out / "metrics.json").read_text())
    fused = subprocess.run([sys.executable, "-c", FUSE, str(out), str(scene), str(fusions)], cwd=tree,
                           env=_env(tree), check=True, capture_output=True, text=True, timeout=1800)
    fusion_s, points = fused.stdout.split()
    return {"patchmatch_s": metrics["seconds"]["patchmatch"], "fusion_s": float(fusion_s), "points": int(points),
            "md5": _md5s(out)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, required=True, help="checkout to compare with (its repository root)")
    parser.add_argument("--scene", type=Path, default=ROOT / "sample_scenes" / "small")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--fusions", type=int, default=5, help="fusions per round; the best counts")
    parser.add_argument("--json", type=Path, default=bench.results_path(__file__))
    args = parser.parse_args(argv)
    trees = {"baseline": args.baseline.resolve(), "this": ROOT}
    for tree in trees.values():
        subprocess.run([sys.executable, "-m", "workbench.cli.compile_cache"], cwd=tree, env=_env(tree), check=True,
                       capture_output=True, timeout=1800)
    results: dict[str, list[dict]] = {k: [] for k in trees}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            for name, tree in trees.items():
                res = one_round(tree, args.scene.resolve(), Path(tmp) / f"{name}_{r}", args.fusions)
                results[name].append(res)
                print(f"round {r + 1} {name:>8}: PatchMatch {res['patchmatch_s']:.2f} s, "
                      f"fusion {res['fusion_s']:.3f} s", flush=True)
    best = {name: {k: min(x[k] for x in rs) for k in ("patchmatch_s", "fusion_s")} for name, rs in results.items()}
    identical = all(a["md5"] == b["md5"] for a, b in zip(results["baseline"], results["this"], strict=True))
    print(f"\n{'':>12} {'baseline':>10} {'this':>10} {'ratio':>7}")
    for k in ("patchmatch_s", "fusion_s"):
        b, n = best["baseline"][k], best["this"][k]
        print(f"{k:>12} {b:>10.3f} {n:>10.3f} {n / b:>7.3f}")
    print(f"maps and fused.ply bit-identical: {identical}")
    base_git = subprocess.run(["git", "rev-parse", "HEAD"], cwd=trees["baseline"], capture_output=True,
                              text=True).stdout.strip()
    bench.write_result({
        "baseline_revision": base_git, "scene": args.scene.name, "rounds": args.rounds, "best": best,
        "ratio": {k: best["this"][k] / best["baseline"][k] for k in best["this"]}, "bit_identical": identical,
        "per_round": {n: [{k: v for k, v in x.items() if k != "md5"} for x in rs] for n, rs in results.items()},
    }, args.json)
    return 0 if identical else 1


if __name__ == "__main__":
    sys.exit(main())
