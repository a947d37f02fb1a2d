"""What a user of rerun's web viewer waits for (chromium, software WebGL): a replay's last iteration, a live run.

    .venv/bin/python benchmarks/performance/bench_replay_load.py [--scene sample_scenes/small] [--rrd FILE]
        [--only replay|live] [--settle 15] [--live-flush-tick S] [--out benchmarks/results/bench_replay_load.json]

Issue 47's targets: ``deepc replay`` of the demo's recording shows the last iteration's maps within 20 s, and the
live stream is at most 5 s behind the run. Both are measured in one headless chromium (``support/browser.py``,
SwiftShader WebGL, a 1280×800 page, ``&renderer=webgl``) by screenshots of one panel, the depth of the scene's
last view (``NNN · depth (m)`` of the ``iterations`` layout, found with ``support/rerun_panels.py``), taken one
after the other (about every 0.5 s when screenshots are quick, slower when the page is busy). A panel's final
state is its last screenshot once it has not changed for ``--settle`` seconds (every wait bounded); it was reached
when the first screenshot from which every later one matches the final state returned (``final_at_s``;
``support.rerun_panels.settled_from``: at most 0.2 % of its pixels differ by more than 8 levels), so a state shown
briefly and replaced does not count; the screenshot before it, which did not match, returned at ``final_after_s``:
the state came between the two (a screenshot waits for the page, up to ~12 s while it ingests data). The final
state must show a depth map (``map_problem``: mostly turbo colours, not one flat colour) and the recording's own
last depth map of that view, coloured as rerun colours it (``final_matches_last``: nearer to it than to the view's
first logged map): until it does, the wait goes on (a page busy ingesting returns the same picture for a while).

- ``live``: the demo's run (``scripts/demo.sh``: ``deepc run sample_scenes/small --record FILE --schedule acmm``,
  its options parsed by ``deepc``'s own parser, PatchMatch, fusion and the recording as ``deepc run`` makes them,
  streamed to a web viewer started as ``deepc run`` starts it without a display, ``live_viewer(web=True)``) in a
  child process, with the page already open on the viewer. The run's layout follows the newest data (as every live
  layout does); for this benchmark it shows the last view (its maps are logged last in each pass). The child notes
  the wall time of every logged iteration. ``behind_s``: from the run logging that view's last depth map to the
  page's panel reaching its final state: how far behind the run the page was at the end (the target: ≤ 5 s).
  ``behind_run_end_s`` counts from the end of the run (fusion included) instead. The stream flushes every
  ``LIVE_FLUSH_TICK_S`` (``workbench/rerun/recording.py``) or ``--live-flush-tick`` seconds; the finished file is
  compacted as ``deepc run`` compacts it, and ``recording_chunks`` counts its chunks.
- ``replay``: the recording the live run wrote (the demo's; or ``--rrd``), served as ``deepc replay --web`` serves
  it (``WebViewer``, the same layout files) except that the layout's time panel follows the newest data instead
  of opening paused at the start (replay opens paused by design; a user would press the end of the time line):
  the benchmark swaps ``LAYOUTS["iterations"]`` for one with ``Contents.live`` set while the files are written.
  ``total_s``: from starting the viewer (reading the recording, writing the layout and notes, starting the
  server) to the panel showing the last iteration's depth map (the target: ≤ 20 s); ``page_s`` counts from
  opening the page.

Every timed wait has a timeout; the viewers, the child run and chromium are stopped in ``finally`` blocks. The
load average is recorded before and after: time it on a quiet machine.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from PIL import Image

from support import bench
from support.browser import chromium, rerun_crashed
from support.rerun_panels import find_panel, following, map_problem, panels_match, settled_from

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?" may be
# absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"scene": str, "recording_mb": float, "recording_chunks": int, "live_flush_tick_s": float, "replay?": dict,
          "live?": dict, "targets": dict,
          "load_average_before": list, "load_average_after": list, "load_average_1min": float, "cpus": int}

TARGETS = {"replay_s": 20.0, "live_behind_s": 5.0}  # issue 47
WIDTH, HEIGHT = 1280, 800
SHOT_EVERY_S = 0.5  # the wait between screenshots (each takes what the page needs on top)
PAGE_TIMEOUT_MS = 120_000  # one screenshot, the canvas appearing
REPLAY_TIMEOUT_S = 300.0  # the replay's panel settling, at most
RUN_TIMEOUT_S = 900.0  # the live run, at most


def summary(result: dict) -> list[dict]:
    """The replay's wait for the last iteration and how far the live page was behind the run, against targets; "wait s
    (from)": the screenshot before showed something else then (the wait lies between the two)."""
    rows = []
    replay, live = result.get("replay"), result.get("live")
    if replay:
        rows.append({"case": "replay", "recording MB": result["recording_mb"],
                     "chunks": result["recording_chunks"],
                     "wait s (from)": replay.get("final_after_s"), "wait s": replay["total_s"],
                     "target s": result["targets"]["replay_s"],
                     "met": replay["total_s"] <= TARGETS["replay_s"] and replay["final_matches_last"],
                     "server s": replay["server_s"], "shots": replay["shots"],
                     "shot interval s": replay["shot_interval_s"], "shows last": replay["final_matches_last"]})
    if live:
        rows.append({"case": f"live (behind run, flush {result['live_flush_tick_s']} s)",
                     "recording MB": result["recording_mb"],
                     "wait s (from)": live["final_after_s"] - live["last_depth_logged_s"] if "final_after_s" in live
                     else None, "wait s": live["behind_s"],
                     "target s": result["targets"]["live_behind_s"],
                     "met": live["behind_s"] <= TARGETS["live_behind_s"] and live["final_matches_last"],
                     "run s": live["run_s"],
                     "shots": live["shots"], "shot interval s": live["shot_interval_s"],
                     "shows last": live["final_matches_last"]})
    return rows


