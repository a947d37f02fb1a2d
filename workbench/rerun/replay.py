"""``deepc replay FILE.rrd [--layout NAME] [--view NAME]``: open a recording in the rerun viewer.

The layout is built from what the recording holds (:func:`recording_contents`) for the chosen view, its panel
titles naming the view. Next to it goes a small notes recording with the same recording id (the viewer merges
them): ``about`` says what the recording holds and lacks, ``missing/<view>/<kind>`` stands in for each map it
lacks, and ``legend`` explains the colour scales of recordings made before the stream logged one.

With a display the native viewer opens; without one (or with ``--web``) the rerun web viewer is
served on 127.0.0.1 and its address printed. The real ``rerun`` binary is started directly (not its
Python wrapper, which would orphan the server when stopped) in its own process group, so stopping
it stops everything it started.
"""

from __future__ import annotations

import dataclasses
import errno
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

from rerun.chunk import RrdReader

from engine.core.errors import DeepCError
from layouts import LAYOUTS, Contents, compare, view_title
from workbench.rerun.notes import log_notes
from workbench.rerun.recording import APP_ID, rerun_binary

_URL = re.compile(r"(http://[^\s]+\?url=[^\s]+)")
_ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")
# one line of ChunkStore.summary(): "/path rows=N static=B timelines=[...] cols=[...]" (escaped parts keep '\ ')
_ENTITY = re.compile(r"^(/(?:\\.|\S)+) rows=\d+ static=\w+ timelines=\[([^\]]*)\] cols=\[(.*)\]", re.MULTILINE)


@dataclasses.dataclass
class RecordingInfo:
    """A recording's ids and :class:`Contents`."""

    application_id: str
    recording_id: str | None
    contents: Contents


def recording_contents(path: str | Path) -> RecordingInfo:
    """What the recording at ``path`` holds; raises DeepCError if it is not a readable recording."""
    path = Path(path)
    if not path.is_file():
        raise DeepCError("recording not found", path)
    try:
        reader = RrdReader(str(path))
        entries = reader.recordings()
        summary = str(reader.stream().collect().summary())
    except Exception as exc:  # the reader raises assorted types for foreign or truncated files
        raise DeepCError(f"not a readable rerun recording ({' '.join(str(exc).split())[:160]})", path) from None
    entities, timelines = set(), set()
    for match in _ENTITY.finditer(summary):
        entity, lines, cols = match.groups()
        timelines.update(t.strip(" '") for t in lines.split(",") if t.strip(" '"))
        # an AnnotationContext alone (the legend of a class-coded map) is not data
        if any("AnnotationContext" not in c for c in cols.split(",")):
            entities.add(entity)
    # entity parts are escaped (entity_name): a '\/' inside a part does not end it
    views = sorted({m.group(1) for e in entities if (m := re.match(r"^/maps/((?:\\.|[^/\\])+)/", e))})
    timelines.discard("log_time")
    entry = entries[0] if entries else None
    return RecordingInfo(entry.application_id if entry else APP_ID, entry.recording_id if entry else None,
                         Contents(views, entities, timelines))


def recording_views(path: str | Path) -> list[str]:
    """View entity names (``maps/<view>/...``) in a recording; raises DeepCError if it is not one."""
    return recording_contents(path).contents.views


def choose_view(contents: Contents, name: str | None) -> str:
    """The view entity that ``name`` names: its image name (``img/0.png``), index (``3``) or entity name;
    the first view when ``name`` is None."""
    views = contents.views
    if not views:
        if name is not None:
            raise DeepCError(f"the recording holds no per-view maps, so --view {name} has nothing to show")
        return "none"
    if name is None:
        return views[0]
    for view in views:
        raw = view.replace("\\", "")
        index, _, image = raw.partition("_")
        if name in (view, raw, image) or (name.isdigit() and index.isdigit() and int(name) == int(index)):
            return view
    shown = ", ".join(view_title(v) for v in views[:8]) + (", ..." if len(views) > 8 else "")
    raise DeepCError(f"no view {name!r} in the recording (it holds {shown})")


