"""A rerun ``.rrd`` recording written under a temporary name, compacted and renamed when complete."""

from __future__ import annotations

import os
import subprocess
import tempfile
import uuid
from pathlib import Path

import rerun as rr
import rerun_cli

from engine.core.errors import DeepCError

APP_ID = "deepc_workbench"
#: seconds the SDK gathers rows before it sends them to a live viewer (rerun's default is 0.2 s). It sends a chunk per
#: entity and flush, and the web viewer ingests about one chunk per frame (~23 chunks/s in software-WebGL chromium on
#: 2 cores), whatever its size: at 0.2 s the demo's stream is ~2 250 chunks of about one row each; at 2 s, by the
#: timing of its logged iterations, about half as many. It adds at most this much delay. The live page's lag at the
#: run's end varies more from run to run than the tick changes it (docs/decisions.md, bench_replay_load.py).
LIVE_FLUSH_TICK_S = 2.0
#: seconds ``rerun rrd optimize`` may take on a finished recording before the file is kept as written
COMPACT_TIMEOUT_S = 120


def rerun_binary() -> Path:
    """The real ``rerun`` binary of the rerun-cli wheel (not its Python wrapper)."""
    return Path(rerun_cli.__file__).parent / "rerun"


def compact(source: Path, target: Path) -> bool:
    """Write ``source`` (a finished ``.rrd``) to ``target`` with its chunks merged (``rerun rrd optimize``): the
    stream logs a chunk per entity and flush, about one row each, and the web viewer's time to load a recording
    follows its chunks, not its bytes. The demo's recording: 2 248 chunks, whose replay showed the last iteration
    only after 99 s in software-WebGL chromium on a loaded machine (a layout of its depth alone); compacted, 295
    chunks and 29 % fewer bytes, 10-25 s with the whole iterations layout (``bench_replay_load.py``). False (and no
    ``target``) when rerun could not."""
    try:
        done = subprocess.run([str(rerun_binary()), "rrd", "optimize", str(source), "-o", str(target)],
                              capture_output=True, timeout=COMPACT_TIMEOUT_S,
                              env={**os.environ, "RERUN_ANALYTICS_DISABLED": "1"})
    except (OSError, subprocess.TimeoutExpired):
        done = None
    if done is None or done.returncode != 0 or not target.is_file() or target.stat().st_size == 0:
        target.unlink(missing_ok=True)
        return False
    return True


class Recording:
    """``rec`` logs into ``<dir>/.<name>.*.tmp`` (and to ``live_url``, a viewer's gRPC address, if given);
    :meth:`finish` compacts the file (:func:`compact`) into ``path``; :meth:`abandon` deletes it."""

    def __init__(self, path: str | Path | None, blueprint=None, live_url: str | None = None):
        batching = rr.ChunkBatcherConfig(flush_tick=LIVE_FLUSH_TICK_S) if live_url else None
        self.rec = rr.RecordingStream(APP_ID, recording_id=str(uuid.uuid4()), batcher_config=batching)
        self.stream = None
        if path is None:  # live only
            self.path = self.tmp = None
            self.rec.connect_grpc(live_url, default_blueprint=blueprint)
            return
        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tmp", dir=self.path.parent)
        except OSError as exc:
            raise DeepCError(f"cannot write the recording: {exc.strerror or exc}", self.path) from exc
        os.fchmod(fd, 0o644)
        os.close(fd)
        self.tmp = Path(tmp)
        if live_url:  # the same logs go to a live viewer and to the file
            self.rec.set_sinks(rr.GrpcSink(live_url), rr.FileSink(str(self.tmp)), default_blueprint=blueprint)
        else:
            self.rec.save(str(self.tmp), default_blueprint=blueprint)

    def finish(self) -> Path | None:
        self.rec.flush()
        self.rec.disconnect()
        if self.tmp is not None:
            fd, name = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tmp", dir=self.path.parent)
            os.close(fd)  # named as the file being written is, so a killed run's is cleaned up alike
            compacted = Path(name)
            if compact(self.tmp, compacted):
                os.chmod(compacted, 0o644)
                os.replace(compacted, self.path)
                self.tmp.unlink()
            else:  # rerun could not: the file as written still replays, only slower
                os.replace(self.tmp, self.path)
        return self.path

    def abandon(self) -> None:
        try:
            self.rec.disconnect()
        finally:
            if self.tmp is not None:
                self.tmp.unlink(missing_ok=True)
