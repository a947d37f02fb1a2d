"""The viewer under load: several browser clients, a stream of GUI events, clients dropping and reconnecting.

    .venv/bin/python benchmarks/bench_viewer_load.py [--scene sample_scenes/fountain_p11] [--clients 5]
                                                     [--rate 50] [--seconds 60]
                                                     [--out benchmarks/results/bench_viewer_load.json]

Raw websocket clients speak viser's protocol (as benchmarks/bench_viewer.py): each registers its camera,
listens to every message, and sends its share of ``--rate`` slider/dropdown changes per second, as a
browser would. Every ~10 s one client disconnects and reconnects and must receive the current state (the
metrics panel the server shows now). Measured: event-to-update latency (from an event to the next
metrics update its client receives), time for the last event's exact result to reach every client,
resident memory over time, and any error the viewer reported. Targets (issue 9): no error, updates within
the viewer's targets (preview 100 ms, exact 2 s, here at most ``--rate`` times more work queued),
memory bounded (last third of the run within 20 % of the first third), reconnecting clients current.
``tests/test_viewer_load.py`` runs a 5-second version.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import random
import statistics
import sys
import tempfile
import time
from pathlib import Path

import msgspec
import viser
import websockets

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "tests"))
sys.path.insert(0, str(REPO / "benchmarks"))

from bench_viewer import decode_frame  # noqa: E402
from conftest import make_fake_run  # noqa: E402

from engine.io.outputs import write_json  # noqa: E402
from engine.memory import current_rss  # noqa: E402
from engine.scene import SceneOptions  # noqa: E402
from workbench.session import ViewerSession  # noqa: E402
from workbench.viewer import ViewerApp  # noqa: E402

_CAMERA = {"type": "ViewerCameraMessage", "wxyz": [1, 0, 0, 0], "position": [0, 0, 0], "fov": 1.0, "near": 0.01,
           "far": 1000.0, "image_height": 600, "image_width": 800, "look_at": [0, 0, 1], "up_direction": [0, -1, 0]}


def _markdown(message: dict, uuid: str) -> str | None:
    """Metrics-panel text carried by ``message`` (an update or the full state sent on connect), or None."""
    if message.get("uuid") != uuid:
        return None
    for holder in (message.get("updates"), message.get("props"), message):
        if isinstance(holder, dict):
            for key in ("_markdown", "content", "markdown"):
                if isinstance(holder.get(key), str):
                    return holder[key]
    return None


class Client:
    """One websocket client: listens to everything, records when metrics updates arrive."""

    def __init__(self, app: ViewerApp, index: int):
        self.app, self.index = app, index
        self.uuid = app.metrics._impl.uuid
        self.ws = None
        self.updates: list[tuple[float, str]] = []  # (monotonic time, metrics text)
        self.sent: list[float] = []
        self.reader: asyncio.Task | None = None

    async def connect(self) -> None:
        self.ws = await websockets.connect(f"ws://127.0.0.1:{self.app.port}",
                                           subprotocols=[f"viser-v{viser.__version__}"], max_size=None)
        await self.ws.send(msgspec.msgpack.encode(_CAMERA))
        self.updates = []
        self.reader = asyncio.create_task(self._read())

    async def _read(self) -> None:
        try:
            async for data in self.ws:
                if isinstance(data, str):
                    continue
                for message in decode_frame(data):
                    text = _markdown(message, self.uuid)
                    if text is not None:
                        self.updates.append((time.monotonic(), text))
        except websockets.ConnectionClosed:
            pass

    async def close(self) -> None:
        await self.ws.close()
        await self.reader

    async def send(self, handle, value) -> None:
        self.sent.append(time.monotonic())
        await self.ws.send(msgspec.msgpack.encode({"type": "GuiUpdateMessage", "uuid": handle._impl.uuid,
                                                   "updates": {"value": value}}))


def _controls(app: ViewerApp, rng: random.Random):
    """(handle, value) pairs a user would produce by dragging sliders and picking colours."""
    choices = [
        lambda: (app.conf_tau, round(rng.uniform(0.0, 0.8), 2)),
        lambda: (app.mask_k, rng.randint(0, 4)),
        lambda: (app.min_views, rng.randint(1, 5)),
        lambda: (app.reproj, rng.choice([0.5, 1.0, 1.5, 2.0])),
        lambda: (app.depth_err, rng.choice([0.005, 0.01, 0.02])),
        lambda: (app.color_mode, rng.choice(list(app.color_mode.options))),
    ]
    return lambda: rng.choice(choices)()


async def load(app: ViewerApp, clients: int, rate: float, seconds: float, reconnect_every: float,
               seed: int = 0) -> dict:
    rng = random.Random(seed)
    pick = _controls(app, rng)
    pool = [Client(app, i) for i in range(clients)]
    for c in pool:
        await c.connect()
    await asyncio.sleep(1.0)
    latencies, reconnects, rss = [], [], []
    start = time.monotonic()
    next_reconnect = start + reconnect_every
    sent = 0
    while time.monotonic() - start < seconds:
        tick = start + sent / rate
        await asyncio.sleep(max(0.0, tick - time.monotonic()))
        client = pool[sent % clients]
        handle, value = pick()
        await client.send(handle, value)
        sent += 1
        if sent % max(1, int(rate)) == 0:
            rss.append((time.monotonic() - start, current_rss() / (1 << 20)))
        if time.monotonic() >= next_reconnect:
            next_reconnect += reconnect_every
            victim = pool[rng.randrange(clients)]
            await victim.close()
            await asyncio.sleep(0.2)
            await victim.connect()
            t = time.monotonic()
            while not victim.updates and time.monotonic() - t < 5:
                await asyncio.sleep(0.01)
            # current = what the server shows now, or what the clients that stayed connected last received
            current = {app.metrics.content} | {c.updates[-1][1] for c in pool if c is not victim and c.updates}
            got = victim.updates[-1][1] if victim.updates else None
            reconnects.append({"at_s": t - start, "state_received_s": (victim.updates[0][0] - t) if got else None,
                               "current": got in current})
    last_sent = time.monotonic()
    settled = app.wait_idle(120)
    final = app.metrics.content
    await asyncio.sleep(0.5)
    settle = []
    for c in pool:  # when did each client get the final exact result (None: it holds something else)?
        last = c.updates[-1] if c.updates else None
        settle.append(max(0.0, last[0] - last_sent) if last and last[1] == final else None)
    for c in pool:
        for sent_at in c.sent:
            after = [t for t, _ in c.updates if t >= sent_at]
            if after:
                latencies.append(after[0] - sent_at)
    errors = sorted({text for c in pool for _, text in c.updates if "error" in text.lower()})
    late = Client(app, clients)  # a client that joins at the end gets the current state
    await late.connect()
    await asyncio.sleep(1.0)
    late_state = late.updates[-1][1] if late.updates else None
    for c in [*pool, late]:
        await c.close()
    return {"events": sent, "latencies": latencies, "settle": settle, "settled": settled, "rss": rss,
            "reconnects": reconnects, "errors": errors, "late_client_current": late_state == final,
            "final": final}


def summarise(result: dict) -> dict:
    lat = sorted(result["latencies"])

    def pct(q):
        return 1000 * lat[min(len(lat) - 1, int(q * len(lat)))] if lat else None

    rss = [m for _, m in result["rss"]]
    third = max(1, len(rss) // 3)
    growth = (statistics.mean(rss[-third:]) / statistics.mean(rss[:third]) - 1) if rss else 0.0
    settle = [s for s in result["settle"] if s is not None]
    return {"events": result["events"], "updates_measured": len(lat), "latency_ms_p50": pct(0.5),
            "latency_ms_p95": pct(0.95), "latency_ms_max": pct(1.0),
            "final_exact_s_max": max(settle) if len(settle) == len(result["settle"]) else None,
            "rss_mb_first": rss[0] if rss else None, "rss_mb_max": max(rss) if rss else None,
            "rss_growth_last_vs_first_third": growth, "reconnects": len(result["reconnects"]),
            "reconnects_current": sum(r["current"] for r in result["reconnects"]),
            "late_client_current": result["late_client_current"], "errors": result["errors"],
            "settled": result["settled"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", type=Path, default=REPO / "sample_scenes" / "fountain_p11")
    parser.add_argument("--size", type=int, default=0)
    parser.add_argument("--clients", type=int, default=5)
    parser.add_argument("--rate", type=float, default=50.0)
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--reconnect-every", type=float, default=10.0)
    parser.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results" / "bench_viewer_load.json")
    args = parser.parse_args()
    out_dir = Path(tempfile.mkdtemp(prefix="bench-viewer-load-"))
    make_fake_run(args.scene, out_dir, scene_options=SceneOptions(max_image_size=args.size))
    app = ViewerApp(ViewerSession.open(out_dir), port=0)
    try:
        app.wait_idle(600)
        result = asyncio.run(load(app, args.clients, args.rate, args.seconds, args.reconnect_every))
    finally:
        app.stop()
    summary = summarise(result)
    summary.update(scene=args.scene.name, clients=args.clients, rate=args.rate, seconds=args.seconds,
                   load_average_1min=os.getloadavg()[0], cpus=os.cpu_count())
    for key, value in summary.items():
        print(f"{key:<34} {value}")
    write_json(args.out, summary)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
