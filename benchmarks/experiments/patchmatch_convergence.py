"""Where PatchMatch's iterations stop changing anything: per level, pass and iteration, the share of pixels whose
hypothesis changed, changed by more than 1 % in depth, and the pooled depth within 1 % of GT.

    .venv/bin/python benchmarks/experiments/patchmatch_convergence.py [SCENE] [--size 768] [--schedule paper]
        [--set patchmatch.NAME=VALUE ...] [--fuse OUT] [--active-from T] [--num-source-views 5]
        [--json benchmarks/results/patchmatch_convergence.json]

``--set patchmatch.active_share=0.1`` turns the active set on (``kernels.half_step_kernel``), ``--set
patchmatch.converge_ratio=0.8`` convergence-driven pass ends. Every run also reports the kernels' work: pixel
updates evaluated and skipped by the active set, NCC windows, and the CPU seconds of the half-steps (all threads;
steadier than wall time on a shared machine). ``--fuse OUT`` runs the vanilla pipeline (PatchMatch, fusion,
evaluation) into OUT instead of PatchMatch alone and adds its fused F1 and depth within 1 % to the result;
``--active-from T`` (ablation) starts the active set at iteration T of every pass instead of
``records.ACTIVE_FROM_ITERATION``.

The measurement behind convergence-driven iteration counts (issue 34): an iteration whose changed share is
small and whose within-1 % does not move is an iteration a user pays for and gets nothing from. "Changed"
compares a view's depth and normal after the iteration with the same view's maps before it; within 1 % is
pooled over all views with GT at the level's resolution (GT resampled as the stream does it).
"""

from __future__ import annotations

import argparse
import collections
import time
from pathlib import Path

import numpy as np

import engine.patchmatch.kernels as K
import engine.patchmatch.records as records
import engine.patchmatch.view_pass as view_pass
from engine.core.resample import resample_depth
from engine.patchmatch import PatchMatchOptions, run_patchmatch
from engine.run.pipeline import PipelineOptions, patchmatch_views, run_pipeline
from engine.scene import SceneOptions, load_scene
from support import bench
from workbench.flags.assignments import section_overrides

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"scene": str, "size": list, "views": int, "options": dict, "total_seconds": float, "cpu_seconds?": float,
          "kernels?": dict, "fused?": dict, "pixel_iterations": float, "final_within_1pct": float, "rows": list,
          "active_from_iteration?": int}



class _Convergence:
    """Counts per (level, pass, iteration) over all views: pixels, changed, changed > 1 %, within 1 % of GT."""

    def __init__(self, gt: list[np.ndarray | None]):
        self.gt = gt
        self.gt_level: dict[tuple[int, int], np.ndarray | None] = {}
        self.previous: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.counts: dict[tuple[int, int, int], np.ndarray] = collections.defaultdict(lambda: np.zeros(6))
        self.seconds: dict[tuple[int, int, int], float] = collections.defaultdict(float)

    def _gt_at(self, view: int, shape: tuple[int, int]) -> np.ndarray | None:
        key = (view, shape[0])
        if key not in self.gt_level:
            gt = self.gt[view]
            self.gt_level[key] = None if gt is None else resample_depth(gt, (shape[1], shape[0]))
        return self.gt_level[key]

    def on_stage(self, name: str, **info) -> None:
        if name == "patchmatch_pass":
            # a pass starts from upsampled or carried-over maps: compare with the first iteration's input only
            # within the pass
            self.previous.clear()

    def on_iteration(self, e) -> None:
        key = (e.level, e.pass_index, e.iteration)
        depth, normal = e.depth, e.normal
        row = self.counts[key]
        row[0] += depth.size
        prev = self.previous.get(e.view)
        if prev is not None:
            pd, pn = prev
            row[1] += np.count_nonzero((pd != depth) | np.any(pn != normal, axis=2))
            with np.errstate(divide="ignore", invalid="ignore"):
                rel = np.abs(depth - pd) / np.maximum(depth, 1e-12)
            row[2] += np.count_nonzero(rel > 0.01)
            row[5] += depth.size
        gt = self._gt_at(e.view, depth.shape)
        if gt is not None:
            valid = gt > 0
            row[3] += np.count_nonzero(valid & (np.abs(depth - gt) <= 0.01 * gt))
            row[4] += np.count_nonzero(valid)
        self.seconds[key] += e.seconds
        self.previous[e.view] = (depth.copy(), normal.copy())

    def rows(self) -> list[dict]:
        out = []
        for key in sorted(self.counts, key=lambda k: (-k[0], k[1], k[2])):
            n, changed, changed1, within, gt_n, compared = self.counts[key]
            out.append({"level": key[0], "pass_index": key[1], "iteration": key[2],
                        "changed_pct": 100 * changed / compared if compared else None,
                        "changed_1pct_pct": 100 * changed1 / compared if compared else None,
                        "within_1pct": 100 * within / gt_n if gt_n else None,
                        "seconds": self.seconds[key]})
        return out


