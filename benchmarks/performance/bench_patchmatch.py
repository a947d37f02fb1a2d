"""PatchMatch engine benchmark: NCC throughput, time per view and iteration, compile time, threads, memory.

    .venv/bin/python benchmarks/performance/bench_patchmatch.py [--sizes 320x240,768x512] [--sources 4,5,10]
        [--json benchmarks/results/bench_patchmatch.json] [--quick]

Scenes are the analytic textured planes of ``support/pm_synthetic.py`` rendered at each size.
Reported:
- weighted NCC samples/s: ``init_cost_kernel`` evaluates every pixel against every source view
  (N · Σ_pixels S weighted samples; S = 36 with the standard window, 25 where a pixel takes the fine
  window), best of 3, 1 and 2 threads;
- seconds per view per red-black iteration (black + red half-step) of a photometric pass at the
  given size and source count (ACMM 5-combination refinement, DeepC pattern), iterations 1..3 averaged,
  with the NCC windows the iteration evaluated per pixel update (``IterationEvent.ncc_windows``; SPEC
  §2.12 budgets (K_up + 1 + 5) · N, the cost caches and early exits need far fewer) and per second;
- JIT compile time: a subprocess running a tiny problem with a fresh NUMBA_CACHE_DIR (cold) and again
  with the cache filled (cached), wall time of the whole process;
- 1 -> 2 thread speed-up of one iteration at the first size;
- peak resident memory of this process.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import subprocess
import sys
import tempfile
import time
import warnings

import numba
import numpy as np

from engine.patchmatch import PatchMatchOptions, ViewState, kernel_params, run_patchmatch
from engine.patchmatch.context import build_context
from engine.patchmatch.view_pass import init_cost
from support import bench
from support.pm_synthetic import make_scene

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"cpu_count": int, "numba_threads": int, "threading_layer": str, "ncc": list, "iterations": list,
          "thread_speedup_1_to_2": float, "compile_seconds": dict, "peak_rss_mb": float}


TINY_RUN = (
    "from support.pm_synthetic import make_scene; from engine.patchmatch import PatchMatchOptions, run_patchmatch;"
    "from engine.consistency import compute_counter_maps;"
    "v, _ = make_scene(48, 40, n_views=3); m = run_patchmatch(v, PatchMatchOptions(iterations=1, levels=1));"
    "compute_counter_maps(v, m)"
)


def ncc_throughput(width: int, height: int, n_src: int, threads: int) -> dict:
    views, _ = make_scene(width, height, n_views=n_src + 1)
    v = views[0]
    opts = PatchMatchOptions()
    ctx = build_context(v.image_gray, v.camera, [views[j].image_gray for j in v.source_views],
                        [views[j].camera for j in v.source_views], opts)
    st = ViewState.zeros(height, width)
    st.depth[:] = 4.0
    st.normal[..., 2] = -1.0
    params = kernel_params(opts, 1.0, 10.0)
    old = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        init_cost(st, ctx, params)  # warm-up / compile
        best = np.inf
        for _ in range(3):
            t = time.perf_counter()
            init_cost(st, ctx, params)
            best = min(best, time.perf_counter() - t)
    finally:
        numba.set_num_threads(old)
    samples = int(n_src * ctx.samples_per_cost().sum())
    return {"size": f"{width}x{height}", "sources": n_src, "threads": threads, "samples": samples,
            "seconds": best, "samples_per_s": samples / best}


def iteration_time(width: int, height: int, n_src: int, threads: int) -> dict:
    views, _ = make_scene(width, height, n_views=n_src + 1)
    times: list[float] = []
    windows: list[int] = []

    class Obs:
        def on_iteration(self, e):
            if e.view == 0 and e.iteration > 0:
                times.append(e.seconds)
                windows.append(e.ncc_windows)

    opts = PatchMatchOptions(levels=1, geom_passes=0, iterations=4, num_threads=threads)
    # only view 0 is timed: the others keep their images (they are its sources) but get no source
    # views themselves, so they are skipped and cost nothing
    vs = [views[0]] + [dataclasses.replace(v, source_views=[]) for v in views[1:]]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_patchmatch(vs, opts, observer=Obs())
    per_update = float(np.mean(windows)) / (width * height)
    return {"size": f"{width}x{height}", "sources": n_src, "threads": threads,
            "seconds_per_view_iteration": float(np.mean(times)),
            "ncc_windows_per_pixel_update": per_update,
            "ncc_windows_per_s": float(np.sum(windows) / np.sum(times))}


def compile_times() -> dict:
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, PYTHONPATH=str(bench.REPO_ROOT))
        out = {}
        for label in ("cold", "cached"):
            t = time.perf_counter()
            subprocess.run([sys.executable, "-c", TINY_RUN], check=True, env=env)
            out[label] = time.perf_counter() - t
    return out


def summary(result: dict) -> list[dict]:
    """NCC throughput per thread count, seconds per view and red-black iteration per size and source count,
    compile times and peak memory."""
    rows = [{"measure": f"NCC {r['size']} N={r['sources']} {r['threads']} thread(s)", "value": r["samples_per_s"] / 1e6,
             "unit": "M samples/s"} for r in result["ncc"]]
    rows += [{"measure": f"iteration {r['size']} N={r['sources']} {r['threads']} threads",
              "value": r["seconds_per_view_iteration"], "unit": "s/view"} for r in result["iterations"]]
    rows.append({"measure": "1 -> 2 threads speed-up", "value": result["thread_speedup_1_to_2"], "unit": "x"})
    for label, seconds in result.get("compile_seconds", {}).items():
        rows.append({"measure": f"compile ({label})", "value": seconds, "unit": "s"})
    rows.append({"measure": "peak RSS", "value": result["peak_rss_mb"], "unit": "MiB"})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="320x240,768x512")
    ap.add_argument("--sources", default="4,5,10")
    ap.add_argument("--json", default=bench.results_path(__file__))
    ap.add_argument("--quick", action="store_true", help="320x240 and 4 sources only, no compile timing")
    args = ap.parse_args()
    sizes = [tuple(int(x) for x in s.split("x")) for s in args.sizes.split(",")]
    sources = [int(s) for s in args.sources.split(",")]
    if args.quick:
        sizes, sources = sizes[:1], sources[:1]
    result: dict = {"cpu_count": os.cpu_count(), "numba_threads": numba.config.NUMBA_NUM_THREADS,
                    "threading_layer": None, "ncc": [], "iterations": []}
    w, h = sizes[0]
    for threads in (1, 2):
        r = ncc_throughput(w, h, sources[0], threads)
        result["ncc"].append(r)
        print(f"NCC {r['size']} N={r['sources']} threads={threads}: {r['samples_per_s'] / 1e6:8.1f} M samples/s")
    try:
        result["threading_layer"] = numba.threading_layer()
    except ValueError:
        pass
    for (w, h) in sizes:
        for n in sources:
            r = iteration_time(w, h, n, 2)
            result["iterations"].append(r)
            print(f"iteration {r['size']} N={n:2d} 2 threads: {r['seconds_per_view_iteration']:7.3f} s/view/iteration, "
                  f"{r['ncc_windows_per_pixel_update']:5.1f} NCC windows per pixel update "
                  f"(SPEC's budget {(16 + 1 + 5) * n}), {r['ncc_windows_per_s'] / 1e6:5.2f} M windows/s")
    w, h = sizes[0]
    one = iteration_time(w, h, sources[0], 1)["seconds_per_view_iteration"]
    two = iteration_time(w, h, sources[0], 2)["seconds_per_view_iteration"]
    result["thread_speedup_1_to_2"] = one / two
    print(f"1 -> 2 threads speed-up ({w}x{h}, N={sources[0]}): {one / two:.2f}x ({one:.3f} s -> {two:.3f} s)")
    if not args.quick:
        result["compile_seconds"] = compile_times()
        print(f"compile (process wall time): cold {result['compile_seconds']['cold']:.1f} s, "
              f"cached {result['compile_seconds']['cached']:.1f} s")
    result["peak_rss_mb"] = bench.peak_rss_mb()
    print(f"peak RSS: {result['peak_rss_mb']:.0f} MB")
    bench.write_result(result, args.json)
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
