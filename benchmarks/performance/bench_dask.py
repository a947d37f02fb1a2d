"""The per-view work on Dask (``deepc run --executor dask``): speed-up and overhead per task, and memory against the
number of views.

    .venv/bin/python benchmarks/performance/bench_dask.py fountain [--scene DIR] [--max-image-size 768]
        [--workers 1 2] [--json benchmarks/results/bench_dask_fountain.json]
    .venv/bin/python benchmarks/performance/bench_dask.py sequence [--views 50 100 200 400] [--size 320 240]
        [--workers 2] [--scenes DIR] [--json benchmarks/results/bench_dask_sequence.json]
        [--pipeline vanilla] [--schedule acmm] [--levels 1] [--iterations 2] [--geom-passes 1]
        [--num-source-views 4] [--set patchmatch.NAME=VALUE ...] [--fusion-cache VIEWS]

``fountain``: the vanilla pipeline on fountain_p11 in this process (``--executor local``) and on a LocalCluster of
each ``--workers`` count (cores / workers numba threads each). Overhead per task = (wall with 1 worker - wall
local) / tasks (one per view and pass, one per view for the final and counter maps).

``sequence``: street scenes of N views one metre apart (``engine.synthetic.sequence.street_scene``, rendered once
into ``--scenes``), the pipeline on a LocalCluster: wall time, peak RSS of each worker and of the driver, and the
driver's peak during the fusion stage with its growth over the RSS the stage started from (fusion and writing
fused.ply), and the growth during the cached fusion alone (``driver_fuse_*``). The driver of an executor run
holds no per-view maps (``engine.run.distributed.streamed``): fusion reads them through a cache of at most
``--fusion-cache`` views (default 1 + the longest overlap list, at most check_num_images + 1 = 51,
``engine.fusion.cached``), and the cloud goes into fused.ply chunk by chunk (``engine.fusion.stream``), so its growth
is the cache's slots (``cache_mb``, bounded whatever N) and one output chunk; ``cloud_mb`` is what the cloud would
take in memory (55 bytes a point). The cache's loads and evictions are recorded. The driver's overall peak comes
after fusion, in the evaluation (it holds every view's GT depth for the free-space rule).
Per-pass map I/O (states written and read through the run folder). A plot of both against N goes beside the JSON.

The pipeline and its options: ``--pipeline``, ``--set SECTION.NAME=VALUE`` as ``deepc run --set`` (sections scene,
patchmatch, confidence, fusion), and shortcuts for cheap PatchMatch settings (``--schedule``, ``--levels``,
``--iterations``, ``--geom-passes``, ``--num-source-views``); the options used are recorded in the JSON.

Every configuration runs in a fresh process (``--one``), so peak memory belongs to it alone.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from support import bench

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"scene?": str, "max_image_size?": int, "rows": list, "size?": list, "workers?": int, "pipeline?": str,
          "set?": list, "fusion_cache?": None}


PASS_STATE_BYTES = 4 + 12 + 4 + 4  # depth, normal, cost, selected views per pixel in a checkpoint state


def worker_peak_mb() -> float:
    """Peak RSS (MiB) of the process that runs this (a Dask worker via ``client.run``)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


class _StagePeaks:
    """An observer that measures the driver's peak RSS up to PatchMatch's end, and during fusion alone (from the end of
    the stage before it) with the RSS fusion started from."""

    def __init__(self):
        self.peaks: dict[str, float] = {}

    def on_stage(self, name: str, **info) -> None:
        if name in ("patchmatch", "confidence", "refinement", "fusion"):
            self.peaks[name] = bench.peak_rss_mb_now()
            if name != "fusion":
                self.peaks["before_fusion"] = bench.rss_mb_now()
            bench.reset_peak_rss()


