"""Roofline of the PatchMatch kernels: cycles per NCC sample and per pixel update against what this CPU can do.

    .venv/bin/python benchmarks/performance/roofline.py [--size 768x512] [--sources 5] [--rows 64]
        [--iterations 3] [--json benchmarks/results/roofline.json]

One thread throughout (per-core numbers; the kernels scale over rows), timed in CPU seconds of the process so that
another job beside it shares the cores without inflating the numbers (it still shares the caches). The scene is the
analytic textured corner of ``support/pm_synthetic.py`` (ground-truth hypotheses, so every window projects inside
its source) with the standard 36-sample window everywhere. Measured, best of 3:

- ``clock``: the core's effective clock, from a chain of dependent float64 additions (no fastmath, so LLVM keeps
  the chain; 3 cycles each on AMD Zen 2-4 and Intel since Skylake-X: the assumption is recorded). Cycles below are
  seconds x this clock.
- ``ncc``: ``ncc.ncc_cost`` as the kernels call it (``photometric_cost``), every pixel of ``--rows`` rows against
  every source: cycles per weighted sample and per window, less the pixels' ``window_weights`` (loaded once per
  pixel for its N windows here, once per pixel update for ~57 windows in a half-step).
- ``window_weights``: ``ncc.load_window`` alone per pixel (a pixel's bilateral weights are computed each time a kernel
  visits it rather than stored: 2·S floats a pixel).
- ``floor_gather``: a plain loop that only gathers the same four texels per sample (their indices and bilinear
  fractions precomputed and streamed in), blends them and accumulates the three weighted sums: the memory and
  load-port floor of the sampling.
- ``floor_project``: the projection alone (the 8-wide loop with its two divisions per sample): the arithmetic
  floor of the homography.
- ``half_step``: ``--iterations`` red-black iterations of a photometric pass from random hypotheses (the default
  options: DeepC pattern, view selection, refinement, cost caches, active set): cycles per pixel update, NCC
  windows per update, and cycles per window with everything around the NCC (candidates, view selection) counted.

The roofline in the result's ``bounds``: the kernel's cycles per sample beside the two floors, and the share of a
pixel update's cycles that its windows' samples account for at the kernel's rate (the rest is per-window and
per-pixel overhead).
"""

from __future__ import annotations

import argparse
import time

import numba
import numpy as np
from numba import njit

from engine.patchmatch import PatchMatchOptions, ViewState, run_view_level
from engine.patchmatch.context import build_context
from engine.patchmatch.geometry import GEO_A, GEO_B, GEO_H, GEO_W, plane_vector, ray
from engine.patchmatch.kernels import (
    CNT_CURRENT,
    CNT_PIXELS,
    CNT_REFINE,
    CNT_REMAINING,
    CNT_ROWS,
    photometric_cost,
    random_init_kernel,
)
from engine.patchmatch.ncc import load_window, ncc_work, work_width
from support import bench
from support.pm_synthetic import make_scene

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"size": list, "sources": int, "rows": int, "threads": int, "clock": dict, "ncc": dict,
          "window_weights": dict, "floor_gather": dict, "floor_project": dict, "half_step": dict, "bounds": dict}

FADD_LATENCY = 3  # cycles of a dependent float64 addition (AMD Zen 2-4, Intel Skylake-X and later)


@njit(cache=True)
def _fadd_chain(n: int, step: float) -> float:
    s = 0.0
    for _ in range(n):
        s = s + step
    return s


def core_clock(repeats: int = 3) -> dict:
    """Effective core clock (Hz) from a dependent addition chain."""
    n = 200_000_000
    _fadd_chain(1000, 1e-9)
    best = min(_timed(lambda: _fadd_chain(n, 1e-9)) for _ in range(repeats))
    return {"hz": FADD_LATENCY * n / best, "method": f"{n} dependent float64 additions, {FADD_LATENCY} cycles each"}


def _timed(fn) -> float:
    # CPU seconds of this process, not wall: another job on the machine then takes turns with this one without
    # counting (one kernel thread, so CPU seconds are its seconds)
    t = time.process_time()
    fn()
    return time.process_time() - t


@njit(cache=True, fastmath=True)
def _ncc_rows(src, stride, plane, geo, kinv, img, offs, sig, mode, mu_a, var_a, ox, oy, wset, ns, depth, nrm, y0, y1,
              min_var, out):
    """Every pixel of rows [y0, y1) against every source with the kernels' cost function; returns samples."""
    h, w = depth.shape
    win, sidx = ncc_work(ox.shape[1])
    samples = 0
    for y in range(y0, y1):
        for x in range(w):
            n = load_window(win, img, offs, sig, mode, ox, oy, wset, ns, x, y)
            rp = ray(kinv, x, y)
            m0, m1, m2, ok = plane_vector(kinv, rp, depth[y, x], nrm[y, x, 0], nrm[y, x, 1], nrm[y, x, 2])
            for j in range(geo.shape[0]):
                out[y - y0, x, j] = photometric_cost(src, stride, plane, geo, j, win, n, mu_a[y, x], var_a[y, x], x, y,
                                                     m0, m1, m2, min_var, sidx)
                samples += n
    return samples


