"""Cost of scoring confidence while PatchMatch runs (``--stream-confidence-every K``), and the demo recording's size.

    .venv/bin/python benchmarks/performance/bench_stream_confidence.py [--scene sample_scenes/small] [--size 0]
        [--schedule acmm] [--every 3 1] [--repeats 2] [--out benchmarks/results/bench_stream_confidence.json]

fountain_p11 at 768 px (the scene beside the checkout, ../shared/data):

    .venv/bin/python benchmarks/performance/bench_stream_confidence.py --scene ../shared/data/fountain_p11 \\
        --size 768 --every 3 --repeats 2 --out benchmarks/results/bench_stream_confidence_fountain_p11_768.json

Per repeat, alternating: PatchMatch headless (no observer), with the rerun stream writing an .rrd (the demo's
stream, ``scripts/demo.sh``: default thinning, no confidence) and, for each K of ``--every``, with the stream
and :class:`workbench.rerun.confidence.LiveConfidence` scoring every K-th iteration of each view. Reports the
best wall times, the overhead of each against the headless run and against the stream alone, the seconds spent
scoring (measured inside the run, so less sensitive to other load than the wall-time ratio) as a share of the
headless engine time (target: at most 25 % at the default K), and the size of each recording (the demo's
recording is the one of the default K on sample_scenes/small; target: under 200 MB).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from engine.patchmatch import PatchMatchOptions, run_patchmatch
from engine.run.pipeline import PipelineOptions, patchmatch_views
from engine.scene import SceneOptions, load_scene
from support import bench
from workbench.rerun.options import DEFAULT_CONFIDENCE_EVERY, StreamOptions
from workbench.rerun.run_recording import open_run_recording

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"scene": str, "views": int, "size": list, "schedule": str, "modes": dict, "targets": dict}
# The shipped networks this script runs by default: their sha256 is recorded with every result.
WEIGHTS = ("deepc_middle.pt",)



def timed_run(scene, options: PipelineOptions, record: Path | None, every: int | None) -> dict:
    """One PatchMatch run: headless (``record`` None), or streaming to ``record`` with confidence every ``every``-th
    iteration (None: no confidence). Wall seconds, scoring seconds, scored view-iterations, recording bytes."""
    views = patchmatch_views(scene)
    recording = confidence = None
    if record is not None:
        recording = open_run_recording(str(record), scene, options, StreamOptions(confidence_every=every or 0))
        confidence = recording.stream.companions[0] if recording.stream.companions else None
    start = time.perf_counter()
    run_patchmatch(views, options.patchmatch, observer=recording.stream if recording else None)
    if recording is not None:
        recording.finish()
    seconds = time.perf_counter() - start
    return {"s": seconds, "scoring_s": confidence.seconds if confidence else 0.0,
            "scored": confidence.computed if confidence else 0, "rrd_bytes": record.stat().st_size if record else 0}


def summary(result: dict) -> list[dict]:
    """Best wall times, overheads, scoring share and recording size per mode."""
    return [{"scene": result["scene"], "mode": mode, "best s": r["best_s"], "overhead vs headless %":
             r["overhead_pct"], "scoring share %": r.get("scoring_share_pct"), "recording MB": r["rrd_mb"]}
            for mode, r in result["modes"].items()]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", type=Path, default=bench.REPO_ROOT / "sample_scenes" / "small")
    parser.add_argument("--size", type=int, default=0, help="--max-image-size (0 = the scene's)")
    parser.add_argument("--schedule", default="acmm", help="PatchMatch schedule (the demo's: acmm)")
    parser.add_argument("--every", type=int, nargs="+", default=[DEFAULT_CONFIDENCE_EVERY, 1])
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--out", type=Path, default=bench.results_path(__file__))
    args = parser.parse_args()

    scene = load_scene(args.scene, SceneOptions(max_image_size=args.size))
    options = PipelineOptions(patchmatch=PatchMatchOptions(schedule=args.schedule)).validate()
    warm = PipelineOptions(patchmatch=PatchMatchOptions(iterations=1, levels=1, geom_passes=0))
    with tempfile.TemporaryDirectory() as tmp:
        timed_run(scene, warm, Path(tmp) / "warm.rrd", 1)  # kernels, torch and its first inference
        modes = {"headless": None, "stream": None, **{f"stream+confidence K={k}": k for k in args.every}}
        runs: dict[str, list[dict]] = {mode: [] for mode in modes}
        for r in range(args.repeats):
            for mode, every in modes.items():
                record = None if mode == "headless" else Path(tmp) / f"{r}_{len(runs[mode])}_{every}.rrd"
                runs[mode].append(timed_run(scene, options, record, every))
                print(f"repeat {r} {mode:<24} {runs[mode][-1]['s']:8.1f} s", flush=True)
    headless = min(x["s"] for x in runs["headless"])
    stream = min(x["s"] for x in runs["stream"])
    result_modes = {}
    for mode, every in modes.items():
        best = min(runs[mode], key=lambda x: x["s"])
        entry = {"every": every, "s": [x["s"] for x in runs[mode]], "best_s": best["s"],
                 "overhead_pct": 100.0 * (best["s"] / headless - 1.0),
                 "overhead_vs_stream_pct": 100.0 * (best["s"] / stream - 1.0), "rrd_mb": best["rrd_bytes"] / 1e6}
        if every:
            shares = [100.0 * x["scoring_s"] / (x["s"] - x["scoring_s"]) for x in runs[mode]]
            entry.update(scoring_s=[x["scoring_s"] for x in runs[mode]], scored_view_iterations=best["scored"],
                         scoring_share_pct=min(shares), scoring_share_pct_all=shares)
        result_modes[mode] = entry
    result = {"scene": scene.name, "views": len(scene.views),
              "size": [scene.views[0].camera.width, scene.views[0].camera.height], "schedule": args.schedule,
              "modes": result_modes, "targets": {"scoring_share_pct": 25.0, "rrd_mb_demo": 200}}
    print(f"{scene.name}: {len(scene.views)} views {result['size'][0]}x{result['size'][1]}, schedule {args.schedule}")
    print(f"{'mode':<26} {'best s':>8} {'vs headless':>12} {'vs stream':>10} {'scoring':>8} {'rrd MB':>8}")
    for mode, e in result_modes.items():
        share = f"{e['scoring_share_pct']:.1f} %" if "scoring_share_pct" in e else "-"
        print(f"{mode:<26} {e['best_s']:>8.1f} {e['overhead_pct']:>10.1f} % {e['overhead_vs_stream_pct']:>8.1f} % "
              f"{share:>8} {e['rrd_mb']:>8.1f}")
    bench.write_result(result, args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
