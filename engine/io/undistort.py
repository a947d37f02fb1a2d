"""Undistortion of non-pinhole COLMAP workspaces with pycolmap, in a child process, into a cache.

pycolmap's image undistorter can end its process with a native abort (an uncaught C++ exception in its thread pool,
e.g. when an image's size disagrees with its camera), and it logs a line per image on stderr. So it runs in a child
(``python -m engine.io.undistort``) whose stdout and stderr go to a log file; a non-zero exit or a signal becomes one
:class:`DeepCError` line naming the workspace and the log.

The cache cannot be left half-written: the child writes into a temporary folder ``.undistort-*`` beside the cache
entries, holding ``owner.json`` (the pid and start time of the process that made it); the folder is renamed into
place only once complete. A folder whose owner is gone (SIGKILL, power loss) is removed by the next
:func:`undistort_workspace`; the child dies with its parent (``PR_SET_PDEATHSIG``), so it cannot outlive it.

The undistorted camera of each model (COLMAP's ``UndistortCamera``: the largest undistorted image inside the
distorted one, at most ``max_image_size`` on its longer side) is computed without pixels by
:func:`undistorted_camera`, so that a scene can be described, and checked, before any image is undistorted.
"""

from __future__ import annotations

import ctypes
import hashlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from engine.core.errors import DeepCError
from engine.io.colmap_model import SparseCamera, import_pycolmap

TEMP_PREFIX = ".undistort-"
OWNER_FILE = "owner.json"
LOG_FILE = "undistort.log"
_FRESH_SECONDS = 60.0  # a temporary folder without an owner file younger than this may be being made
_PROGRESS = re.compile(rb"Undistorting image \[(\d+)/(\d+)\]")
# the prefixes of a log line: glog's (severity, time, thread, file:line) and pycolmap's exception ([file:line])
_GLOG_PREFIX = re.compile(r"^(?:[IWEF]\d{8} [\d:.]+ +\d+ [\w.]+:\d+\] )?(?:\w+: )?(?:\[[\w.]+:\d+\] )?")


def undistorted_camera(camera: SparseCamera, max_image_size: int = 0) -> SparseCamera:
    """The PINHOLE camera pycolmap's undistorter gives ``camera`` (at most ``max_image_size`` px; 0 = any size)."""
    pycolmap = import_pycolmap()

    options = pycolmap.UndistortCameraOptions(max_image_size=max_image_size if max_image_size > 0 else -1)
    source = pycolmap.Camera(model=camera.model, width=camera.width, height=camera.height,
                             params=list(camera.params), camera_id=camera.camera_id)
    result = pycolmap.undistort_camera(options, source)
    return SparseCamera(camera.camera_id, result.model.name, int(result.width), int(result.height),
                        np.array(result.params, np.float64))


def cache_key(scene_root: Path, model_dir: Path, image_names: Sequence[str], max_image_size: int) -> str:
    """Name of a workspace's cache entry: the scene's name and a digest of the model's files, the registered images'
    sizes and modification times, and the working size."""
    digest = hashlib.sha1()
    for name in sorted(os.listdir(model_dir)):
        digest.update(name.encode())
        digest.update((model_dir / name).read_bytes() if (model_dir / name).is_file() else b"")
    for name in image_names:
        try:
            stat = (scene_root / "images" / name).stat()
            digest.update(f"{name}\0{stat.st_size}\0{stat.st_mtime_ns}\0".encode())
        except OSError:
            digest.update(f"{name}\0missing\0".encode())
    digest.update(f"max_image_size={max_image_size}".encode())
    return f"{scene_root.resolve().name}-{digest.hexdigest()[:12]}"


def cached_workspace(cache_root: Path, key: str) -> Path | None:
    """The complete cache entry ``key``, or None."""
    target = Path(cache_root) / key
    return target if (target / "sparse").is_dir() and (target / "images").is_dir() else None


