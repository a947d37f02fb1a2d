"""What a PatchMatch pixel-iteration costs per level and pass kind in a whole `deepc run`, and how the whole-run
ETA (engine/run/eta.py) would have predicted the time left at every pass end.

    PYTHONPATH=. .venv/bin/python benchmarks/performance/eta_costs.py SCENE [--pipeline vanilla]
        [--max-image-size PX] [--json benchmarks/results/eta_costs.json]

Runs the pipeline as `deepc run SCENE --headless` does (defaults, compiled kernels loaded first, PatchMatch
checkpoint and pass history included) with an observer that records the wall and the CPU time (this process, all
threads) of every pass start, every red-black iteration of every view and the end of PatchMatch and of the run.
From that timeline:

- ``by_pass``: per pass its wall and CPU seconds from its start to the next pass's (views' contexts, initial costs,
  iterations, snapshots and checkpoints), the view-iterations it ran against its plan (passes end by convergence)
  and microseconds per planned pixel-iteration;
- ``weights``: per level and pass kind, the cost of a planned pixel-iteration relative to the finest level's
  photometric pass, from wall seconds (what engine/run/eta.py's ``PASS_WEIGHTS`` are made of) and from CPU
  seconds;
- ``replay``: the recorded events fed again into :class:`engine.run.eta.RunEta` on a clock that replays the
  recorded wall times, at the end of every pass: seconds left predicted and actual and the relative error, with
  every pixel-iteration alike (``unweighted``), with this run's wall weights (``this_runs_wall_weights``: in
  sample) and with the shipped ``PASS_WEIGHTS`` (``shipped``).
  ``benchmarks/reliability/first_try.py`` measures the ETA `deepc run` prints, out of sample.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

from engine.core.observer import ObserverList
from engine.run.checkpoint import CHECKPOINT_DIR, PatchMatchCheckpoint
from engine.run.eta import LATER_SHARE, PASS_WEIGHTS, PlannedPass, RunEta, pass_plan
from engine.run.memory import load_kernels
from engine.run.pass_history import HISTORY_DIR, PassHistory
from engine.run.per_view import SceneView
from engine.run.pipeline import run_pipeline
from engine.scene import load_scene
from support import bench
from workbench.cli.main import build_parser
from workbench.flags.run_options import run_options_from_args

# Top-level keys of this script's result JSON and their types (support/schema.py); the harness adds its own.
SCHEMA = {"scene": str, "size": list, "views": int, "pipeline": str, "run_seconds": float,
          "patchmatch_seconds": float, "by_pass": list, "weights": dict, "shipped_weights": dict, "replay": dict,
          "load_average": list}


def summary(result: dict) -> list[dict]:
    """Per pass: seconds, iterations ran of planned, cost per planned pixel-iteration and its weight, and the
    replayed ETA error at its end without and with the weights."""
    errors = {name: {r["pass"]: r["error"] for r in rows} for name, rows in result["replay"].items()}
    return [{"pass": p["pass"], "seconds": p["seconds"], "CPU s": p["cpu_seconds"],
             "iterations ran/planned": f"{p['ran']}/{p['planned']}",
             "CPU us per planned px-it": p["cpu_us_per_planned_pixel_iteration"],
             **{f"ETA error at its end, {name}": e.get(p["pass"]) for name, e in errors.items()}}
            for p in result["by_pass"]]


class Timeline:
    """An engine observer that keeps every stage and iteration event with the wall and the CPU time (this process,
    all its threads) it came at, in seconds since it was made."""

    def __init__(self) -> None:
        self.start, self.cpu_start = time.perf_counter(), time.process_time()
        self.events: list[tuple[float, float, str, dict[str, Any]]] = []

    def now(self) -> float:
        return time.perf_counter() - self.start

    def _add(self, kind: str, info: dict[str, Any]) -> None:
        self.events.append((self.now(), time.process_time() - self.cpu_start, kind, info))

    def on_stage(self, name: str, **info: Any) -> None:
        self._add("stage", {"name": name, **{k: v for k, v in info.items() if isinstance(v, (int, float, str))}})

    def on_iteration(self, event: Any) -> None:
        self._add("iteration", {"view": event.view, "level": event.level, "pass_index": event.pass_index,
                                "iteration": event.iteration, "pixels": int(event.depth.size),
                                "seconds": event.seconds})


class _Event:
    """An iteration event as RunEta reads it (``view``, ``iteration``, ``depth.size``)."""

    def __init__(self, info: dict[str, Any]):
        self.view, self.iteration = info["view"], info["iteration"]
        self.depth = type("Depth", (), {"size": info["pixels"]})()


def _name(level: int, pass_index: int) -> str:
    return f"level {level} {'geometric' if pass_index else 'photometric'} {pass_index}"


def replay(events: list, plan: list[PlannedPass], later_share: float, end: float) -> list[dict[str, Any]]:
    """The recorded events fed into a fresh RunEta on a replayed clock: its seconds left at the end of every pass
    (when the next pass starts, or PatchMatch ends) against the recorded time left."""
    clock = [0.0]
    eta = RunEta(plan, later_share, clock=lambda: clock[0])
    rows, current = [], None
    for t, _cpu, kind, info in events:
        clock[0] = t
        if kind == "stage" and info["name"] in ("patchmatch_pass", "patchmatch_done") and current is not None:
            predicted = eta.seconds_left()
            if predicted is not None:
                rows.append({"pass": current, "ended_at_s": round(t, 2), "eta_s": round(predicted, 1),
                             "actual_left_s": round(end - t, 1), "error": round(predicted / (end - t) - 1, 3)})
        if kind == "stage":
            eta.on_stage(info["name"], **{k: v for k, v in info.items() if k != "name"})
            if info["name"] == "patchmatch_pass":
                current = _name(info["level"], info["pass_index"])
        else:
            eta.on_iteration(_Event(info))
    return rows


def passes(events: list, plan: list[PlannedPass], pm_end: tuple[float, float]) -> list[dict[str, Any]]:
    """Per pass: its wall and CPU seconds (from its start to the next pass's), view-iterations ran and planned,
    pixel-iterations planned, and microseconds (wall and CPU) per planned pixel-iteration."""
    starts = [(t, cpu, info) for t, cpu, kind, info in events
              if kind == "stage" and info["name"] == "patchmatch_pass"]
    rows = []
    for k, (t, cpu, info) in enumerate(starts):
        t_end, cpu_end = (starts[k + 1][0], starts[k + 1][1]) if k + 1 < len(starts) else pm_end
        ran = sum(1 for s, _c, kind, i in events if kind == "iteration" and t <= s <= t_end
                  and (i["level"], i["pass_index"]) == (info["level"], info["pass_index"]))
        p = next(q for q in plan if (q.level, q.pass_index) == (info["level"], info["pass_index"]))
        rows.append({"pass": _name(p.level, p.pass_index), "level": p.level, "pass_index": p.pass_index,
                     "seconds": round(t_end - t, 2), "cpu_seconds": round(cpu_end - cpu, 2), "ran": ran,
                     "planned": p.iterations * sum(1 for x in p.view_pixels if x),
                     "pixel_iterations_planned": p.units,
                     "us_per_planned_pixel_iteration": round((t_end - t) / p.units * 1e6, 3),
                     "cpu_us_per_planned_pixel_iteration": round((cpu_end - cpu) / p.units * 1e6, 3)})
    return rows


def cost_weights(by_pass: list[dict[str, Any]], key: str) -> dict[str, float]:
    """Per level and pass kind: ``key`` (microseconds per planned pixel-iteration) summed over the kind's passes
    and divided by their pixel-iterations, relative to the finest level's photometric pass ("L<level>_<kind>")."""
    sums: dict[tuple[int, str], list[float]] = {}
    for r in by_pass:
        kind = "geometric" if r["pass_index"] else "photometric"
        acc = sums.setdefault((r["level"], kind), [0.0, 0.0])
        acc[0] += r[key] * r["pixel_iterations_planned"]
        acc[1] += r["pixel_iterations_planned"]
    per = {lk: s / n for lk, (s, n) in sums.items()}
    ref = per[(0, "photometric")]
    return {f"L{level}_{kind}": round(v / ref, 3) for (level, kind), v in sorted(per.items())}


def table(weights: dict[str, float]) -> dict[tuple[int, str], float]:
    """``{"L1_geometric": w}`` as engine/run/eta.py's ``{(1, "geometric"): w}``."""
    return {(int(k[1:].split("_")[0]), k.split("_", 1)[1]): v for k, v in weights.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("--pipeline", default="vanilla")
    ap.add_argument("--max-image-size", type=int, default=None)
    ap.add_argument("--json", default=bench.results_path(__file__))
    ap.add_argument("--save-timeline", metavar="FILE.json", help="also write the raw recorded events there")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="eta-costs-"))
    try:
        out = tmp / "run"
        cli = ["run", args.scene, "--out", str(out), "--headless", "--pipeline", args.pipeline]
        if args.max_image_size is not None:
            cli += ["--max-image-size", str(args.max_image_size)]
        run_args = build_parser().parse_args(cli)
        scene_options, options, _ = run_options_from_args(run_args)
        os.environ.setdefault("DEEPC_CACHE", str(tmp / "cache"))
        scene = load_scene(args.scene, scene_options)
        views = [SceneView(scene, i) for i in range(len(scene.views))]
        later = LATER_SHARE.get(options.pipeline, 0.1)
        load_kernels()  # as deepc run does before PatchMatch: compiled kernels, resident
        load = [(0.0, os.getloadavg()[0])]
        timeline = Timeline()
        run_pipeline(scene, out, options, observer=ObserverList([timeline]),
                     checkpoint=PatchMatchCheckpoint(out / CHECKPOINT_DIR), history=PassHistory(out / HISTORY_DIR))
        end = timeline.now()
        load.append((round(end, 1), os.getloadavg()[0]))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    events = timeline.events
    if args.save_timeline:
        Path(args.save_timeline).write_text(json.dumps({"events": events, "end": end}))
    pm_end = next((t, cpu) for t, cpu, kind, info in events
                  if kind == "stage" and info["name"] == "patchmatch_done")
    pm_start = next(t for t, _c, kind, info in events if kind == "stage" and info["name"] == "patchmatch_pass")
    plan = pass_plan(views, options.patchmatch, weights={})
    by_pass = passes(events, plan, pm_end)
    weights = {"cpu": cost_weights(by_pass, "cpu_us_per_planned_pixel_iteration"),
               "wall": cost_weights(by_pass, "us_per_planned_pixel_iteration")}
    plans = {"unweighted": plan, "this_runs_wall_weights": pass_plan(views, options.patchmatch, table(weights["wall"])),
             "shipped": pass_plan(views, options.patchmatch)}
    result = {"scene": Path(args.scene).name, "size": [scene.views[0].camera.width, scene.views[0].camera.height],
              "views": len(scene.views), "pipeline": options.pipeline, "run_seconds": round(end - pm_start, 2),
              "patchmatch_seconds": round(pm_end[0] - pm_start, 2), "by_pass": by_pass, "weights": weights,
              "shipped_weights": {f"L{level}_{kind}": w for (level, kind), w in PASS_WEIGHTS.items()},
              "replay": {name: replay(events, p, later, end) for name, p in plans.items()},
              "load_average": load}
    bench.print_table(summary(result), title=f"eta costs: {result['scene']}")
    bench.write_result(result, args.json)


if __name__ == "__main__":
    main()