# ---- the live run (a child process) -------------------------------------------------------------------------

def run_args(scene: Path, out: Path, rrd: Path) -> list[str]:
    """``deepc run``'s arguments as ``scripts/demo.sh`` gives them."""
    return ["run", str(scene), "--out", str(out), "--record", str(rrd), "--schedule", "acmm"]


def child_run(scene: Path, out: Path, rrd: Path, live_url: str | None, times: Path, flush_tick: float) -> None:
    """The demo's run, streamed to ``live_url`` (when given; else recorded only, counter and confidence scored every
    third iteration as live) and recorded to ``rrd``, the live stream flushed every ``flush_tick`` s; writes the wall
    times of its logged iterations to ``times``."""
    from engine.run.pipeline import run_pipeline
    from engine.scene import load_scene
    from layouts import DEFAULT, LAYOUTS
    from workbench.cli.main import build_parser
    from workbench.flags.run_options import run_options_from_args
    from workbench.rerun import recording as recording_module
    from workbench.rerun.options import DEFAULT_CONFIDENCE_EVERY
    from workbench.rerun.run_recording import open_run_recording

    args = build_parser().parse_args(run_args(scene, out, rrd))
    scene_options, options, stream_options = run_options_from_args(args)
    if live_url is None:
        stream_options = stream_options.replace(confidence_every=DEFAULT_CONFIDENCE_EVERY)
    loaded = load_scene(args.scene, scene_options)
    recording_module.LIVE_FLUSH_TICK_S = flush_tick
    layout = LAYOUTS[DEFAULT]
    LAYOUTS[DEFAULT] = lambda contents, _view: layout(contents, contents.views[-1])  # the last view's panels
    try:
        recording = open_run_recording(str(rrd), loaded, options, stream_options, live_url)
    finally:
        LAYOUTS[DEFAULT] = layout
    logged: list[tuple[float, int]] = []
    log_maps = recording.stream._log_maps

    def noted(event, *rest, **kw):
        log_maps(event, *rest, **kw)
        logged.append((time.time(), event.view))

    recording.stream._log_maps = noted
    start = time.time()
    with contextlib.redirect_stdout(io.StringIO()):
        run_pipeline(loaded, out, options, observer=recording.stream)
    recording.finish()
    end = time.time()
    times.write_text(json.dumps({"start": start, "end": end, "logged": logged, "views": len(loaded.views),
                                 "plan": [recording.stream.options.max_size, recording.stream.options.every]}))


# ---- watching a panel ---------------------------------------------------------------------------------------