def notes_file(path: str | Path, info: RecordingInfo, view: str, layout: str, folder: Path) -> Path | None:
    """A small recording with ``info``'s recording id holding ``about``, ``missing/...`` and (if the recording has
    none) ``legend`` text documents; None when the recording id is unknown."""
    import rerun as rr  # lazy: rerun

    if info.recording_id is None:
        return None
    target = folder / "notes.rrd"
    rec = rr.RecordingStream(info.application_id, recording_id=info.recording_id)
    rec.save(str(target))
    try:
        log_notes(rec, info.contents, view, layout, legend=not info.contents.has("/legend"))
    finally:
        rec.flush()
        rec.disconnect()
    return target


def layout_file(path: str | Path, layout: str, folder: Path, view: str | None = None) -> Path:
    """Write the blueprint ``layout`` for the recording at ``path`` and view ``view`` into ``folder``; returns the
    .rbl (the notes recording it refers to goes beside it: :func:`layout_files`)."""
    return layout_files(path, layout, folder, view)[0]


def replay_files(path: str | Path, layout: str | None, folder: Path, view: str | None = None,
                 compare: str | Path | None = None) -> list[Path]:
    """What the viewer opens: the recording with its layout's files, or (``compare``: a second recording) the two
    merged under ``/a`` and ``/b`` with the side-by-side layout (:mod:`workbench.rerun.compare`)."""
    if compare is not None:
        if layout is not None:
            raise DeepCError("--layout does not apply with --compare: its layout sets each map of A beside B's")
        return compare_files(path, compare, folder, view)
    return [Path(path), *layout_files(path, layout or default_layout(path), folder, view)]


def compare_files(path_a: str | Path, path_b: str | Path, folder: Path, view: str | None = None) -> list[Path]:
    """The recording of ``path_a`` and ``path_b`` merged under ``/a`` and ``/b``
    (:func:`workbench.rerun.compare.merge_recordings`) and its ``compare`` blueprint with ``view``'s tab open
    (default: the first view both hold), written into ``folder``; recordings without a view's maps in common are a
    :class:`DeepCError`."""
    from workbench.rerun.compare import merge_recordings  # lazy: rerun's chunk streams

    a, b = recording_contents(path_a), recording_contents(path_b)
    common = [v for v in a.contents.views if v in b.contents.views]
    if not common:
        raise DeepCError(f"{path_a} and {path_b} hold no view's maps in common (views are matched by entity name, "
                         "maps/<index>_<image>)")
    chosen = common[0] if view is None else choose_view(a.contents, view)
    if chosen not in common:
        raise DeepCError(f"view {view} is not in both recordings")
    merged = merge_recordings(path_a, path_b, folder / "compare.rrd", a.application_id)
    blueprint = folder / "compare.rbl"
    compare(a.contents, b.contents, chosen).save(a.application_id, str(blueprint))
    return [merged, blueprint]


def layout_files(path: str | Path, layout: str, folder: Path, view: str | None = None) -> list[Path]:
    """The blueprint ``.rbl`` of ``layout`` for ``view`` and the notes recording it shows."""
    if layout not in LAYOUTS:
        raise DeepCError(f"unknown layout {layout!r} (one of {', '.join(LAYOUTS)})")
    info = recording_contents(path)
    chosen = choose_view(info.contents, view)
    target = folder / f"{layout}.rbl"
    LAYOUTS[layout](info.contents, chosen).save(info.application_id, str(target))
    notes = notes_file(path, info, chosen, layout, folder)
    return [target] + ([notes] if notes else [])


#: busy ports tried after the requested one before giving up, as viser does for ``deepc view``
PORT_TRIES = 32