class _KernelWork:
    """Sums the counts (``kernels.CNT_*``) and the CPU seconds of every half-step while installed (it wraps
    ``view_pass.half_step``, which ``run_view_level`` calls)."""

    def __init__(self) -> None:
        self.counts = np.zeros(K.N_COUNTS, np.int64)
        self.cpu_seconds = 0.0
        self.original = view_pass.half_step

    def __enter__(self) -> _KernelWork:
        def counted(*args, **kwargs):
            t0 = time.process_time()
            counts = self.original(*args, **kwargs)
            self.cpu_seconds += time.process_time() - t0
            self.counts += counts
            return counts

        view_pass.half_step = counted
        return self

    def __exit__(self, *exc) -> None:
        view_pass.half_step = self.original

    def summary(self) -> dict:
        c = self.counts
        windows = int(c[: K.CNT_PIXELS].sum())
        return {"pixel_updates": int(c[K.CNT_PIXELS]), "pixels_skipped": int(c[K.CNT_SKIPPED]),
                "ncc_windows": windows, "windows_per_update": windows / max(int(c[K.CNT_PIXELS]), 1),
                "half_step_cpu_seconds": self.cpu_seconds,
                "windows_rows": int(c[K.CNT_ROWS]), "windows_current": int(c[K.CNT_CURRENT]),
                "windows_remaining": int(c[K.CNT_REMAINING]), "windows_refine": int(c[K.CNT_REFINE])}


