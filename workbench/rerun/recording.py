"""A rerun ``.rrd`` recording written under a temporary name and renamed when complete."""

from __future__ import annotations

import os
import tempfile
import uuid
from pathlib import Path

import rerun as rr

from engine.core.errors import DeepCError

APP_ID = "deepc_workbench"


class Recording:
    """``rec`` logs into ``<dir>/.<name>.*.tmp`` (and to ``live_url``, a viewer's gRPC address, if given);
    :meth:`finish` renames the file to ``path``; :meth:`abandon` deletes it."""

    def __init__(self, path: str | Path | None, blueprint=None, live_url: str | None = None):
        self.rec = rr.RecordingStream(APP_ID, recording_id=str(uuid.uuid4()))
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
            os.replace(self.tmp, self.path)
        return self.path

    def abandon(self) -> None:
        try:
            self.rec.disconnect()
        finally:
            if self.tmp is not None:
                self.tmp.unlink(missing_ok=True)
