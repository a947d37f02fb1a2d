"""Ours against the OpenMVS peer, side by side: alternating runs on one scene, wall and CPU time, peak RSS, fused F1.

    .venv/bin/python benchmarks/performance/bench_peer.py --peer-bin DIR [--scene DIR | --synthetic SEED]
        [--max-image-size 768] [--num-source-views 5] [--repeats 2] [--ours-args "" --ours-args "--schedule acmm"]
        [--peer-args "..."] [--work DIR] [--json benchmarks/results/bench_peer_<scene>.json]

``--peer-bin`` is the folder holding OpenMVS's ``InterfaceCOLMAP`` and ``DensifyPointCloud`` (this script never
builds it; the result records the ``--peer-build`` text given, e.g. "OpenMVS v2.3.0, CPU, Release"). The scene is a
COLMAP workspace with ground truth (``images/``, ``sparse/`` as text, ``ground_truth/``), or a synthetic scene of 7
views at 480x360 drawn from ``--synthetic SEED`` (``engine.synthetic.layout.random_scene``; the shipped
networks trained on seeds 0-5 and 2000-2009: take one from 10000 on).

Each repeat runs the peer, then (unless ``--no-ours``) ours once per ``--ours-args`` (``deepc run --pipeline vanilla
--headless`` with our default options and those arguments; default: our defaults alone), each in its own process
under ``/usr/bin/time``: wall and CPU seconds and peak RSS of the process. The peer works at the scene's resolution
divided by 2^L (``--resolution-level L``), chosen so that both work on the same pixels; both use
``--num-source-views`` source views (the peer's ``--number-views``). Both clouds are scored by the same code:
ETH3D-style F1 against the scene's GT points with the unobserved-space rule (what ``deepc run`` reports) at 1, 2 and
5 cm. Ratios: peer / ours of the median wall and CPU seconds (above 1: ours faster), ours / peer of the peak RSS.
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from statistics import median

import numpy as np

from support import bench

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"scene": str, "size": list, "views": int, "num_source_views": int, "repeats": int, "peer_build": str,
          "peer_command": list, "ours_command": list, "tolerances": list, "runs": dict, "ratios": dict}


TOLERANCES = (0.01, 0.02, 0.05)
PEER_DEFAULT_ARGS = "--number-views-fuse 3 --iters 3 --geometric-iters 2 --max-threads 0 --process-priority 0"


def summary(result: dict) -> list[dict]:
    """One row per tool and configuration: median wall / CPU seconds and the highest peak RSS over the repeats,
    fused F1 at 1 / 2 / 5 cm (median), and the ratios against the peer."""
    rows = []
    for name, runs in result["runs"].items():
        ratios = result["ratios"].get(name, {})
        f1 = [median(r["f1"][i] for r in runs) for i in range(len(result["tolerances"]))]
        rows.append({"tool": name, "wall s": median(r["wall_s"] for r in runs),
                     "CPU s": median(r["cpu_s"] for r in runs), "peak MiB": max(r["peak_mb"] for r in runs),
                     "F1 1/2/5 cm": " / ".join(f"{f:.1f}" for f in f1),
                     "peer wall / ours": ratios.get("wall", ""), "peer CPU / ours": ratios.get("cpu", ""),
                     "ours RSS / peer": ratios.get("peak_rss", "")})
    return rows


def timed(cmd: list[str], log: Path, timeout: float) -> dict:
    """Run ``cmd`` under /usr/bin/time: wall and CPU seconds, peak RSS (MiB) of the process."""
    stats = log.with_suffix(".time")
    with open(log, "w") as out:
        proc = subprocess.run(["/usr/bin/time", "-f", "%e %U %S %M", "-o", str(stats), *cmd], stdout=out,
                              stderr=subprocess.STDOUT, timeout=timeout)
    if proc.returncode != 0:
        tail = log.read_text(errors="replace").splitlines()[-5:]
        raise SystemExit(f"{cmd[0]} failed (exit {proc.returncode}): " + " | ".join(tail))
    wall, user, system, peak_kb = stats.read_text().split()[-4:]
    return {"wall_s": float(wall), "cpu_s": float(user) + float(system), "peak_mb": int(peak_kb) / 1024}


def score(scene, xyz: np.ndarray) -> list[float]:
    """F1 (%) of ``xyz`` (N, 3) world points at :data:`TOLERANCES`, as ``deepc run`` scores its own cloud."""
    from engine.evaluation import EvaluationOptions, evaluate_points
    from engine.io.ply import read_points

    result = evaluate_points(np.asarray(xyz, np.float64), read_points(scene.gt_points_path),
                             EvaluationOptions(tolerances=TOLERANCES), scene.gt_views() or None)
    return [float(f) for f in result.f1]


def read_peer_cloud(path: Path) -> np.ndarray:
    """The peer's dense cloud (N, 3) from its PLY."""
    import open3d as o3d

    cloud = o3d.io.read_point_cloud(str(path))
    if not cloud.has_points():
        raise SystemExit(f"{path}: no points")
    return np.asarray(cloud.points)