def summary(result: dict) -> list[dict]:
    """One row per run: its schedule and options, the work done and the final depth within 1 %."""
    opts = ", ".join(f"{k}={v}" for k, v in result["options"].items())
    if "active_share" in result["options"] and "active_from_iteration" in result:
        opts += f", active from iteration {result['active_from_iteration']}"
    row = {"scene": Path(result["scene"]).name, "options": opts,
           "pixel-iterations (M)": result.get("pixel_iterations", 0) / 1e6,
           "final within 1 %": result.get("final_within_1pct"), "seconds": result["total_seconds"]}
    kernels = result.get("kernels")
    if kernels:  # results since the active set: the kernels' work
        row.update({"updates (M)": kernels["pixel_updates"] / 1e6, "skipped (M)": kernels["pixels_skipped"] / 1e6,
                    "NCC windows (M)": kernels["ncc_windows"] / 1e6,
                    "half-step CPU s": kernels["half_step_cpu_seconds"]})
    f1 = (result.get("fused") or {}).get("f1")
    if f1:
        row["fused F1 1 / 2 / 5 cm"] = " / ".join(f"{v:.2f}" for v in f1[:3])
    return [row]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", default="sample_scenes/small")
    ap.add_argument("--size", type=int, default=0, help="longest image side (0 = the scene's size)")
    ap.add_argument("--schedule", default="paper")
    ap.add_argument("--set", action="append", default=[], metavar="patchmatch.NAME=VALUE")
    ap.add_argument("--num-source-views", type=int, default=5)
    ap.add_argument("--fuse", default=None, metavar="OUT", help="run the vanilla pipeline into OUT (fused F1)")
    ap.add_argument("--active-from", type=int, default=None, metavar="T",
                    help=f"ablation: first iteration of the active set (default {records.ACTIVE_FROM_ITERATION})")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    if args.active_from is not None:
        records.ACTIVE_FROM_ITERATION = args.active_from  # read by records.active_share at every iteration
    scene_options = SceneOptions(num_source_views=args.num_source_views,
                                 **({"max_image_size": args.size} if args.size else {}))
    scene = load_scene(args.scene, scene_options)
    views = patchmatch_views(scene)
    overrides = section_overrides(args.set, "patchmatch", PatchMatchOptions)
    options = PatchMatchOptions(schedule=args.schedule, **overrides).validate()
    probe = _Convergence([scene.gt_depth(i) for i in range(len(views))])
    t0 = time.perf_counter()
    cpu0 = time.process_time()
    fused = None
    with _KernelWork() as work:
        if args.fuse:
            pipeline = PipelineOptions(pipeline="vanilla", patchmatch=options)
            result = run_pipeline(scene, args.fuse, pipeline, observer=probe)
            maps, metrics = result.maps, result.metrics
            fused = {"f1": metrics.get("eval", {}).get("f1"), "tolerances": metrics.get("eval", {}).get("tolerances"),
                     "depth_within_1pct": metrics.get("depth", {}).get("within_1pct"),
                     "patchmatch_seconds": metrics["seconds"]["patchmatch"]}
        else:
            maps = run_patchmatch(views, options, observer=probe)
    total = time.perf_counter() - t0
    cpu = time.process_time() - cpu0
    pixel_iterations = sum(n for (n, *_rest) in probe.counts.values())
    gt = [(m.depth, g) for m, g in zip(maps, probe.gt, strict=True) if g is not None]
    final = None
    if gt:
        valid = np.concatenate([g[g > 0] for _d, g in gt])
        est = np.concatenate([d[g > 0] for d, g in gt])
        final = 100 * float(np.count_nonzero(np.abs(est - valid) <= 0.01 * valid)) / valid.size
    rows = probe.rows()
    print(f"{'level':>5} {'pass':>4} {'iter':>4} {'changed %':>9} {'>1 % %':>7} {'within 1 %':>10} {'s':>6}")
    for r in rows:
        fmt = lambda v: "-" if v is None else f"{v:.2f}"  # noqa: E731
        print(f"{r['level']:>5} {r['pass_index']:>4} {r['iteration']:>4} {fmt(r['changed_pct']):>9} "
              f"{fmt(r['changed_1pct_pct']):>7} {fmt(r['within_1pct']):>10} {r['seconds']:6.2f}")
    print(f"total {total:.1f} s ({cpu:.1f} CPU s), {pixel_iterations / 1e6:.1f} M pixel-iterations, final within 1 % "
          f"{'-' if final is None else f'{final:.2f}'}")
    kernel = work.summary()
    print("kernels: " + ", ".join(f"{k} {v:.4g}" for k, v in kernel.items()))
    if fused is not None:
        print(f"fused F1 {fused['f1']} at {fused['tolerances']}, depth within 1 % {fused['depth_within_1pct']}")
    variant = "_".join([scene.name, args.schedule] + [f"{k}{v}" for k, v in sorted(overrides.items())])
    name = bench.results_path(__file__, variant)
    bench.write_result({"scene": args.scene, "size": list(views[0].image_gray.shape[::-1]), "views": len(views),
                        "options": {"schedule": args.schedule, **overrides},
                        "active_from_iteration": records.ACTIVE_FROM_ITERATION, "total_seconds": total,
                        "cpu_seconds": cpu, "kernels": kernel, "fused": fused,
                        "pixel_iterations": pixel_iterations, "final_within_1pct": final, "rows": rows},
                       args.json or name)
    print(f"wrote {args.json or name}")


if __name__ == "__main__":
    main()