def _start_time(pid: int) -> str | None:
    """The process's start time (clock ticks since boot, /proc/PID/stat field 22), or None if it is gone (or a
    zombie: dead, not yet reaped)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return None if fields[0] in ("Z", "X") else fields[19]


def _alive(owner: dict) -> bool:
    pid, start = owner.get("pid"), owner.get("start")
    if not isinstance(pid, int) or pid <= 0:
        return False
    now = _start_time(pid)
    if now is None:
        if Path("/proc/self/stat").exists():
            return False
        try:  # no /proc: the pid alone
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        except PermissionError:
            return True
        return True
    return start is None or now == start


def _write_owner(folder: Path, child: int | None = None) -> None:
    """Record in ``folder`` the processes that write it: this one and its child."""
    owner = {"pid": os.getpid(), "start": _start_time(os.getpid())}
    if child is not None:
        owner.update(child=child, child_start=_start_time(child))
    tmp = folder / f".{OWNER_FILE}.new"
    tmp.write_text(json.dumps(owner))
    os.replace(tmp, folder / OWNER_FILE)


def remove_stale_temporaries(cache_root: Path) -> list[Path]:
    """Remove the temporary folders under ``cache_root`` whose owner process is gone; returns them."""
    removed = []
    try:
        entries = list(Path(cache_root).glob(f"{TEMP_PREFIX}*"))
    except OSError:
        return removed
    for folder in entries:
        if not folder.is_dir():
            continue
        try:
            owner = json.loads((folder / OWNER_FILE).read_text())
            owner = owner if isinstance(owner, dict) else {}
            stale = not _alive(owner) and not _alive({"pid": owner.get("child"), "start": owner.get("child_start")})
        except (OSError, ValueError):  # no owner file: from an older deepc, or just being made
            try:
                stale = time.time() - folder.stat().st_mtime > _FRESH_SECONDS
            except OSError:
                continue
        if stale:
            shutil.rmtree(folder, ignore_errors=True)
            removed.append(folder)
    return removed


def _describe_exit(code: int) -> str:
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit status {code}"


def _last_error(log: Path) -> str:
    """The last line of the child's log that reads like an error (glog's E/F lines, a Python exception)."""
    try:
        lines = log.read_text(errors="replace").splitlines()
    except OSError:
        return ""
    for line in reversed(lines):
        text = line.strip()
        if text[:1] in ("E", "F") and "]" in text[:60] or "Error" in text or "error" in text or "what()" in text:
            return _GLOG_PREFIX.sub("", " ".join(text.split()))[:200]
    return ""


def undistort_workspace(scene_root: Path, model_dir: Path, cache_root: Path, *, key: str, max_image_size: int = 0,
                        progress: Callable[[int, int], None] | None = None, poll: float = 0.2) -> Path:
    """Undistort ``scene_root`` (model in ``model_dir``, images in ``images/``) into ``cache_root/key``; returns it.

    A complete entry is reused. Otherwise the child undistorts into a temporary folder, renamed when complete;
    ``progress(done, total)`` follows pycolmap's log. Any failure, Ctrl+C included, removes the temporary folder.
    Raises :class:`DeepCError` naming the workspace when the child fails.
    """
    cache_root = Path(cache_root)
    done = cached_workspace(cache_root, key)
    if done is not None:
        return done
    try:
        cache_root.mkdir(parents=True, exist_ok=True)
        remove_stale_temporaries(cache_root)
        tmp = Path(tempfile.mkdtemp(prefix=TEMP_PREFIX, dir=cache_root))
    except OSError as exc:
        raise DeepCError(f"cannot write the undistortion cache: {exc.strerror or exc}", cache_root) from None
    failed_log = cache_root / f"{key}.failed.log"
    child = None
    try:
        _write_owner(tmp)
        log = tmp / LOG_FILE
        env = dict(os.environ)
        package_root = str(Path(__file__).resolve().parents[2])  # the folder holding engine/
        env["PYTHONPATH"] = os.pathsep.join([package_root] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
        command = [sys.executable, "-m", "engine.io.undistort", str(tmp / "out"), str(model_dir),
                   str(scene_root / "images"), str(max_image_size), str(os.getpid())]
        with open(log, "wb") as sink:
            child = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=sink, stderr=subprocess.STDOUT, env=env)
        _write_owner(tmp, child.pid)
        seen = (0, 0)
        while child.poll() is None:
            time.sleep(poll)
            seen = _report_progress(log, seen, progress)
        _report_progress(log, seen, progress)
        if child.returncode != 0 or not (tmp / "out" / "sparse").is_dir():
            shutil.copyfile(log, failed_log)
            reason = _last_error(log)
            raise DeepCError(f"undistortion with pycolmap failed ({_describe_exit(child.returncode)}"
                             f"{': ' + reason if reason else ''}; its log: {failed_log})", scene_root)
        out = tmp / "out"
        shutil.move(log, out / LOG_FILE)
        shutil.rmtree(out / "stereo", ignore_errors=True)
        for script in out.glob("run-colmap-*.sh"):
            script.unlink()
        target = cache_root / key
        try:
            os.replace(out, target)
        except OSError:
            if cached_workspace(cache_root, key) is None:  # not another process's complete entry: a real failure
                raise
    except OSError as exc:
        raise DeepCError(f"cannot write the undistortion cache: {exc.strerror or exc}", cache_root) from None
    finally:
        if child is not None and child.poll() is None:  # Ctrl+C, SIGTERM: the child goes with us
            child.kill()
            child.wait()
        shutil.rmtree(tmp, ignore_errors=True)
    failed_log.unlink(missing_ok=True)
    return cache_root / key


def _report_progress(log: Path, seen: tuple[int, int], progress: Callable[[int, int], None] | None) -> tuple[int, int]:
    """Call ``progress`` with the last "Undistorting image [k/N]" of the log when it moved on."""
    if progress is None:
        return seen
    try:
        with open(log, "rb") as handle:
            handle.seek(max(0, os.path.getsize(log) - 4096))
            matches = _PROGRESS.findall(handle.read())
    except OSError:
        return seen
    if matches:
        now = (int(matches[-1][0]), int(matches[-1][1]))
        if now != seen:
            progress(*now)
            return now
    return seen


def _die_with_parent(parent: int) -> None:
    """Ask Linux to SIGKILL this process when its parent dies (``PR_SET_PDEATHSIG``); exit if it already has."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL, 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent:
        sys.exit(3)


def main(argv: Sequence[str] | None = None) -> int:
    """Child: ``python -m engine.io.undistort OUT MODEL_DIR IMAGE_DIR MAX_IMAGE_SIZE PARENT_PID``."""
    out, model_dir, image_dir, max_size, parent = list(sys.argv[1:] if argv is None else argv)
    _die_with_parent(int(parent))
    pycolmap = import_pycolmap()

    options = pycolmap.UndistortCameraOptions(max_image_size=int(max_size) if int(max_size) > 0 else -1)
    pycolmap.undistort_images(out, model_dir, image_dir, undistort_options=options)
    return 0


if __name__ == "__main__":
    sys.exit(main())