@dataclasses.dataclass
class Watch:
    """Screenshots of one panel: (wall time the screenshot returned, the panel body's pixels or None)."""

    times: list[float] = dataclasses.field(default_factory=list)
    panels: list[np.ndarray | None] = dataclasses.field(default_factory=list)
    last_change: float = 0.0

    def shoot(self, page, blueprint, title: str) -> None:
        png = page.screenshot(timeout=PAGE_TIMEOUT_MS)
        now = time.time()
        shot = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
        try:
            panel = find_panel(shot, blueprint, title).body().pixels(shot).copy()
        except AssertionError:  # the layout is not on the page yet
            panel = None
        if not self.panels or not panels_match(panel, self.panels[-1]):
            self.last_change = now
            print(f"  {time.strftime('%H:%M:%S')} shot {len(self.panels)}: the panel "
                  f"{'is not on the page' if panel is None else 'changed'}", file=sys.stderr, flush=True)
        self.times.append(now)
        self.panels.append(panel)
        self.full = shot

    def settled(self) -> tuple[float, int]:
        index = settled_from(self.panels)
        return self.times[index], index

    def record(self, origin: float, last: tuple, first: tuple) -> dict:
        """What the shots tell, times from ``origin``; ``last`` and ``first``: the view's last and first logged depth
        maps with their colour range (:func:`depth_maps`)."""
        when, index = self.settled()
        final = self.panels[-1]
        intervals = np.diff(self.times)
        out = {"shots": len(self.times), "settled_index": index,
               "shot_interval_s": round(float(statistics.median(intervals)), 3) if len(intervals) else 0.0,
               "shot_interval_max_s": round(float(intervals.max()), 3) if len(intervals) else 0.0,
               "changes": int(sum(not panels_match(a, b) for a, b in zip(self.panels, self.panels[1:], strict=False))),
               "final_at_s": round(when - origin, 3),
               # the screenshot before showed something else: the final state came between the two
               "final_after_s": round(self.times[max(index - 1, 0)] - origin, 3),
               "final_problem": "panel not found" if final is None else map_problem(final, "turbo")}
        out["final_matches_last"], out["final_vs_maps"] = compare_with_maps(final, last, first)
        return out


def wait_settled(page, watch: Watch, blueprint, title: str, settle_s: float, deadline: float,
                 running=lambda: False, final=lambda panel: True) -> None:
    """Screenshots until the panel has not changed for ``settle_s``, nor since ``running()`` turned false, and
    ``final(panel)`` holds, or ``deadline`` (then a RuntimeError). A page busy ingesting data can return the same
    picture for longer than ``settle_s``: ``final`` tells that state from the last one."""
    stopped = None
    while True:
        watch.shoot(page, blueprint, title)
        if rerun_crashed(page):
            raise RuntimeError("the rerun web viewer crashed")
        now = time.time()
        if stopped is None and not running():
            stopped = now
        quiet = now - max(watch.last_change, stopped or now)
        if stopped is not None and watch.panels[-1] is not None and quiet >= settle_s and final(watch.panels[-1]):
            return
        if now > deadline:
            saved = Path(tempfile.gettempdir()) / "bench_replay_load_unsettled.png"
            Image.fromarray(watch.full).save(saved)
            raise RuntimeError(f"the panel {title!r} did not settle in time (last change "
                               f"{now - watch.last_change:.0f} s ago, {len(watch.panels)} screenshots; the last: "
                               f"{saved})")
        time.sleep(SHOT_EVERY_S)


# ---- the recording's own maps, coloured as rerun colours them -----------------------------------------------

def depth_maps(rrd: Path, view: str) -> tuple[tuple, tuple]:
    """The first and last logged depth maps of ``view`` in the recording, each (steps, colour range in steps)."""
    from rerun.chunk import RrdReader

    table = (RrdReader(str(rrd)).stream().collect()
             .reader(index="view_iteration", contents=f"/maps/{view}/depth").to_arrow_table())
    columns = {c.rsplit(":", 1)[-1]: c for c in table.column_names if ":" in c}
    rows = [i for i, cell in enumerate(table[columns["blob"]].to_pylist()) if cell]

    def decode(row: int) -> tuple:
        steps = np.asarray(Image.open(io.BytesIO(bytes(table[columns["blob"]][row].as_py()[0]))), np.float64)
        lo, hi = table[columns["depth_range"]][row].as_py()[0]
        return steps, (float(lo), float(hi))

    return decode(rows[0]), decode(rows[-1])


def coloured(steps: np.ndarray, depth_range: tuple[float, float]) -> np.ndarray:
    """(H, W, 3) turbo colours of a depth map over ``depth_range`` (steps), NaN where no depth."""
    from matplotlib import colormaps

    lo, hi = depth_range
    rgb = colormaps["turbo"](np.clip((steps - lo) / max(hi - lo, 1e-9), 0, 1))[..., :3] * 255
    rgb[steps <= 0] = np.nan
    return rgb


