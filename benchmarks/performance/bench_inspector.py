"""Pixel inspector latency: from a click to a client holding the filled inspector, and a region re-run.

    .venv/bin/python benchmarks/performance/bench_inspector.py [--run OUT | --scene sample_scenes/fountain_p11
                                                   --size 192] [--pixels 4] [--out benchmarks/results/...]

A run folder of ``deepc run`` (with its pass history) is opened in the viewer with the view's depth map as the
map plane; a raw websocket client registers as a browser would, and each click is a ray from the view's camera
through a pixel, handed to the inspector's click handler (the plane turns it into that pixel). The time is taken
when the client receives the inspector's status line for that pixel (sent after the filled folder), and for a
region re-run the region's status line (sent after the before/after maps). The first click on a view
replays that view's PatchMatch from the history ("cold"); later clicks on the same view reuse the replay
("warm"); a pixel probed before answers from the viewer's cache ("again"), and so does its neighbour ("next"),
traced by the same probe (``viewer_inspector.PROBE_NEIGHBOURS``). Without ``--run`` a vanilla run
of ``--scene`` at ``--size`` px is made first with ``deepc run --headless``.
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import msgspec
import numpy as np
import websockets

from support import bench
from support.viewer_clients import CAMERA, SUBPROTOCOL, decode_frame, markdown_text
from workbench.viewer.app import ViewerApp
from workbench.viewer.session import ViewerSession

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"run": str, "scene": str, "size": str, "views": int, "summary": list, "clicks": list, "what": dict}



def click_ray(app: ViewerApp, view: int, x: int, y: int) -> SimpleNamespace:
    """The click event a browser sends for a ray from view ``view``'s camera through pixel (x, y)."""
    camera = app.session.scene.views[view].camera
    direction = camera.R.T @ (np.linalg.inv(camera.K_idx) @ np.array([x, y, 1.0]))
    return SimpleNamespace(ray_origin=tuple(camera.center), ray_direction=tuple(direction / np.linalg.norm(direction)))


async def measure(app: ViewerApp, jobs: list[tuple[str, int, int, int]]) -> list[dict]:
    inspector = app.inspector
    status_id, region_id = inspector.status._impl.uuid, inspector.region_status._impl.uuid
    results = []
    async with websockets.connect(f"ws://127.0.0.1:{app.port}", subprotocols=[SUBPROTOCOL], max_size=None) as ws:
        await ws.send(msgspec.msgpack.encode(CAMERA))

        async def wait_text(uuid: str, start: str, deadline: float) -> str:
            while time.perf_counter() < deadline:
                data = await asyncio.wait_for(ws.recv(), timeout=max(0.01, deadline - time.perf_counter()))
                if isinstance(data, str):
                    continue
                for message in decode_frame(data):
                    text = markdown_text(message, uuid)
                    if text is not None and text.startswith(start) and text.endswith(" s"):
                        return text
                    if text is not None and "cannot" in text:
                        raise RuntimeError(text)
            raise TimeoutError(f"no {start!r} from the viewer")

        async def drain(quiet: float = 1.0) -> None:
            try:
                while True:
                    await asyncio.wait_for(ws.recv(), timeout=quiet)
            except TimeoutError:
                pass

        await drain()
        for kind, view, x, y in jobs:
            inspector.wait_idle(600)
            if app._selected_view != view or str(inspector.plane_kind.value) == "off":
                app.select_view(view)  # the map plane follows the view: a click through (x, y) hits that pixel
                inspector.plane_kind.value = "depth"
            await drain(0.5)
            start = time.perf_counter()
            if kind == "region":
                inspector.rerun(view, (max(0, x - 32), max(0, y - 32), 64, 64))
                await wait_text(region_id, "box", start + 600)
            else:
                inspector._scene_clicked(click_ray(app, view, x, y))
                text = await wait_text(status_id, f"pixel ({x}, {y})", start + 600)
                assert "map plane" in text, text
            seconds = time.perf_counter() - start
            inspector.wait_idle(600)
            status = inspector.region_status.content if kind == "region" else inspector.status.content
            results.append({"kind": kind, "view": view, "x": x, "y": y, "seconds": round(seconds, 4),
                            "status": status})
            print(f"{kind:<7} view {view} ({x}, {y}): {seconds:.3f} s  · {status}", flush=True)
    return results


def summary(result: dict) -> list[dict]:
    """Median and largest time per kind of click, and of a region re-run."""
    return [{"scene": f"{result['scene']} {result['size']}", **row} for row in result["summary"]]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, help="a run folder of deepc run (with history/)")
    parser.add_argument("--scene", type=Path, default=bench.REPO_ROOT / "sample_scenes" / "fountain_p11")
    parser.add_argument("--size", type=int, default=192)
    parser.add_argument("--pixels", type=int, default=4, help="warm clicks per view")
    parser.add_argument("--out", type=Path, default=bench.results_path(__file__))
    args = parser.parse_args()

    run_dir = args.run
    if run_dir is None:
        run_dir = Path(tempfile.mkdtemp(prefix="bench-inspector-")) / "run"
        t = time.perf_counter()
        subprocess.run([sys.executable, "-m", "workbench.cli", "run", str(args.scene), "--out", str(run_dir),
                        "--max-image-size", str(args.size), "--headless"], check=True, stdout=subprocess.DEVNULL)
        print(f"deepc run of {args.scene.name} at {args.size} px in {time.perf_counter() - t:.1f} s")
    app = ViewerApp(ViewerSession.open(run_dir), port=0)
    app.wait_idle(600)
    scene = app.session.scene
    camera = scene.views[0].camera
    rng = np.random.default_rng(0)
    jobs: list[tuple[str, int, int, int]] = []
    for view in (0, len(scene.views) // 2):
        depth = app.session.data[view].depth
        ys, xs = np.nonzero(depth > 0)
        picks = rng.choice(len(xs), args.pixels + 1, replace=False)
        pixels = [(int(xs[i]), int(ys[i])) for i in picks]
        jobs += [("cold" if k == 0 else "warm", view, *p) for k, p in enumerate(pixels)]
        jobs.append(("again", view, *pixels[1]))
        jobs.append(("next", view, min(pixels[1][0] + 1, depth.shape[1] - 1), pixels[1][1]))
        jobs.append(("region", view, *pixels[1]))
    try:
        results = asyncio.run(measure(app, jobs))
    finally:
        app.stop()

    kinds = ("cold", "warm", "again", "next", "region")
    by_kind = {kind: [r["seconds"] for r in results if r["kind"] == kind] for kind in kinds}
    rows = [{"what": kind, "n": len(times), "median s": statistics.median(times), "max s": max(times)}
            for kind, times in by_kind.items() if times]
    bench.print_table(rows)
    record = {"run": str(run_dir), "scene": scene.name, "size": f"{camera.width}x{camera.height}",
              "views": len(scene.views), "summary": rows, "clicks": results,
              "what": {"cold": "click -> inspector filled, first probe of a view (replays the view)",
                       "warm": "click -> inspector filled, the view replayed before",
                       "again": "click on a pixel probed before (viewer cache)",
                       "next": "click on a neighbour of a pixel probed before (probed with it)",
                       "region": "re-run of a 64x64 box -> before/after maps shown"}}
    bench.write_result(record, args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
