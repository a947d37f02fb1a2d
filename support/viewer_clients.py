"""Browser-like websocket clients for the viewer benchmarks, speaking viser's protocol.

Kept free of the engine and of viser's server so that ``support/viewer_load.py`` can run the clients in their own
process, as five browser tabs would be: clients in the server's process compete with it for the GIL
and their decoding then counts as the server's latency.
"""

from __future__ import annotations

import asyncio
import random
import struct
import time
from importlib.metadata import version

import msgspec
import websockets
import zstandard

CAMERA = {"type": "ViewerCameraMessage", "wxyz": [1, 0, 0, 0], "position": [0, 0, 0], "fov": 1.0, "near": 0.01,
          "far": 1000.0, "image_height": 600, "image_width": 800, "look_at": [0, 0, 1], "up_direction": [0, -1, 0]}
SUBPROTOCOL = f"viser-v{version('viser')}"
CLOUD = "/fused"  # the viewer's scene node for the fused cloud


def decode_frame(data: bytes) -> list[dict]:
    """The messages of one binary websocket frame from viser (zstd-compressed msgpack with a size header)."""
    raw_size, zstd_size = struct.unpack_from("<QQ", data, 0)
    payload = zstandard.ZstdDecompressor().decompress(data[16:16 + zstd_size], max_output_size=raw_size)
    return msgspec.msgpack.decode(payload).get("messages", [])


def markdown_text(message: dict, uuid: str) -> str | None:
    """Markdown text that ``message`` carries for GUI element ``uuid`` (an update or the full state sent on
    connect), or None."""
    if message.get("uuid") != uuid:
        return None
    for holder in (message.get("updates"), message.get("props"), message):
        if isinstance(holder, dict):
            for key in ("_markdown", "content", "markdown"):
                if isinstance(holder.get(key), str):
                    return holder[key]
    return None


def is_exact_text(text: str) -> bool:
    """Whether a metrics-panel text reports an exact result (scores, or "no ground truth"), not a preview
    or a computation in progress."""
    return "F1 " in text or "no ground truth" in text


def is_cloud_update(message: dict, name: str) -> bool:
    """Whether ``message`` changes the scene node ``name`` (the viewer's fused cloud)."""
    return message.get("type") == "SceneNodeUpdateMessage" and message.get("name") == name


class Client:
    """One websocket client: listens to everything, records when the viewer answers (a metrics-panel or a
    cloud update: a change whose metrics text happens to be unchanged still shows a new cloud)."""

    def __init__(self, port: int, metrics_uuid: str, index: int):
        self.port, self.uuid, self.index = port, metrics_uuid, index
        self.ws = None
        self.updates: list[tuple[float, str]] = []  # (monotonic time, metrics text) on this connection
        self.history: list[float] = []  # arrival times of every answer (metrics or cloud), all connections
        self.exact_history: list[float] = []  # arrival times of exact results, all connections
        self.closed_at: list[float] = []  # when this client dropped its connection
        # (time, "preview" | "exact": what the event can get at once, GUI element uuid)
        self.sent: list[tuple[float, str, str]] = []
        self.reader: asyncio.Task | None = None

    async def connect(self) -> None:
        self.ws = await websockets.connect(f"ws://127.0.0.1:{self.port}", subprotocols=[SUBPROTOCOL], max_size=None)
        await self.ws.send(msgspec.msgpack.encode(CAMERA))
        self.updates = []
        self.reader = asyncio.create_task(self._read())

    async def _read(self) -> None:
        try:
            async for data in self.ws:
                if isinstance(data, str):
                    continue
                now = time.monotonic()
                answered = False
                for message in decode_frame(data):
                    text = markdown_text(message, self.uuid)
                    if text is not None:
                        self.updates.append((now, text))
                        if is_exact_text(text):
                            self.exact_history.append(now)
                    answered = answered or text is not None or is_cloud_update(message, CLOUD)
                if answered:
                    self.history.append(now)
        except websockets.ConnectionClosed:
            pass

    async def close(self) -> None:
        self.closed_at.append(time.monotonic())
        await self.ws.close()
        await self.reader

    async def send(self, uuid: str, value, kind: str) -> None:
        self.sent.append((time.monotonic(), kind, uuid))
        await self.ws.send(msgspec.msgpack.encode({"type": "GuiUpdateMessage", "uuid": uuid,
                                                   "updates": {"value": value}}))

    def latencies(self) -> tuple[dict[str, list[float]], int]:
        """Per sent event: the time to the next answer ("preview" events: any update of the metrics panel or
        the cloud) and to the next exact result ("exact": every event). Events whose client dropped before
        the answer arrived are counted apart (their wait is the reconnect's)."""
        out: dict[str, list[float]] = {"preview": [], "exact": []}
        dropped = 0
        for sent_at, kind, uuid in self.sent:
            for key, times in (("preview", self.history), ("exact", self.exact_history)):
                if key == "preview" and kind != "preview":
                    continue
                after = next((t for t in times if t >= sent_at), None)
                if after is None:
                    continue
                if any(sent_at <= c < after for c in self.closed_at):
                    dropped += key == "exact"
                else:
                    out[key].append(after - sent_at)
                    if key == "preview":
                        out.setdefault(uuid, []).append(after - sent_at)
        return out, dropped


