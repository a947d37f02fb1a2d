"""What a user of the tuning viewer waits for in chromium (software WebGL) under the point and triangle budgets.

    .venv/bin/python benchmarks/performance/bench_viewer_budget.py [--scene sample_scenes/small] [--run DIR]
                                                     [--tau 0.3] [--triangle-budget N]
                                                     [--out benchmarks/results/bench_viewer_budget.json]

Without ``--run`` the scene is run first as ``deepc run SCENE --pipeline fast --headless --out DIR`` (a temporary
folder) and meshed with ``deepc mesh DIR`` (Poisson) when the run has no ``mesh.ply``; neither is timed. Then, one
headless chromium page (``support/browser.py``) on ``deepc view DIR`` (``ViewerApp``, 127.0.0.1, a free port), each
measured once, wall clock in this process:

- ``open_ready_s``: from opening the session to the page showing the first exact cloud's metrics and what was sent
  (its budget note); the page is loaded while the viewer computes, as a user's would be;
- ``tau_preview_s`` / ``tau_exact_s``: from a change of the confidence threshold (to ``--tau``, a value not shown
  before) until the page shows the preview, then the exact result (noted in the page by a MutationObserver, so a
  preview shown briefly still counts; when the exact result comes first no preview shows and
  ``tau_preview_shown`` is false);
- ``mesh_shown_s``: from choosing Show "mesh" until the page says the (decimated) mesh was sent, and
  ``mesh_frame_s`` until a screenshot of the 3-D canvas after it (one frame rendered with the mesh).

The budgets are the viewer's defaults (``POINT_BUDGET``, ``TRIANGLE_BUDGET``; ``--triangle-budget`` sets the Mesh
folder's before Show); the counts sent are recorded with them. Issue 47's numbers before the budgets: on small,
a τ change took 7-22 s to show and showing the mesh about 60 s (not kept in a result file).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from support import bench
from support.browser import chromium, dismiss_software_webgl_notice

# The fast pipeline's run (without --run) uses the shipped network of the fast pipeline.
WEIGHTS = ("deepc_middle.pt",)

# Top-level keys of this script's result JSON and their types (support/schema.py); the harness adds its own
# (script, argv, git, dirty, environment, inputs).
SCHEMA = {"scene": str, "run_points": int, "point_budget": int, "sent_points": int, "open_ready_s": float,
          "tau_from": float, "tau_to": float, "tau_preview_shown": bool, "tau_preview_s?": float, "tau_exact_s": float,
          "tau_exact_points": int, "mesh_triangles": int, "triangle_budget": int, "mesh_sent_triangles": int,
          "mesh_shown_s": float, "mesh_frame_s": float, "load_average_1min": float, "cpus": int}

PAGE_TIMEOUT_MS = 300_000  # a wait on the page gives up after this (software WebGL on a loaded machine is slow)


def summary(result: dict) -> list[dict]:
    """The waits of one session: open, τ preview and exact result, mesh; with the counts sent."""
    return [{"scene": result["scene"], "points (sent)": f"{result['run_points']:,} ({result['sent_points']:,})",
             "open s": result["open_ready_s"], "τ preview s": result.get("tau_preview_s"),
             "τ exact s": result["tau_exact_s"], "mesh shown s": result["mesh_shown_s"],
             "mesh triangles (sent)": f"{result['mesh_triangles']:,} ({result['mesh_sent_triangles']:,})"}]


def _deepc(*args: str) -> None:
    """``deepc ARGS`` in a child process (its output discarded unless it fails)."""
    done = subprocess.run([sys.executable, "-m", "workbench.cli", *args], capture_output=True, text=True,
                          cwd=bench.REPO_ROOT)
    if done.returncode != 0:
        raise SystemExit(f"deepc {' '.join(args)} failed:\n{done.stdout[-2000:]}{done.stderr[-2000:]}")


def prepare_run(scene: Path, run: Path | None) -> Path:
    """The run folder to view: ``run``, else a fast headless run of ``scene``; meshed (Poisson) if not yet."""
    if run is None:
        run = Path(tempfile.mkdtemp(prefix="bench-viewer-budget-")) / scene.name
        _deepc("run", str(scene), "--pipeline", "fast", "--headless", "--out", str(run))
    if not (run / "mesh.ply").is_file():
        _deepc("mesh", str(run))
    return run


def _since(start: float) -> float:
    return round(time.perf_counter() - start, 3)


# In the page: a MutationObserver notes (performance.now(), ms) when the page's text first holds a watched text,
# and logs every change of what the metrics show ("preview", or the exact result's point count "75,047"), so a
# state shown briefly (a preview the exact result replaces at once) is never missed by polling.
WATCHER = r"""() => {
  window.__marks = {}; window.__watches = []; window.__log = []; let last = null;
  const check = () => {
    const text = document.body.textContent;
    for (const w of window.__watches) {
      if (window.__marks[w.name] === undefined && text.includes(w.text)) window.__marks[w.name] = performance.now();
    }
    const exact = text.match(/([\d,]+) points(?: \([^)]*\))? · exact/);
    const state = text.includes("exact result follows") ? "preview" : (exact ? exact[1] : null);
    if (state !== last) { last = state; window.__log.push([performance.now(), state]); }
  };
  new MutationObserver(check).observe(document.body, {subtree: true, childList: true, characterData: true});
}"""


def _watch(page, *watches: dict) -> float:
    """Start watching for ``watches`` ({name, text}); returns the page's clock now (ms)."""
    return page.evaluate("w => { window.__watches.push(...w); return performance.now(); }", list(watches))