class _CountingCache:
    """Records the cache statistics of the run's streamed fusion (``engine.run.distributed.streamed``)."""

    def __init__(self, cache_views: int | None):
        import engine.run.distributed.streamed as streamed
        from engine.fusion.cached import CacheStats

        self.stats, self.cache_views, self.module = CacheStats(), cache_views, streamed
        self.original = streamed.fuse_cached
        self.start_mb = self.peak_mb = None

        def counted(*args, **kwargs):
            kwargs["stats"] = self.stats
            if self.cache_views is not None:
                kwargs["cache_views"] = self.cache_views
            # fuse_cached alone (the fusion stage also writes fused.ply: engine.io.ply's table and its bytes)
            bench.reset_peak_rss()
            self.start_mb = bench.rss_mb_now()
            cloud = self.original(*args, **kwargs)
            self.peak_mb = bench.peak_rss_mb_now()
            return cloud

        streamed.fuse_cached = counted

    def close(self) -> None:
        self.module.fuse_cached = self.original


def pipeline_options(config: dict):
    """(SceneOptions, PipelineOptions) of a configuration: its pipeline, ``set`` items and image size."""
    from engine.confidence.options import ConfidenceOptions
    from engine.fusion import DEFAULT_PRESET, FUSION_PRESETS, FusionOptions
    from engine.patchmatch import PatchMatchOptions
    from engine.run.pipeline import PipelineOptions
    from engine.scene import SceneOptions
    from workbench.flags.assignments import section_overrides

    items = config.get("set", [])
    scene = SceneOptions(**{"max_image_size": config["max_image_size"],
                            **section_overrides(items, "scene", SceneOptions)}).validate()
    options = PipelineOptions(
        pipeline=config.get("pipeline", "vanilla"),
        patchmatch=PatchMatchOptions(**section_overrides(items, "patchmatch", PatchMatchOptions)),
        confidence=ConfidenceOptions(**section_overrides(items, "confidence", ConfidenceOptions)),
        fusion=FUSION_PRESETS[DEFAULT_PRESET].replace(**section_overrides(items, "fusion", FusionOptions)))
    return scene, options.validate()


def run_one(config: dict) -> dict:
    """One pipeline run as ``config`` says; the numbers of :func:`main`'s rows."""
    from engine.run.pipeline import run_pipeline
    from engine.scene import load_scene

    scene_options, options = pipeline_options(config)
    scene = load_scene(config["scene"], scene_options)
    cache = _CountingCache(config.get("fusion_cache"))
    executor = None
    if config["workers"]:
        from engine.run.distributed.dask_executor import DaskExecutor

        executor = DaskExecutor(workers=config["workers"], stall_timeout=3600)
    peaks = _StagePeaks()
    try:
        with tempfile.TemporaryDirectory() as out, bench.Stopwatch() as watch:
            result = run_pipeline(scene, out, options, observer=peaks, executor=executor)
        workers = sorted(executor.client.run(worker_peak_mb).values()) if executor else []
    finally:
        cache.close()
        if executor is not None:
            executor.close()
    n = len(scene.views)
    levels = result.metrics["options"]["patchmatch"]["levels"]
    passes = levels * (1 + options.patchmatch.geom_passes)
    w, h = result.metrics["image_size"]
    sources = sum(len(v.source_views) for v in scene.views)
    return {"views": n, "size": f"{w}x{h}", "workers": config["workers"],
            "threads": executor.threads if executor else None, "wall_s": watch.wall,
            "seconds": result.metrics["seconds"], "tasks": n * passes + n if executor else 0,
            "driver_peak_mb": bench.peak_rss_mb(), "driver_patchmatch_peak_mb": peaks.peaks.get("patchmatch"),
            "driver_fusion_peak_mb": peaks.peaks.get("fusion"),
            "driver_fusion_start_mb": peaks.peaks.get("before_fusion"),
            "driver_fuse_start_mb": cache.start_mb, "driver_fuse_peak_mb": cache.peak_mb,
            "fusion_cache": dataclasses.asdict(cache.stats) if executor else None, "worker_peak_mb": workers,
            # level-0 pass: every view writes its state and reads its own and its sources' (geometric passes)
            "pass_written_mb": n * w * h * PASS_STATE_BYTES / 2**20,
            "pass_read_mb": (n + sources) * w * h * PASS_STATE_BYTES / 2**20,
            "fused_points": result.metrics["fused_points"], "pipeline": options.pipeline,
            # what fusion's peak must hold whatever it does: the cloud, and the cache's slots (23 bytes a pixel)
            "cloud_mb": sum(getattr(result.cloud, f.name).nbytes for f in dataclasses.fields(result.cloud)) / 2**20,
            "cache_mb": cache.stats.peak_resident * w * h * 23 / 2**20 if executor else None,
            "options": {"scene": scene_options.to_dict(), **options.to_dict()}}