async def run_clients(config: dict, last_sent_cb, final_state) -> dict:
    """Drive ``config["clients"]`` clients: ``rate`` events per second for ``seconds``, one client dropping
    and reconnecting every ``reconnect_every`` seconds (beside the event stream, so the rate holds).

    ``config["controls"]`` lists (GUI element uuid, values to pick from). ``last_sent_cb(t)`` is called after
    the last event; ``await final_state()`` returns the server's final metrics text once it has settled.
    """
    rng = random.Random(config.get("seed", 0))
    clients, rate, port = config["clients"], config["rate"], config["port"]
    pool = [Client(port, config["metrics_uuid"], i) for i in range(clients)]
    for c in pool:
        await c.connect()
    await asyncio.sleep(1.0)
    reconnects: list[dict] = []
    reconnecting: set[int] = set()
    start = time.monotonic()

    async def reconnect(victim: Client) -> None:
        reconnecting.add(victim.index)
        await victim.close()
        await asyncio.sleep(0.2)
        t = time.monotonic()
        await victim.connect()
        while not victim.updates and time.monotonic() - t < 5:
            await asyncio.sleep(0.01)
        first = victim.updates[0][0] if victim.updates else t
        await asyncio.sleep(1.5)
        # current: within 1 s of its first message (the replay on connect, which starts with the panel's
        # creation text and may span several frames behind the cloud's) the client shows a text that the
        # clients that stayed connected were shown at some instant since it connected: their last text before
        # it connected, or one they received since. Judging the replay's last text at a fixed delay instead
        # failed when the replay took longer than that delay under load.
        others = [c for c in pool if c is not victim]
        shown_at_connect = {texts[-1] for c in others if (texts := [x for a, x in c.updates if a <= t])}
        got_at = None
        for at, text in victim.updates:
            if at > first + 1.0:
                break
            if text in shown_at_connect or any(x == text for c in others for a, x in c.updates if t < a <= at + 0.05):
                got_at = at
                break
        reconnects.append({"at_s": t - start, "state_received_s": (got_at - t) if got_at is not None else None,
                           "current": got_at is not None})
        reconnecting.discard(victim.index)

    tasks, sent = [], 0
    last_value: dict[str, object] = {}
    next_reconnect = start + config["reconnect_every"]
    while time.monotonic() - start < config["seconds"]:
        await asyncio.sleep(max(0.0, start + sent / rate - time.monotonic()))
        ready = [c for c in pool if c.index not in reconnecting]
        if not ready:
            await asyncio.sleep(0.01)
            continue
        client = pool[sent % clients] if pool[sent % clients] in ready else ready[0]
        uuid, values, kind = rng.choice(config["controls"])
        # a real drag changes the value: an event that sets what is already set has nothing to answer
        value = rng.choice([v for v in values if v != last_value.get(uuid)])
        last_value[uuid] = value
        await client.send(uuid, value, kind)
        sent += 1
        if time.monotonic() >= next_reconnect:
            next_reconnect += config["reconnect_every"]
            tasks.append(asyncio.create_task(reconnect(pool[rng.randrange(clients)])))
    await asyncio.gather(*tasks)
    last_sent = max(t for c in pool for t, _, _ in c.sent)  # the last event (reconnect tasks may end later)
    last_sent_cb(last_sent)
    final = await final_state()
    await asyncio.sleep(0.5)
    settle = []
    for c in pool:  # when did each client get the final exact result (None: it holds something else)?
        last = c.updates[-1] if c.updates else None
        settle.append(max(0.0, last[0] - last_sent) if last and last[1] == final else None)
    latencies: dict[str, list[float]] = {"preview": [], "exact": []}
    dropped = 0
    for c in pool:
        lat, lost = c.latencies()
        for key in lat:
            latencies[key] = latencies.get(key, []) + lat[key]
        dropped += lost
    errors = sorted({text for c in pool for _, text in c.updates if "error" in text.lower()})
    late = Client(port, config["metrics_uuid"], clients)  # a client that joins at the end gets the current state
    await late.connect()
    await asyncio.sleep(1.0)
    late_state = late.updates[-1][1] if late.updates else None
    for c in [*pool, late]:
        await c.close()
    return {"events": sent, "start": start, "latencies": latencies, "dropped_by_reconnect": dropped,
            "settle": settle, "reconnects": reconnects, "errors": errors, "late_client_current": late_state == final,
            "final": final}


def client_process(conn, config: dict) -> None:
    """Entry point of the clients' own process: runs ``run_clients`` and talks to the server's process over
    a pipe ("sent" with the time of the last event → the final metrics text → the results)."""

    async def final_state() -> str:
        return await asyncio.get_running_loop().run_in_executor(None, conn.recv)

    try:
        result = asyncio.run(run_clients(config, lambda t: conn.send(("sent", t)), final_state))
        conn.send(("result", result))
    except BaseException as exc:  # the parent must learn why, not wait for a timeout
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
        raise
