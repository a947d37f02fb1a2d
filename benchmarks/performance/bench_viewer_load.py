"""The viewer under load: several browser clients, a stream of GUI events, clients dropping and reconnecting.

    .venv/bin/python benchmarks/performance/bench_viewer_load.py [--scene sample_scenes/fountain_p11] [--clients 5]
                                                     [--rate 50] [--seconds 60]
                                                     [--out benchmarks/results/bench_viewer_load.json]

Raw websocket clients speak viser's protocol (``support/viewer_clients.py``): each registers its camera,
listens to every message, and sends its share of ``--rate`` slider/dropdown changes per second, as a browser
would. The clients run in their own process, as browser tabs do (in the server's process they would compete
with it for the GIL). Every ~10 s one client disconnects and reconnects and must show the current state (the
metrics panel the other clients show) within 1 s of its first message. Measured, per event: the time to the
viewer's first answer (a metrics-panel or cloud update; for the controls a preview can serve: tau, mask-k, min
views, colour) and to the next exact result (scores in the panel; every event); the time for the last event's
exact result to reach every client; resident memory over time; any error the viewer reported. Targets (issues
7 and 9): no error; previews within 100 ms; the exact result within 2 s of the last event; memory bounded (the
stage caches are LRU-bounded and fill early: the last third of the run within 10 % of the middle third);
reconnecting and late clients current.
``tests/test_viewer_load.py`` runs a 5-second version (the load and its summary: ``support/viewer_load.py``).
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

from engine.scene import SceneOptions
from support import bench
from support.fake_run import make_fake_run
from support.viewer_load import load, summarise
from workbench.viewer.app import ViewerApp
from workbench.viewer.session import ViewerSession

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"events": int, "exact_measured": int, "preview_measured": int, "events_dropped_by_reconnect": int,
          "preview_ms_p50": float, "preview_ms_p95": float, "preview_ms_max": float, "preview_by_control": dict,
          "exact_s_p50": float, "exact_s_p95": float, "exact_s_max": float, "final_exact_s_max": float,
          "rss_mb_every_5s": list, "rss_mb_first": float, "rss_mb_max": float,
          "rss_growth_last_vs_first_third": float, "rss_growth_last_vs_middle_third": float, "reconnects": int,
          "reconnects_current": int, "late_client_current": bool, "errors": list, "settled": bool, "scene": str,
          "clients": int, "rate": float, "seconds": float, "load_average_1min": float, "cpus": int}



def summary(result: dict) -> list[dict]:
    """Events sent, preview and exact-result latencies (p50 / p95 / max), memory, reconnects, errors."""
    return [{"clients": result.get("clients"), "events": result["events"],
             "preview ms p50 / p95 / max": [result["preview_ms_p50"], result["preview_ms_p95"],
                                            result["preview_ms_max"]],
             "exact s p50 / p95 / max": [result["exact_s_p50"], result["exact_s_p95"], result["exact_s_max"]],
             "RSS MiB max": result["rss_mb_max"], "reconnects current": f"{result['reconnects_current']} of "
             f"{result['reconnects']}", "errors": len(result["errors"])}]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", type=Path, default=bench.REPO_ROOT / "sample_scenes" / "fountain_p11")
    parser.add_argument("--size", type=int, default=0)
    parser.add_argument("--clients", type=int, default=5)
    parser.add_argument("--rate", type=float, default=50.0)
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--reconnect-every", type=float, default=10.0)
    parser.add_argument("--out", type=Path, default=bench.results_path(__file__))
    args = parser.parse_args()
    out_dir = Path(tempfile.mkdtemp(prefix="bench-viewer-load-"))
    make_fake_run(args.scene, out_dir, scene_options=SceneOptions(max_image_size=args.size))
    app = ViewerApp(ViewerSession.open(out_dir), port=0)
    try:
        app.wait_idle(600)
        result = load(app, args.clients, args.rate, args.seconds, args.reconnect_every)
    finally:
        app.stop()
    record = summarise(result)
    record.update(scene=args.scene.name, clients=args.clients, rate=args.rate, seconds=args.seconds,
                  load_average_1min=os.getloadavg()[0], cpus=os.cpu_count())
    for key, value in record.items():
        print(f"{key:<34} {value}")
    bench.write_result(record, args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
