"""Overhead of the live 3-D viewer: the same PatchMatch headless and with the live viewer and one browser-like client.

    .venv/bin/python benchmarks/performance/bench_viewer_live.py [--scene sample_scenes/small] [--size 0]
        [--iterations 2] [--repeats 3] [--out benchmarks/results/bench_viewer_live.json]

fountain_p11 at 768 px: ``--scene ../shared/data/fountain_p11 --size 768 --out
benchmarks/results/bench_viewer_live_fountain768.json``.

Each repeat runs PatchMatch (the default levels and passes, ``--iterations`` per pass) once headless (no
observer: the engine builds no events) and once observed by a :class:`workbench.viewer.live.LiveViewer`
with one websocket client in its own process taking every frame, as a browser tab would; the order alternates
between repeats so that a drift of the shared machine's load falls on both. Reported: the engine seconds of
every run, the overhead as the ratio of the medians (and of the best times), the CPU seconds of the viewer's
threads (its worker, viser's event loop and pool) against the engine's (main thread and numba's workers) in
the same runs, which a loaded machine disturbs far less than wall times, the clouds pushed and the bytes the
client received. The server's start (cameras drawn) is timed apart: it happens once per run.
"""

from __future__ import annotations

import argparse
import asyncio
import multiprocessing
import os
import statistics
import threading
import time
from pathlib import Path

from engine.patchmatch import PatchMatchOptions, run_patchmatch
from engine.run.pipeline import PipelineOptions, patchmatch_views
from engine.scene import SceneOptions, load_scene
from support import bench

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"scene": str, "views": int, "size": list, "iterations_per_pass": int, "headless_s": list, "live_s": list,
          "overhead_pct_median": float, "overhead_pct_best": float, "headless_engine_cpu_s": list,
          "live_engine_cpu_s": list, "viewer_cpu_s": list, "viewer_cpu_pct": float, "server_start_s": list,
          "pushes": int, "frames": int, "client_bytes": int, "all_drawn": bool}


CONNECT_TIMEOUT_S = 60.0


def client_process(port: int, stop, result) -> None:
    """A browser-like websocket client: connect, then take every frame until ``stop`` is set; put (frames,
    bytes) on ``result``."""
    import msgspec  # lazy: only the client process needs them
    import websockets

    from support.viewer_clients import CAMERA, SUBPROTOCOL

    async def main() -> tuple[int, int]:
        frames = size = 0
        async with websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL], max_size=None) as ws:
            await ws.send(msgspec.msgpack.encode(CAMERA))
            while not stop.is_set():
                try:
                    data = await asyncio.wait_for(ws.recv(), timeout=0.2)
                except TimeoutError:
                    continue
                frames += 1
                size += len(data)
        return frames, size

    result.put(asyncio.run(main()))