def compare_with_maps(panel: np.ndarray | None, last: tuple, first: tuple) -> tuple[bool, dict]:
    """Whether the panel's picture (its non-white box, brought to the map's size) is nearer to the last logged map
    than to the first, with both mean colour distances."""
    if panel is None:
        return False, {}
    lit = ~np.all(panel >= 250, axis=-1)
    ys, xs = np.nonzero(lit)
    if not len(ys):
        return False, {}
    picture = Image.fromarray(panel[ys.min():ys.max() + 1, xs.min():xs.max() + 1])
    distances = {}
    for name, (steps, depth_range) in {"last": last, "first": first}.items():
        target = coloured(steps, depth_range)
        shown = np.asarray(picture.resize((target.shape[1], target.shape[0]), Image.BOX), np.float64)
        valid = ~np.isnan(target[..., 0])
        distances[name] = round(float(np.abs(shown - target)[valid].mean()), 2)
    return distances["last"] < distances["first"], distances


def chunks(rrd: Path) -> int:
    """How many chunks the recording holds (the web viewer ingests about one a frame)."""
    from rerun.chunk import RrdReader

    return len(RrdReader(str(rrd)).stream().to_chunks())


# ---- the two cases --------------------------------------------------------------------------------------------

def measure_replay(context, rrd: Path, settle_s: float) -> dict:
    from layouts import LAYOUTS, MAP_LABELS, view_label
    from workbench.rerun.replay import WebViewer, recording_contents

    contents = recording_contents(rrd).contents
    view = contents.views[-1]
    maps = depth_maps(rrd, view)
    blueprint = LAYOUTS["iterations"](dataclasses.replace(contents, live=True), view)
    title = f"{view_label(view)} · {MAP_LABELS['depth']}"
    start = time.time()
    with following("iterations"):
        viewer = WebViewer(rrd, layout="iterations", view=view)
    try:
        server = time.time()
        page = context.new_page()
        try:
            opened = time.time()
            page.goto(viewer.url + "&renderer=webgl")
            page.wait_for_selector("canvas", state="attached", timeout=PAGE_TIMEOUT_MS)
            watch = Watch()
            wait_settled(page, watch, blueprint, title, settle_s, start + REPLAY_TIMEOUT_S,
                         final=lambda panel: compare_with_maps(panel, maps[1], maps[0])[0])
            record = watch.record(start, maps[1], maps[0])
            record.update(server_s=round(server - start, 3), total_s=record["final_at_s"],
                          page_s=round(watch.settled()[0] - opened, 3), panel=title)
            Image.fromarray(watch.full).save(Path(tempfile.gettempdir()) / "bench_replay_load_replay.png")
            return record
        finally:
            page.close()
    finally:
        viewer.stop()


