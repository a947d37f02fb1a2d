"""``deepc replay FILE.rrd [--layout NAME]``: open a recording in the rerun viewer.

With a display the native viewer opens; without one (or with ``--web``) the rerun web viewer is
served on 127.0.0.1 and its address printed. The real ``rerun`` binary is started directly (not its
Python wrapper, which would orphan the server when stopped) in its own process group, so stopping
it stops everything it started.
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import tempfile
import threading
import time
import urllib.parse
from pathlib import Path

import rerun_cli
from rerun.chunk import RrdReader

from engine.errors import DeepCError
from layouts import LAYOUTS
from workbench.recording import APP_ID

_URL = re.compile(r"(http://[^\s]+\?url=[^\s]+)")


def rerun_binary() -> Path:
    return Path(rerun_cli.__file__).parent / "rerun"


def recording_views(path: str | Path) -> list[str]:
    """View entity names (``maps/<view>/...``) in a recording; raises DeepCError if it is not one."""
    path = Path(path)
    if not path.is_file():
        raise DeepCError("recording not found", path)
    try:
        summary = str(RrdReader(str(path)).stream().collect().summary())
    except Exception as exc:  # the reader raises assorted types for foreign or truncated files
        raise DeepCError(f"not a readable rerun recording ({' '.join(str(exc).split())[:160]})", path) from None
    # entity parts are escaped (entity_name): a '\/' inside a part does not end it
    views = sorted({m.group(1) for m in re.finditer(r"^/maps/((?:\\.|[^/\\\s])+)/", summary, re.MULTILINE)})
    return views


def layout_file(path: str | Path, layout: str, folder: Path) -> Path:
    """Write the blueprint ``layout`` for the recording at ``path`` into ``folder``; returns the .rbl."""
    if layout not in LAYOUTS:
        raise DeepCError(f"unknown layout {layout!r} (one of {', '.join(LAYOUTS)})")
    views = recording_views(path) or ["none"]
    target = folder / f"{layout}.rbl"
    LAYOUTS[layout](views).save(APP_ID, str(target))
    return target


class WebViewer:
    """A rerun web viewer on ``host``: serving one recording, or (``path=None``) waiting for a live
    stream at :attr:`grpc_url`. Use as a context manager or call stop()."""

    def __init__(self, path: str | Path | None = None, layout: str | None = None, host: str = "127.0.0.1",
                 port: int = 0, timeout: float = 60.0):
        self._tmp = tempfile.TemporaryDirectory(prefix="deepc-replay-")
        files = [] if path is None else [str(Path(path).resolve())]
        if path is not None and layout:
            files.append(str(layout_file(path, layout, Path(self._tmp.name))))
        elif path is not None:
            recording_views(path)  # validates the file before starting anything
        cmd = [str(rerun_binary()), "--serve-web", "--bind", host, "--port", "0", "--web-viewer-port", str(port),
               *files]
        env = {**os.environ, "RERUN_ANALYTICS_DISABLED": "1"}
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                     start_new_session=True, env=env)
        self.url = self._wait_for_url(timeout)
        query = urllib.parse.parse_qs(urllib.parse.urlsplit(self.url).query)
        self.grpc_url = query.get("url", [""])[0].replace("localhost", "127.0.0.1")

    def _wait_for_url(self, timeout: float) -> str:
        found: list[str] = []
        lines: list[str] = []

        def read() -> None:
            for line in self.proc.stdout:
                lines.append(line)
                match = _URL.search(line)
                if match and not found:
                    found.append(match.group(1))
        threading.Thread(target=read, daemon=True).start()
        deadline = time.monotonic() + timeout
        while not found and time.monotonic() < deadline and self.proc.poll() is None:
            time.sleep(0.05)
        if not found:
            self.stop()
            raise DeepCError(f"the rerun web viewer did not start ({''.join(lines[-3:]).strip()[:200]})")
        return found[0].replace("localhost", "127.0.0.1")

    def stop(self) -> None:
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGTERM)
                self.proc.wait(timeout=10)
            except (ProcessLookupError, subprocess.TimeoutExpired):
                try:
                    os.killpg(self.proc.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
        self._tmp.cleanup()

    def __enter__(self) -> WebViewer:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def replay(path: str, layout: str | None = None, web: bool = False, host: str = "127.0.0.1", port: int = 9090) -> int:
    """Blocking: open the native viewer, or serve the web viewer until Ctrl+C."""
    if has_display() and not web:
        with tempfile.TemporaryDirectory(prefix="deepc-replay-") as tmp:
            files = [path] + ([str(layout_file(path, layout, Path(tmp)))] if layout else [])
            if not layout:
                recording_views(path)
            return subprocess.call([str(rerun_binary()), *files])
    viewer = WebViewer(path, layout, host, port)
    print(f"rerun web viewer: {viewer.url}  (Ctrl+C to stop)", flush=True)
    try:
        viewer.proc.wait()
    except KeyboardInterrupt:
        pass
    finally:
        viewer.stop()
    return 0


class NativeViewer:
    """The native rerun viewer, listening for a live stream on 127.0.0.1 (needs a display)."""

    def __init__(self, host: str = "127.0.0.1"):
        with socket.socket() as sock:
            sock.bind((host, 0))
            port = sock.getsockname()[1]
        self.proc = subprocess.Popen([str(rerun_binary()), "--bind", host, "--port", str(port)],
                                     start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        self.grpc_url = f"rerun+http://{host}:{port}/proxy"
        self.url = "the native rerun viewer"

    def stop(self) -> None:
        """Leave the window open for the user; it is theirs to close."""


def live_viewer(host: str = "127.0.0.1", web: bool = False) -> WebViewer | NativeViewer:
    """A viewer to stream a run into: native with a display, otherwise the web viewer on ``host``."""
    return NativeViewer(host) if has_display() and not web else WebViewer(None, host=host)