@njit(cache=True, fastmath=True)
def _load_windows(img, offs, sig, mode, ox, oy, wset, ns, y0, y1, w):
    """Only ``load_window`` for every pixel of rows [y0, y1): a pixel's weights, computed where a kernel visits it."""
    win, _ = ncc_work(ox.shape[1])
    acc = np.float32(0)
    for y in range(y0, y1):
        for x in range(w):
            load_window(win, img, offs, sig, mode, ox, oy, wset, ns, x, y)
            acc += win[0, 0]
    return acc


@njit(cache=True, fastmath=True)
def _projections(geo, kinv, ox, oy, wset, ns, depth, nrm, y0, y1, plane, stride, idx, fu, fv, ok_out):
    """The texel index (into the raveled stack) and bilinear fractions of every sample of every window of rows
    [y0, y1), as ``ncc_cost``'s first loop computes them (not timed: the gather floor's input)."""
    w = depth.shape[1]
    for y in range(y0, y1):
        for x in range(w):
            rp = ray(kinv, x, y)
            m0, m1, m2, ok = plane_vector(kinv, rp, depth[y, x], nrm[y, x, 0], nrm[y, x, 1], nrm[y, x, 2])
            s = wset[y, x]
            for j in range(geo.shape[0]):
                p = (y - y0) * w + x
                h = np.empty(9, np.float32)
                for r in range(3):
                    for c in range(3):
                        h[3 * r + c] = np.float32(geo[j, GEO_A + 3 * r + c] - geo[j, GEO_B + r] * (m0, m1, m2)[c])
                wmax = np.float32(geo[j, GEO_W] - 1)
                hmax = np.float32(geo[j, GEO_H] - 1)
                ok_out[p, j] = ok
                for k in range(ns[s]):
                    dx = np.float32(x) + ox[s, k]
                    dy = np.float32(y) + oy[s, k]
                    hz = max(h[6] * dx + h[7] * dy + h[8], np.float32(1e-6))
                    u = min(max((h[0] * dx + h[1] * dy + h[2]) / hz, np.float32(0)), wmax)
                    v = min(max((h[3] * dx + h[4] * dy + h[5]) / hz, np.float32(0)), hmax)
                    iu = np.int32(u)
                    iv = np.int32(v)
                    idx[p, j, k] = j * plane + iv * stride + iu
                    fu[p, j, k] = u - np.float32(iu)
                    fv[p, j, k] = v - np.float32(iv)


@njit(cache=True, fastmath=True)
def _gather_floor(flat, stride, idx, fu, fv, wgt_rows, wa_rows, n, out):
    """Only the sampling: four texels per sample, the bilinear blend and the three weighted sums."""
    ustride = np.int64(stride)
    for p in range(idx.shape[0]):
        for j in range(idx.shape[1]):
            sb = np.float32(0)
            sbb = np.float32(0)
            sab = np.float32(0)
            for k in range(n):
                i = np.int64(idx[p, j, k])
                p00 = flat[i]
                p01 = flat[i + 1]
                p10 = flat[i + ustride]
                p11 = flat[i + ustride + 1]
                a = fu[p, j, k]
                top = p00 + a * (p01 - p00)
                bot = p10 + a * (p11 - p10)
                b = top + fv[p, j, k] * (bot - top)
                wb = wgt_rows[p, k] * b
                sb += wb
                sbb += wb * b
                sab += wa_rows[p, k] * b
            out[p, j] = sab - sb * sbb


@njit(cache=True, fastmath=True)
def _project_floor(h, ox, oy, n, n_windows, wmax, hmax, scratch):
    """Only the projection: the 8-wide loop of ``ncc_cost`` (two divisions per sample) over ``n_windows`` windows."""
    acc = np.float32(0)
    n_vec = work_width(n)
    for t in range(n_windows):
        cz = h[8] + np.float32(t & 7) * np.float32(1e-3)  # varies per window so the loop is not hoisted
        for k in range(n_vec):
            dx = ox[k]
            dy = oy[k]
            hz = max(cz + h[6] * dx + h[7] * dy, np.float32(1e-6))
            u = min(max((h[2] + h[0] * dx + h[1] * dy) / hz, np.float32(0)), wmax)
            v = min(max((h[5] + h[3] * dx + h[4] * dy) / hz, np.float32(0)), hmax)
            scratch[0, k] = u
            scratch[1, k] = v
        acc += scratch[0, t & 7] + scratch[1, 0]
    return acc


