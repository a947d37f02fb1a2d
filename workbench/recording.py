"""A rerun ``.rrd`` recording written under a temporary name and renamed when complete."""

from __future__ import annotations

import os
import tempfile
import uuid
from pathlib import Path

import rerun as rr

from engine.errors import DeepCError

APP_ID = "deepc_workbench"


class Recording:
    """``rec`` logs into ``<dir>/.<name>.*.tmp``; :meth:`finish` renames it to ``path``; :meth:`abandon` deletes it."""

    def __init__(self, path: str | Path, blueprint=None):
        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tmp", dir=self.path.parent)
        except OSError as exc:
            raise DeepCError(f"cannot write the recording: {exc.strerror or exc}", self.path) from exc
        os.fchmod(fd, 0o644)
        os.close(fd)
        self.tmp = Path(tmp)
        self.rec = rr.RecordingStream(APP_ID, recording_id=str(uuid.uuid4()))
        self.rec.save(str(self.tmp), default_blueprint=blueprint)
        self.stream = None

    def finish(self) -> Path:
        self.rec.flush()
        self.rec.disconnect()
        os.replace(self.tmp, self.path)
        return self.path

    def abandon(self) -> None:
        try:
            self.rec.disconnect()
        finally:
            self.tmp.unlink(missing_ok=True)
