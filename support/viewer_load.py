"""The viewer under load: a client process applying GUI events, and the summary of what it measured.

Shared by ``benchmarks/performance/bench_viewer_load.py`` and its short version ``tests/test_viewer_load.py``.
"""

from __future__ import annotations

import multiprocessing
import statistics
import threading
import time
from typing import TYPE_CHECKING

from engine.core.errors import DeepCError
from engine.run.memory import current_rss
from support.viewer_clients import client_process

if TYPE_CHECKING:
    from workbench.viewer.app import ViewerApp


def _controls(app: ViewerApp) -> list[tuple[str, list, str]]:
    """(GUI element uuid, values, answer) triples a user would produce by dragging sliders and picking
    colours. answer: "preview" where the viewer can answer at once (masking the cached cloud, recolouring),
    "exact" where it must fuse again (the fusion's reprojection and depth thresholds)."""
    return [
        (app.fused_confidence_tau._impl.uuid, [round(0.01 * i, 2) for i in range(81)], "preview"),
        (app.mask_k._impl.uuid, [0, 1, 2, 3, 4], "preview"),
        (app.min_views._impl.uuid, [1, 2, 3, 4, 5], "preview"),
        (app.reproj._impl.uuid, [0.5, 1.0, 1.5, 2.0], "exact"),
        (app.depth_err._impl.uuid, [0.005, 0.01, 0.02], "exact"),
        (app.color_mode._impl.uuid, list(app.color_mode.options), "preview"),
    ]


def load(app: ViewerApp, clients: int, rate: float, seconds: float, reconnect_every: float, seed: int = 0,
         timeout: float = 300.0) -> dict:
    """Apply the load from a separate client process; sample this process's memory once a second."""
    config = {"port": app.port, "metrics_uuid": app.metrics._impl.uuid, "controls": _controls(app),
              "clients": clients, "rate": rate, "seconds": seconds, "reconnect_every": reconnect_every,
              "seed": seed}
    ctx = multiprocessing.get_context("spawn")
    ours, theirs = ctx.Pipe()
    proc = ctx.Process(target=client_process, args=(theirs, config), daemon=True)
    rss: list[tuple[float, float]] = []
    stop = threading.Event()

    def sample() -> None:
        while not stop.wait(1.0):
            rss.append((time.monotonic(), current_rss() / (1 << 20)))

    sampler = threading.Thread(target=sample, daemon=True)
    deadline = time.monotonic() + timeout

    def receive(expected: str):
        if not ours.poll(max(0.0, deadline - time.monotonic())):
            raise DeepCError(f"viewer load: the client process sent no {expected!r} within {timeout:.0f} s")
        kind, value = ours.recv()
        if kind != expected:
            raise DeepCError(f"viewer load: the client process failed: {value}")
        return value

    proc.start()
    try:
        sampler.start()
        receive("sent")
        settled = app.wait_idle(120)
        ours.send(app.metrics.content)
        result = receive("result")
    finally:
        stop.set()
        proc.join(10)
        if proc.is_alive():
            proc.kill()
    start = result["start"]
    result.update(settled=settled, rss=[(t - start, m) for t, m in rss if t >= start],
                  control_names={h._impl.uuid: h.label for h in (app.fused_confidence_tau, app.mask_k, app.min_views,
                                                                 app.reproj, app.depth_err, app.color_mode)})
    return result


def summarise(result: dict) -> dict:
    def pct(values, q, scale):
        values = sorted(values)
        return scale * values[min(len(values) - 1, int(q * len(values)))] if values else None

    preview, exact = result["latencies"]["preview"], result["latencies"]["exact"]
    names = result.get("control_names", {})
    per_control = {names.get(k, k): {"events": len(v), "p50_ms": pct(v, 0.5, 1000), "p95_ms": pct(v, 0.95, 1000)}
                   for k, v in result["latencies"].items() if k not in ("preview", "exact")}
    rss = [m for _, m in result["rss"]]
    third = max(1, len(rss) // 3)
    growth = (statistics.mean(rss[-third:]) / statistics.mean(rss[:third]) - 1) if rss else 0.0
    # the stage caches are LRU-bounded and fill during the first third: bounded memory = a plateau after that
    plateau = (statistics.mean(rss[-third:]) / statistics.mean(rss[third:2 * third]) - 1) if len(rss) >= 3 else 0.0
    settle = [s for s in result["settle"] if s is not None]
    return {"events": result["events"], "exact_measured": len(exact), "preview_measured": len(preview),
            "events_dropped_by_reconnect": result["dropped_by_reconnect"],
            "preview_ms_p50": pct(preview, 0.5, 1000), "preview_ms_p95": pct(preview, 0.95, 1000),
            "preview_ms_max": pct(preview, 1.0, 1000), "preview_by_control": per_control,
            "exact_s_p50": pct(exact, 0.5, 1), "exact_s_p95": pct(exact, 0.95, 1), "exact_s_max": pct(exact, 1.0, 1),
            "final_exact_s_max": max(settle) if len(settle) == len(result["settle"]) else None,
            "rss_mb_every_5s": [round(m) for t, m in result["rss"] if int(t) % 5 == 0][:50],
            "rss_mb_first": rss[0] if rss else None, "rss_mb_max": max(rss) if rss else None,
            "rss_growth_last_vs_first_third": growth, "rss_growth_last_vs_middle_third": plateau,
            "reconnects": len(result["reconnects"]),
            "reconnects_current": sum(r["current"] for r in result["reconnects"]),
            "reconnect_current_after_s": [r["state_received_s"] for r in result["reconnects"]],
            "late_client_current": result["late_client_current"], "errors": result["errors"],
            "settled": result["settled"]}