def _best(fn, repeats: int = 3) -> float:
    fn()
    return min(_timed(fn) for _ in range(repeats))


def measure(width: int, height: int, n_src: int, rows: int, iterations: int) -> dict:
    numba.set_num_threads(1)
    views, gts = make_scene(width, height, n_views=n_src + 1)
    v = views[0]
    opts = PatchMatchOptions()
    ctx = build_context(v.image_gray, v.camera, [views[j].image_gray for j in v.source_views],
                        [views[j].camera for j in v.source_views], opts,
                        fine_allowed=np.zeros((height, width), np.uint8))
    depth = gts[0].astype(np.float32)
    nrm = np.zeros((height, width, 3), np.float32)
    nrm[..., 2] = -1.0
    y0 = (height - rows) // 2
    y1 = y0 + rows
    n = int(ctx.ns[0])
    clock = core_clock()
    hz = clock["hz"]
    result: dict = {"size": [width, height], "sources": n_src, "rows": rows, "threads": 1, "clock": clock}

    out = np.empty((rows, width, n_src), np.float32)
    args = (ctx.flat, ctx.stride, ctx.plane, ctx.geo, ctx.kinv, ctx.image, ctx.offs_sets, ctx.sigmas, ctx.weighting,
            ctx.mu_a, ctx.var_a, ctx.ox, ctx.oy, ctx.wset, ctx.ns, depth, nrm, y0, y1, np.float32(opts.min_var), out)
    n_px = rows * width
    weights_seconds = _best(lambda: _load_windows(ctx.image, ctx.offs_sets, ctx.sigmas, ctx.weighting, ctx.ox,
                                                  ctx.oy, ctx.wset, ctx.ns, y0, y1, width))
    result["window_weights"] = {"pixels": n_px, "seconds": weights_seconds,
                                "cycles_per_pixel": weights_seconds * hz / n_px}
    samples = _ncc_rows(*args)
    with_weights = _best(lambda: _ncc_rows(*args))
    seconds = with_weights - weights_seconds  # the windows alone: each pixel's weights are loaded once for N windows
    windows = rows * width * n_src
    result["ncc"] = {"samples": samples, "windows": windows, "seconds": seconds, "seconds_with_weights": with_weights,
                     "cycles_per_sample": seconds * hz / samples, "cycles_per_window": seconds * hz / windows,
                     "samples_per_window": samples / windows}
    idx = np.empty((n_px, n_src, n), np.int32)
    fu = np.empty((n_px, n_src, n), np.float32)
    fv = np.empty((n_px, n_src, n), np.float32)
    ok = np.empty((n_px, n_src), np.bool_)
    _projections(ctx.geo, ctx.kinv, ctx.ox, ctx.oy, ctx.wset, ctx.ns, depth, nrm, y0, y1, ctx.plane, ctx.stride, idx,
                 fu, fv, ok)
    wgt, wa = ctx.window_weights()
    wgt_rows = np.ascontiguousarray(wgt[y0:y1, :, :n].reshape(n_px, n))
    wa_rows = np.ascontiguousarray(wa[y0:y1, :, :n].reshape(n_px, n))
    del wgt, wa
    gout = np.empty((n_px, n_src), np.float32)
    seconds = _best(lambda: _gather_floor(ctx.flat, ctx.stride, idx, fu, fv, wgt_rows, wa_rows, n, gout))
    result["floor_gather"] = {"samples": n_px * n_src * n, "seconds": seconds,
                              "cycles_per_sample": seconds * hz / (n_px * n_src * n),
                              "streamed_bytes_per_sample": 12}

    h = np.array([1.0, 0.01, 3.0, 0.02, 1.0, 2.0, 1e-4, 2e-4, 1.0], np.float32)
    scratch = np.empty((2, work_width(n)), np.float32)
    seconds = _best(lambda: _project_floor(h, ctx.ox[0], ctx.oy[0], n, windows, np.float32(width - 1),
                                           np.float32(height - 1), scratch))
    result["floor_project"] = {"samples": windows * work_width(n), "seconds": seconds,
                               "cycles_per_sample": seconds * hz / (windows * work_width(n))}

    # a photometric pass's first iterations on the whole view from random hypotheses (what a pass costs most)
    state = ViewState.zeros(height, width)
    random_init_kernel(state.depth, state.normal, ctx.kinv, v.depth_min, v.depth_max, np.uint64(7), False)
    per_iteration: list[dict] = []

    clock_at = [0.0]

    def on_iteration(t: int, counts: np.ndarray, wall: float) -> None:
        now = time.process_time()
        secs = now - clock_at[0]  # CPU seconds since the previous iteration (the first includes the initial cost)
        clock_at[0] = now
        wins = int(counts[CNT_ROWS] + counts[CNT_CURRENT] + counts[CNT_REMAINING] + counts[CNT_REFINE])
        px = int(counts[CNT_PIXELS])
        per_iteration.append({"iteration": t, "seconds": secs, "pixel_updates": px, "windows": wins,
                              "windows_per_update": wins / max(px, 1),
                              "cycles_per_update": secs * hz / max(px, 1),
                              "cycles_per_window": secs * hz / max(wins, 1)})

    warm = ViewState.zeros(24, 32)
    run_view_level(warm, build_context(v.image_gray[:24, :32], v.camera, [views[1].image_gray[:24, :32]],
                                       [views[1].camera], opts), opts, 1.0, 10.0, iterations=1)
    clock_at[0] = time.process_time()
    run_view_level(state, ctx, opts, v.depth_min, v.depth_max, iterations=iterations, on_iteration=on_iteration)
    secs = sum(r["seconds"] for r in per_iteration)
    wins = sum(r["windows"] for r in per_iteration)
    px = sum(r["pixel_updates"] for r in per_iteration)
    result["half_step"] = {"iterations": per_iteration, "seconds": secs, "windows_per_update": wins / px,
                           "cycles_per_update": secs * hz / px, "cycles_per_window": secs * hz / wins}

    ncc = result["ncc"]
    sample_share = wins * ncc["cycles_per_window"] / (secs * hz)
    result["bounds"] = {
        "kernel_cycles_per_sample": ncc["cycles_per_sample"],
        "floor_gather_cycles_per_sample": result["floor_gather"]["cycles_per_sample"],
        "floor_project_cycles_per_sample": result["floor_project"]["cycles_per_sample"],
        "floor_cycles_per_sample": (result["floor_gather"]["cycles_per_sample"]
                                    + result["floor_project"]["cycles_per_sample"]),
        "kernel_over_floor": ncc["cycles_per_sample"] / (result["floor_gather"]["cycles_per_sample"]
                                                         + result["floor_project"]["cycles_per_sample"]),
        "window_share_of_update": sample_share,
        "window_weights_share_of_update": result["window_weights"]["cycles_per_pixel"] / (secs * hz / px),
        "update_cycles_at_floor": (wins / px) * ncc["samples_per_window"] * (
            result["floor_gather"]["cycles_per_sample"] + result["floor_project"]["cycles_per_sample"]),
    }
    return result