def _spawn(config: dict, timeout: float) -> dict:
    out = subprocess.run([sys.executable, __file__, "--one", json.dumps(config)], capture_output=True, text=True,
                         timeout=timeout, check=False, env={**os.environ, "PYTHONPATH": str(bench.REPO_ROOT)})
    if out.returncode != 0:
        raise SystemExit(f"configuration {config} failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def summary(result: dict) -> list[dict]:
    """One row per configuration: wall time, speed-up over local and overhead per task (fountain), peak RSS of the
    driver (all of the run; fusion alone, and its growth over the RSS fusion started from: bounded by the cache of
    views with an executor), the cache's loads, the busiest worker's peak RSS, map I/O of one level-0 pass."""
    return [{"views": r["views"], "size": r["size"], "workers": r["workers"] or "local", "threads": r["threads"],
             "wall s": r["wall_s"], "tasks": r["tasks"], "speed-up": r.get("speedup"),
             "overhead/task s": r.get("overhead_per_task_s"), "driver MiB": r["driver_peak_mb"],
             "fusion MiB": r["driver_fusion_peak_mb"],
             "fusion +MiB": (r["driver_fusion_peak_mb"] - r["driver_fusion_start_mb"]
                             if r.get("driver_fusion_start_mb") and r["driver_fusion_peak_mb"] else None),
             "fuse +MiB": (r["driver_fuse_peak_mb"] - r["driver_fuse_start_mb"]
                           if r.get("driver_fuse_peak_mb") else None),
             "cloud MiB": r.get("cloud_mb"), "cache MiB": r.get("cache_mb"),
             "cache loads": (r.get("fusion_cache") or {}).get("loads"),
             "worker MiB": max(r["worker_peak_mb"], default=None),
             "pass write MiB": r["pass_written_mb"], "pass read MiB": r["pass_read_mb"]} for r in result["rows"]]


def fountain(args: argparse.Namespace) -> dict:
    scene = Path(args.scene)
    if not scene.is_dir():
        scene = bench.REPO_ROOT / "sample_scenes" / "fountain_p11"
    rows = []
    for workers in [0, *args.workers]:
        rows.append(_spawn({"scene": str(scene), "max_image_size": args.max_image_size, "workers": workers},
                           args.timeout))
    local = rows[0]["wall_s"]
    for r in rows:
        r["speedup"] = local / r["wall_s"]
        if r["workers"] == 1:
            r["overhead_per_task_s"] = (r["wall_s"] - local) / r["tasks"]
    return {"scene": scene.name, "max_image_size": args.max_image_size, "rows": rows}


def sequence(args: argparse.Namespace) -> dict:
    from engine.synthetic import write_scene
    from engine.synthetic.sequence import street_scene

    root = Path(args.scenes)
    rows = []
    for n in args.views:
        folder = root / f"street_{n}_{args.size[0]}x{args.size[1]}"
        if not (folder / "sparse").is_dir():
            start = time.perf_counter()
            write_scene(street_scene(n, *args.size), folder)
            print(f"rendered {folder} ({time.perf_counter() - start:.0f} s)", file=sys.stderr)
        rows.append(_spawn({"scene": str(folder), "max_image_size": max(args.size), "workers": args.workers,
                            "pipeline": args.pipeline, "set": settings(args), "fusion_cache": args.fusion_cache},
                           args.timeout))
        print(json.dumps(rows[-1]), file=sys.stderr)
    return {"size": list(args.size), "workers": args.workers, "pipeline": args.pipeline, "set": settings(args),
            "fusion_cache": args.fusion_cache, "rows": rows}


#: shortcut flag -> the --set item it stands for
SHORTCUTS = {"schedule": "patchmatch.schedule", "levels": "patchmatch.levels", "iterations": "patchmatch.iterations",
             "geom_passes": "patchmatch.geom_passes", "num_source_views": "scene.num_source_views"}


def settings(args: argparse.Namespace) -> list[str]:
    """The --set items of a run: the shortcut flags given, then --set (which wins)."""
    items = [f"{key}={getattr(args, flag)}" for flag, key in SHORTCUTS.items() if getattr(args, flag) is not None]
    return items + list(args.set)


def plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = result["rows"]
    n = [r["views"] for r in rows]
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    a.plot(n, [r["wall_s"] for r in rows], "o-", label="wall")
    a.plot(n, [r["seconds"]["patchmatch"] for r in rows], "s--", label="PatchMatch + counter tasks")
    a.plot(n, [r["seconds"]["fusion"] for r in rows], "^--", label="fusion (driver)")
    a.set_xlabel("views")
    a.set_ylabel("seconds")
    a.legend()
    b.plot(n, [max(r["worker_peak_mb"]) for r in rows], "o-", label="worker (max over workers)")
    b.plot(n, [r["driver_peak_mb"] for r in rows], "s-", label="driver")
    b.plot(n, [r["driver_fusion_peak_mb"] for r in rows], "^--", label="driver during fusion")
    b.set_xlabel("views")
    b.set_ylabel("peak RSS (MiB)")
    b.legend()
    fig.suptitle(f"street sequences {result['size'][0]}x{result['size'][1]}, {result['workers']} Dask workers")
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--one", help=argparse.SUPPRESS)
    sub = ap.add_subparsers(dest="mode")
    f = sub.add_parser("fountain")
    f.add_argument("--scene", default=str(bench.SHARED_DATA / "fountain_p11"))
    f.add_argument("--max-image-size", type=int, default=768)
    f.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    f.add_argument("--json", default=None)
    f.add_argument("--timeout", type=float, default=3600)
    s = sub.add_parser("sequence")
    s.add_argument("--views", type=int, nargs="+", default=[50, 100, 200, 400])
    s.add_argument("--size", type=int, nargs=2, default=[320, 240])
    s.add_argument("--workers", type=int, default=2)
    s.add_argument("--scenes", default=str(Path(tempfile.gettempdir()) / "deepc_street_scenes"))
    s.add_argument("--json", default=None)
    s.add_argument("--timeout", type=float, default=7200)
    s.add_argument("--pipeline", choices=("vanilla", "fast", "full"), default="vanilla")
    s.add_argument("--set", action="append", default=[], metavar="SECTION.NAME=VALUE",
                   help="an option as deepc run --set (sections scene, patchmatch, confidence, fusion); repeatable")
    s.add_argument("--schedule", default=None, help="patchmatch.schedule (paper, acmm)")
    s.add_argument("--levels", type=int, default=None, help="patchmatch.levels")
    s.add_argument("--iterations", type=int, default=None, help="patchmatch.iterations (every pass)")
    s.add_argument("--geom-passes", type=int, default=None, help="patchmatch.geom_passes")
    s.add_argument("--num-source-views", type=int, default=None, help="scene.num_source_views")
    s.add_argument("--fusion-cache", type=int, default=None, metavar="VIEWS",
                   help="views the driver's fusion holds at once (default: 1 + the longest overlap list)")
    args = ap.parse_args(argv)
    if args.one:
        print(json.dumps(run_one(json.loads(args.one))))
        return 0
    if args.mode is None:
        ap.error("choose fountain or sequence")
    result = fountain(args) if args.mode == "fountain" else sequence(args)
    path = Path(args.json or bench.results_path(__file__, args.mode))
    bench.write_result(result, path)
    bench.print_table(summary(result))
    if args.mode == "sequence":
        plot(result, path.with_suffix(".png"))
    print(f"results: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