def free_port(host: str, port: int) -> int:
    """``port`` if it is free on ``host``, else the next free one (0 = any free port, chosen later); a port that
    cannot be bound for another reason, or no free port among the next ``PORT_TRIES``, is a one-line DeepCError."""
    if port == 0:
        return 0
    for candidate in range(port, port + PORT_TRIES):
        with socket.socket() as sock:
            try:
                sock.bind((host, candidate))
                return candidate
            except OSError as exc:
                if exc.errno != errno.EADDRINUSE:
                    raise DeepCError(f"cannot serve on {host}:{candidate}: {exc.strerror or exc}") from None
    raise DeepCError(f"ports {port}-{port + PORT_TRIES - 1} on {host} are all in use: pass --port N, or --port 0 "
                     "for any free port")


def _error_line(lines: list[str]) -> str:
    """The rerun viewer's own error from its output, without colour codes or log prefixes."""
    plain = [_ANSI.sub("", line).strip() for line in lines]
    errors = [line for line in plain if line.startswith("Error") or " ERROR " in f" {line} "]
    text = (errors or [line for line in plain if line][-1:] or ["no output"])[-1]
    return " ".join(text.split())[:200]


def default_layout(path: str | Path) -> str:
    """``iterations`` for a recording of PatchMatch iterations, ``probe`` for one of probed pixels only
    (``workbench/rerun/probe.py``), ``pipelines`` for one of results only."""
    entities = recording_contents(path).contents.entities or ()
    if any(e.startswith("/stats/") for e in entities):
        return "iterations"
    return "probe" if any(e.startswith("/probe/") for e in entities) else "pipelines"


class WebViewer:
    """A rerun web viewer on ``host``: serving one recording, or (``path=None``) waiting for a live
    stream at :attr:`grpc_url`. Use as a context manager or call stop()."""

    def __init__(self, path: str | Path | None = None, layout: str | None = None, host: str = "127.0.0.1",
                 port: int = 0, timeout: float = 60.0, view: str | None = None, compare: str | Path | None = None):
        self.port = free_port(host, port)
        self._tmp = tempfile.TemporaryDirectory(prefix="deepc-replay-")
        files = []
        try:
            if path is not None:  # validates the file before starting anything
                files = [str(Path(f).resolve())
                         for f in replay_files(path, layout, Path(self._tmp.name), view, compare)]
        except BaseException:
            self._tmp.cleanup()
            raise
        cmd = [str(rerun_binary()), "--serve-web", "--bind", host, "--port", "0", "--web-viewer-port", str(self.port),
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
                match = _URL.search(_ANSI.sub("", line))
                if match and not found:
                    found.append(match.group(1))
        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        deadline = time.monotonic() + timeout
        while not found and time.monotonic() < deadline and self.proc.poll() is None:
            time.sleep(0.05)
        if not found:
            reader.join(timeout=1)  # the last lines of a viewer that exited
            self.stop()
            raise DeepCError(f"the rerun web viewer did not start: {_error_line(lines)}")
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


def replay(path: str, layout: str | None = None, web: bool = False, host: str = "127.0.0.1", port: int = 9090,
           view: str | None = None, compare: str | None = None) -> int:
    """Blocking: open the native viewer, or serve the web viewer until Ctrl+C. The layout (default: iterations,
    or pipelines for a recording without iterations) is built for ``view`` (default: the first view);
    ``compare``: a second recording shown beside this one (:mod:`workbench.rerun.compare`)."""
    if has_display() and not web:
        with tempfile.TemporaryDirectory(prefix="deepc-replay-") as tmp:
            files = [str(f) for f in replay_files(path, layout, Path(tmp), view, compare)]
            return subprocess.call([str(rerun_binary()), *files])
    viewer = WebViewer(path, layout, host, port, view=view, compare=compare)
    if port and viewer.port != port:
        print(f"rerun web viewer: port {port} is in use; serving on port {viewer.port} instead", flush=True)
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