def summary(result: dict) -> list[dict]:
    """Cycles per NCC sample of the kernel and of the two floors, and per pixel update of a half-step."""
    b = result["bounds"]
    hs = result["half_step"]
    return [
        {"measure": "effective core clock", "value": result["clock"]["hz"] / 1e9, "unit": "GHz"},
        {"measure": "ncc_cost (as the kernels call it)", "value": b["kernel_cycles_per_sample"],
         "unit": "cycles/sample"},
        {"measure": "floor: gather + blend + sums only", "value": b["floor_gather_cycles_per_sample"],
         "unit": "cycles/sample"},
        {"measure": "floor: projection only (8 wide, 2 divisions)", "value": b["floor_project_cycles_per_sample"],
         "unit": "cycles/sample"},
        {"measure": "kernel / (sum of floors)", "value": b["kernel_over_floor"], "unit": "x"},
        {"measure": "half-step: NCC windows per pixel update", "value": hs["windows_per_update"], "unit": "windows"},
        {"measure": "half-step: cycles per pixel update", "value": hs["cycles_per_update"], "unit": "cycles"},
        {"measure": "half-step: cycles per window (all included)", "value": hs["cycles_per_window"], "unit": "cycles"},
        {"measure": "share of an update's cycles spent in its windows", "value": 100 * b["window_share_of_update"],
         "unit": "%"},
        {"measure": "a pixel's window weights, computed per visit",
         "value": result["window_weights"]["cycles_per_pixel"], "unit": "cycles"},
        {"measure": "their share of a pixel update", "value": 100 * b["window_weights_share_of_update"], "unit": "%"},
        {"measure": "pixel update at the floor (its windows' samples only)", "value": b["update_cycles_at_floor"],
         "unit": "cycles"},
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="768x512", help="image size WxH (px)")
    ap.add_argument("--sources", type=int, default=5, help="source views (the peer comparison's 5)")
    ap.add_argument("--rows", type=int, default=64, help="rows of the NCC and floor measurements")
    ap.add_argument("--iterations", type=int, default=3, help="red-black iterations of the half-step measurement")
    ap.add_argument("--json", default=bench.results_path(__file__))
    args = ap.parse_args()
    width, height = (int(s) for s in args.size.split("x"))
    result = measure(width, height, args.sources, args.rows, args.iterations)
    bench.print_table(summary(result))
    bench.write_result(result, args.json)
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