def _seconds_to(page, name: str, start_ms: float) -> float:
    """Seconds from ``start_ms`` (page clock) until the watch ``name`` was met; waits for it (with a timeout)."""
    page.wait_for_function("n => window.__marks[n] !== undefined", arg=name, timeout=PAGE_TIMEOUT_MS)
    return round((page.evaluate("n => window.__marks[n]", name) - start_ms) / 1000, 3)


def measure(run: Path, tau: float, triangle_budget: int | None = None) -> dict:
    """One viewer session on ``run`` in one chromium page: the waits of :data:`SCHEMA` (``triangle_budget``: the
    Mesh folder's budget set before Show, None: the default)."""
    from workbench.viewer.app import POINT_BUDGET, ViewerApp
    from workbench.viewer.session import ViewerSession

    record: dict = {"point_budget": POINT_BUDGET}
    quiet = io.StringIO()
    with chromium(timeout_ms=PAGE_TIMEOUT_MS) as context:
        start = time.perf_counter()
        with contextlib.redirect_stdout(quiet):
            app = ViewerApp(ViewerSession.open(run), port=0)
        try:
            page = context.new_page()
            page.goto(f"http://127.0.0.1:{app.port}/")
            page.get_by_text("Connected").wait_for()
            page.get_by_text("· exact").first.wait_for()
            page.get_by_text(re.compile("whole cloud sent|cloud thinned")).first.wait_for()  # the budget note
            record["open_ready_s"] = _since(start)
            app.wait_idle(PAGE_TIMEOUT_MS / 1000)
            dismiss_software_webgl_notice(page)
            page.evaluate(WATCHER)
            record["run_points"] = len(app.cloud)
            record["sent_points"] = int(app.cloud_handle.points.shape[0])

            record["tau_from"] = float(app.fused_confidence_tau.value)
            record["tau_to"] = tau
            start_ms = _watch(page)
            app.fused_confidence_tau.value = tau  # as a browser's change arrives: runs the callbacks
            app.wait_idle(PAGE_TIMEOUT_MS / 1000)
            count = f"{len(app.cloud):,}"
            record["tau_exact_points"] = len(app.cloud)
            page.wait_for_function("n => window.__log.some(e => e[1] === n)", arg=count, timeout=PAGE_TIMEOUT_MS)
            log = [(t, state) for t, state in page.evaluate("window.__log") if t > start_ms]
            exact_ms = next(t for t, state in log if state == count)
            preview_ms = next((t for t, state in log if state == "preview" and t < exact_ms), None)
            # a preview that waited for the previous cloud to reach the page may find the exact result done: then
            # the exact result is the first answer and no preview shows
            record["tau_preview_shown"] = preview_ms is not None
            if preview_ms is not None:
                record["tau_preview_s"] = round((preview_ms - start_ms) / 1000, 3)
            record["tau_exact_s"] = round((exact_ms - start_ms) / 1000, 3)

            panel = app.mesh_panel
            if triangle_budget is not None:
                panel.triangle_budget.value = triangle_budget  # as a browser's change: nothing sent before Show
            page.get_by_text("Mesh", exact=True).first.dispatch_event("click")  # open the folder
            # "N triangles, M sent (decimated)" or "N triangles, all sent"
            start_ms = _watch(page, {"name": "mesh", "text": "triangles, "})
            start = time.perf_counter()
            panel.show.value = "mesh"
            record["mesh_shown_s"] = _seconds_to(page, "mesh", start_ms)
            page.locator("canvas").first.screenshot(timeout=PAGE_TIMEOUT_MS)
            record["mesh_frame_s"] = _since(start)
            record["mesh_triangles"] = len(panel.mesh)
            record["triangle_budget"] = panel.budget()
            record["mesh_sent_triangles"] = len(panel.sent.shown)
            page.close()
        finally:
            with contextlib.redirect_stdout(quiet), contextlib.redirect_stderr(quiet):
                app.stop()
    return record


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", type=Path, default=bench.REPO_ROOT / "sample_scenes" / "small",
                        help="scene to run when --run is not given (default: sample_scenes/small)")
    parser.add_argument("--run", type=Path, default=None,
                        help="an existing deepc run folder to view instead (meshed first if it has no mesh.ply)")
    parser.add_argument("--tau", type=float, default=0.3,
                        help="confidence threshold to change to (default 0.3; the fast run's own is 0.1)")
    parser.add_argument("--triangle-budget", type=int, default=None,
                        help="the Mesh folder's triangle budget for the mesh shown (default: the viewer's)")
    parser.add_argument("--out", type=Path, default=bench.results_path(__file__))
    args = parser.parse_args()
    run = prepare_run(args.scene, args.run)
    record = {"scene": args.scene.name if args.run is None else run.name,
              **measure(run, args.tau, args.triangle_budget),
              "load_average_1min": os.getloadavg()[0], "cpus": os.cpu_count()}
    bench.print_table(summary(record))
    print(f"wrote {bench.write_result(record, args.out)}")


if __name__ == "__main__":
    main()