def measure_live(context, scene: Path, folder: Path, settle_s: float, flush_tick: float) -> tuple[dict, Path]:
    from engine.scene import load_scene
    from layouts import LAYOUTS, MAP_LABELS, view_label
    from workbench.cli.main import build_parser
    from workbench.flags.run_options import run_options_from_args
    from workbench.rerun.replay import live_viewer
    from workbench.rerun.run_recording import expected_contents, recording_plan

    rrd, times = folder / "recording.rrd", folder / "times.json"
    args = build_parser().parse_args(run_args(scene, folder / "out", rrd))
    scene_options, options, stream_options = run_options_from_args(args)
    loaded = load_scene(args.scene, scene_options)
    contents = expected_contents(loaded, options, recording_plan(loaded, options, stream_options),
                                 live_confidence=stream_options.confidence_k(live=True) > 0)
    contents.live = True
    view = contents.views[-1]
    blueprint = LAYOUTS["iterations"](contents, view)
    title = f"{view_label(view)} · {MAP_LABELS['depth']}"
    viewer = live_viewer(web=True)
    child = None
    try:
        page = context.new_page()
        try:
            page.goto(viewer.url + "&renderer=webgl")
            page.wait_for_selector("canvas", state="attached", timeout=PAGE_TIMEOUT_MS)
            page.wait_for_timeout(2000)
            log = (folder / "child.log").open("w")
            child = subprocess.Popen([sys.executable, __file__, "--child", str(scene), str(folder / "out"), str(rrd),
                                      viewer.grpc_url, str(times), str(flush_tick)], stdout=log,
                                     stderr=subprocess.STDOUT, cwd=bench.REPO_ROOT, start_new_session=True,
                                     env={**os.environ, "PYTHONPATH": str(bench.REPO_ROOT)})
            watch = Watch()
            maps: list = []  # the recording's first and last depth maps of the view, once the run has written it

            def final(panel) -> bool:
                if child.returncode != 0:
                    raise RuntimeError(f"the live run failed: {(folder / 'child.log').read_text()[-2000:]}")
                maps[:] = maps or depth_maps(rrd, view)
                return compare_with_maps(panel, maps[1], maps[0])[0]

            wait_settled(page, watch, blueprint, title, settle_s, time.time() + RUN_TIMEOUT_S,
                         running=lambda: child.poll() is None, final=final)
            run = json.loads(times.read_text())
            record = watch.record(run["start"], maps[1], maps[0])
            shown = [t for t, v in run["logged"] if v == len(loaded.views) - 1]
            final_at = watch.settled()[0]
            record.update(run_s=round(run["end"] - run["start"], 3),
                          last_depth_logged_s=round(shown[-1] - run["start"], 3),
                          last_map_logged_s=round(max(t for t, _ in run["logged"]) - run["start"], 3),
                          behind_s=round(final_at - shown[-1], 3), behind_run_end_s=round(final_at - run["end"], 3),
                          logged_iterations=len(run["logged"]), map_size=run["plan"][0], every=run["plan"][1],
                          panel=title)
            Image.fromarray(watch.full).save(Path(tempfile.gettempdir()) / "bench_replay_load_live.png")
            return record, rrd
        finally:
            page.close()
    finally:
        if child is not None and child.poll() is None:
            os.killpg(child.pid, signal.SIGTERM)
            child.wait(timeout=30)
        viewer.stop()


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--child":  # the live run, started by measure_live
        scene, out, rrd, url, times, tick = sys.argv[2:8]
        child_run(Path(scene), Path(out), Path(rrd), url or None, Path(times), float(tick))
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", type=Path, default=Path("sample_scenes/small"),
                        help="the scene of the live run (default: the demo's, sample_scenes/small)")
    parser.add_argument("--rrd", type=Path, default=None,
                        help="replay this recording instead of the one the live run writes")
    parser.add_argument("--only", choices=("replay", "live"), default=None, help="measure one case only")
    parser.add_argument("--settle", type=float, default=15.0,
                        help="seconds without a change that make a panel's state final (default 15)")
    parser.add_argument("--live-flush-tick", type=float, default=None,
                        help="seconds the live stream gathers rows before sending them (default: the recording's "
                             "LIVE_FLUSH_TICK_S; rerun's own default is 0.2)")
    parser.add_argument("--out", type=Path, default=bench.results_path(__file__))
    args = parser.parse_args()
    from workbench.rerun.recording import LIVE_FLUSH_TICK_S

    tick = LIVE_FLUSH_TICK_S if args.live_flush_tick is None else args.live_flush_tick
    before = [round(v, 2) for v in os.getloadavg()]
    record: dict = {"scene": str(args.scene), "targets": dict(TARGETS), "live_flush_tick_s": tick}
    with tempfile.TemporaryDirectory(prefix="bench-replay-load-") as tmp, \
            chromium(WIDTH, HEIGHT, timeout_ms=PAGE_TIMEOUT_MS) as context:
        rrd = args.rrd
        if args.only != "replay":
            record["live"], made = measure_live(context, args.scene, Path(tmp), args.settle, tick)
            rrd = rrd or made
        if rrd is None:  # replay only: the demo's recording, made without a viewer
            rrd = Path(tmp) / "recording.rrd"
            child_run(args.scene, Path(tmp) / "out", rrd, None, Path(tmp) / "times.json", tick)
        record["recording_mb"] = round(rrd.stat().st_size / 1e6, 3)
        record["recording_chunks"] = chunks(rrd)
        if args.only != "live":
            record["replay"] = measure_replay(context, rrd, args.settle)
    record.update(load_average_before=before, load_average_after=[round(v, 2) for v in os.getloadavg()],
                  load_average_1min=before[0], cpus=os.cpu_count())
    bench.print_table(summary(record))
    print(f"wrote {bench.write_result(record, args.out)}")


if __name__ == "__main__":
    main()