def thread_cpu_s() -> dict[int, float]:
    """CPU seconds (user + system) of every thread of this process so far, by native thread id (Linux)."""
    tick = os.sysconf("SC_CLK_TCK")
    out = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            fields = Path(f"/proc/self/task/{tid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:  # the thread ended meanwhile
            continue
        out[int(tid)] = (int(fields[11]) + int(fields[12])) / tick
    return out


def cpu_split(before: dict[int, float], after: dict[int, float]) -> tuple[float, float]:
    """(engine, viewer) CPU seconds between two :func:`thread_cpu_s`: the viewer's are the Python threads
    other than the main one (the live viewer's worker, viser's event loop and its pool); the engine's are the
    main thread and numba's workers (native threads Python does not list)."""
    viewer_ids = {t.native_id for t in threading.enumerate() if t is not threading.main_thread()}
    engine = viewer = 0.0
    for tid, seconds in after.items():
        spent = seconds - before.get(tid, 0.0)
        if tid in viewer_ids:
            viewer += spent
        else:
            engine += spent
    return engine, viewer


def timed_run(scene, options: PatchMatchOptions, live: bool) -> dict:
    """One PatchMatch run: engine seconds, and with ``live`` the server start, pushes and client traffic."""
    from workbench.viewer.live import LiveViewer  # lazy: viser

    views = patchmatch_views(scene)
    if not live:
        cpu = thread_cpu_s()
        start = time.perf_counter()
        run_patchmatch(views, options)
        seconds = time.perf_counter() - start
        return {"engine_s": seconds, "engine_cpu_s": cpu_split(cpu, thread_cpu_s())[0]}
    t = time.perf_counter()
    viewer = LiveViewer(scene, PipelineOptions(patchmatch=options), port=0)
    start_s = time.perf_counter() - t
    ctx = multiprocessing.get_context("spawn")  # no fork of a process with viser's threads
    stop, result = ctx.Event(), ctx.Queue()
    client = ctx.Process(target=client_process, args=(viewer.port, stop, result), daemon=True)
    try:
        client.start()
        deadline = time.monotonic() + CONNECT_TIMEOUT_S
        while not viewer.server.get_clients():
            if time.monotonic() > deadline:
                raise TimeoutError("the benchmark client did not connect")
            time.sleep(0.05)
        cpu = thread_cpu_s()
        start = time.perf_counter()
        run_patchmatch(views, options, observer=viewer)
        seconds = time.perf_counter() - start
        engine_cpu, viewer_cpu = cpu_split(cpu, thread_cpu_s())
        drained = viewer.wait_idle(30)
        time.sleep(0.5)  # the last frames reach the client
        stop.set()
        frames, size = result.get(timeout=30)
        client.join(timeout=30)
        return {"engine_s": seconds, "engine_cpu_s": engine_cpu, "viewer_cpu_s": viewer_cpu,
                "server_start_s": start_s, "pushes": viewer.pushes, "frames": frames,
                "client_bytes": size, "drained": drained}
    finally:
        stop.set()
        if client.is_alive():
            client.terminate()
            client.join(timeout=10)
        viewer.stop()


def summary(result: dict) -> list[dict]:
    """Median engine seconds headless and live, the overhead, and what reached the client."""
    return [{"scene": f"{result['scene']} {result['size'][0]}x{result['size'][1]}",
             "iterations": result["iterations_per_pass"], "headless s": statistics.median(result["headless_s"]),
             "live s": statistics.median(result["live_s"]), "overhead % (medians)": result["overhead_pct_median"],
             "overhead % (best)": result["overhead_pct_best"],
             "viewer CPU % of engine CPU": result.get("viewer_cpu_pct"), "pushes": result["pushes"],
             "client MB": result["client_bytes"] / 1e6}]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", type=Path, default=bench.REPO_ROOT / "sample_scenes" / "small")
    parser.add_argument("--size", type=int, default=0, help="--max-image-size of the scene (0 = as stored)")
    parser.add_argument("--iterations", type=int, default=2, help="iterations per pass")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=bench.results_path(__file__))
    args = parser.parse_args()

    scene = load_scene(args.scene, SceneOptions(max_image_size=args.size) if args.size else None)
    options = PatchMatchOptions(iterations=args.iterations)
    timed_run(scene, PatchMatchOptions(iterations=1, levels=1, geom_passes=0), False)  # compile / warm caches
    headless, live, runs, headless_cpu = [], [], [], []
    for r in range(args.repeats):
        for with_viewer in ((False, True) if r % 2 == 0 else (True, False)):
            run = timed_run(scene, options, with_viewer)
            (live if with_viewer else headless).append(run["engine_s"])
            (runs if with_viewer else headless_cpu).append(run if with_viewer else run["engine_cpu_s"])
            cpu = f", viewer CPU {run['viewer_cpu_s']:.2f} s" if with_viewer else ""
            print(f"repeat {r}: {'live    ' if with_viewer else 'headless'} {run['engine_s']:.2f} s "
                  f"(engine CPU {run['engine_cpu_s']:.1f} s{cpu})", flush=True)
    cam = scene.views[0].camera
    result = {"scene": scene.name, "views": len(scene.views), "size": [cam.width, cam.height],
              "iterations_per_pass": args.iterations, "headless_s": headless, "live_s": live,
              "overhead_pct_median": 100.0 * (statistics.median(live) / statistics.median(headless) - 1.0),
              "overhead_pct_best": 100.0 * (min(live) / min(headless) - 1.0),
              "headless_engine_cpu_s": headless_cpu, "live_engine_cpu_s": [r["engine_cpu_s"] for r in runs],
              "viewer_cpu_s": [r["viewer_cpu_s"] for r in runs],
              "viewer_cpu_pct": 100.0 * sum(r["viewer_cpu_s"] for r in runs) / sum(r["engine_cpu_s"] for r in runs),
              "server_start_s": [r["server_start_s"] for r in runs], "pushes": runs[-1]["pushes"],
              "frames": runs[-1]["frames"], "client_bytes": runs[-1]["client_bytes"],
              "all_drawn": all(r["drained"] for r in runs)}
    bench.print_table(summary(result))
    bench.write_result(result, args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