def synthetic_scene(seed: int, work: Path) -> Path:
    """A 7-view 480x360 scene drawn from ``seed``, written once into ``work`` (COLMAP text model)."""
    from engine.synthetic.export import write_scene
    from engine.synthetic.layout import random_scene

    path = work / f"synthetic_{seed:05d}"
    if not (path / "README.txt").is_file():
        recipe = random_scene(seed, n_views=(7, 7), width=480, height=360)
        recipe.name = path.name
        write_scene(recipe, path, binary_model=False, command=f"bench_peer.py --synthetic {seed}")
    return path


def resolution_level(scene_dir: Path, max_image_size: int) -> tuple[int, int]:
    """(L, our --max-image-size) so that the peer's images at 1/2^L are ours."""
    from engine.scene import SceneOptions, load_scene

    camera = load_scene(scene_dir, SceneOptions(max_image_size=0)).views[0].camera  # full size: the peer's input
    longest = max(camera.width, camera.height)
    target = min(max_image_size or longest, longest)
    level = round(math.log2(longest / target))
    if longest / 2 ** level != target:
        raise SystemExit(f"{scene_dir}: the longest side {longest} px over a power of two is not {target} px")
    return level, target


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--peer-bin", type=Path, required=True, help="folder with InterfaceCOLMAP and DensifyPointCloud")
    ap.add_argument("--peer-build", default="OpenMVS v2.3.0, CPU build (Release, no CUDA/OpenGL/CERES)")
    where = ap.add_mutually_exclusive_group()
    where.add_argument("--scene", type=Path, default=bench.SHARED_DATA / "fountain_p11")
    where.add_argument("--synthetic", type=int, default=None, metavar="SEED")
    ap.add_argument("--max-image-size", type=int, default=768, help="our longest side (px); 0 = the scene's")
    ap.add_argument("--num-source-views", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--ours-args", action="append", default=None,
                    help="extra 'deepc run' arguments of one configuration (repeatable; default: our defaults)")
    ap.add_argument("--no-ours", action="store_true",
                    help="run the peer alone (its folder and F1 for deepc compare / eval; no ratios)")
    ap.add_argument("--peer-args", default=PEER_DEFAULT_ARGS, help="extra DensifyPointCloud arguments")
    ap.add_argument("--work", type=Path, default=None, help="runs go here (default: a temporary folder)")
    ap.add_argument("--timeout", type=float, default=3600, help="seconds per run")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    for tool in ("InterfaceCOLMAP", "DensifyPointCloud"):
        if not (args.peer_bin / tool).is_file():
            raise SystemExit(f"{args.peer_bin / tool}: not found (build OpenMVS first; see issue 34)")
    work = args.work or Path(tempfile.mkdtemp(prefix="bench_peer_"))
    work.mkdir(parents=True, exist_ok=True)
    scene_dir = synthetic_scene(args.synthetic, work) if args.synthetic is not None else args.scene
    if args.synthetic is not None:
        args.max_image_size = 0
    level, size = resolution_level(scene_dir, args.max_image_size)

    from engine.scene import SceneOptions, load_scene

    scene = load_scene(scene_dir, SceneOptions(max_image_size=size))
    peer_args = ["--resolution-level", str(level), "--number-views", str(args.num_source_views),
                 *shlex.split(args.peer_args)]
    ours_cmd = [sys.executable, "-m", "workbench.cli", "run", str(scene_dir), "--pipeline", "vanilla", "--headless",
                "--max-image-size", str(size), "--num-source-views", str(args.num_source_views)]
    configs = {} if args.no_ours else {f"ours {a}".strip(): shlex.split(a) for a in (args.ours_args or [""])}
    runs: dict[str, list[dict]] = {"peer": [], **{name: [] for name in configs}}
    for k in range(args.repeats):
        # a fresh folder per repeat: the peer reuses depth maps it finds in its working folder
        folder = work / f"peer_{k}"
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir(parents=True)
        mvs = folder / "scene.mvs"
        timed([str(args.peer_bin / "InterfaceCOLMAP"), "-i", str(scene_dir), "-o", str(mvs), "--image-folder",
               str(scene_dir / "images"), "-w", str(folder)], folder / "interface.log", args.timeout)
        out = folder / "scene_dense.mvs"
        peer = timed([str(args.peer_bin / "DensifyPointCloud"), str(mvs), "-w", str(folder), "-o", str(out),
                      *peer_args], folder / "densify.log", args.timeout)
        peer["f1"] = score(scene, read_peer_cloud(out.with_suffix(".ply")))
        runs["peer"].append(peer)
        print(f"repeat {k}: peer {peer['wall_s']:.1f} s", flush=True)
        for c, (name, extra) in enumerate(configs.items()):
            run_dir = work / f"ours_{c}_{k}"
            shutil.rmtree(run_dir, ignore_errors=True)
            ours = timed([*ours_cmd, *extra, "--out", str(run_dir)], work / f"ours_{c}_{k}.log", args.timeout)
            metrics = json.loads((run_dir / "metrics.json").read_text())
            ours["f1"] = [float(f) for t, f in zip(metrics["eval"]["tolerances"], metrics["eval"]["f1"], strict=True)
                          if round(t, 6) in TOLERANCES]
            ours["seconds"] = metrics["seconds"]
            ours["within_1pct"] = metrics.get("depth", {}).get("within_1pct")
            runs[name].append(ours)
            print(f"repeat {k}: {name} {ours['wall_s']:.1f} s", flush=True)

    def med(name: str, key: str) -> float:
        return median(r[key] for r in runs[name])

    ratios = {name: {"wall": med("peer", "wall_s") / med(name, "wall_s"),
                     "cpu": med("peer", "cpu_s") / med(name, "cpu_s"),
                     "peak_rss": max(r["peak_mb"] for r in runs[name]) / max(r["peak_mb"] for r in runs["peer"])}
              for name in configs}
    result = {"scene": scene.name, "size": [scene.views[0].camera.width, scene.views[0].camera.height],
              "views": len(scene.views), "num_source_views": args.num_source_views, "repeats": args.repeats,
              "peer_build": args.peer_build, "peer_command": ["DensifyPointCloud", "scene.mvs", *peer_args],
              "ours_command": ["deepc", "run", "SCENE", "--pipeline", "vanilla", "--headless", "--max-image-size",
                               str(size), "--num-source-views", str(args.num_source_views), "[--ours-args]"],
              "tolerances": list(TOLERANCES), "runs": runs, "ratios": ratios}
    variant = scene.name if args.synthetic is None else "synthetic"
    path = bench.write_result(result, args.json or bench.results_path(__file__, variant))
    bench.print_table(summary(result))
    print(f"results: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
