"""The undistortion child and its cache (issue 46): a native abort, a killed child, a killed or interrupted parent
leave no temporary folder behind (or one the next load removes), and the next load succeeds."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from conftest import REPO, SAMPLES

from engine.core.errors import DeepCError
from engine.io.undistort import TEMP_PREFIX, remove_stale_temporaries, undistort_workspace
from engine.scene import SceneOptions, load_scene
from support.colmap_workspaces import write_workspace

LOAD = ("import sys\nfrom engine.scene import SceneOptions, load_scene\ntry:\n"
        "    load_scene(sys.argv[1], SceneOptions(cache_dir=sys.argv[2]))\nexcept KeyboardInterrupt:\n"
        "    sys.exit(130)\n")


@pytest.fixture
def large(tmp_path) -> Path:
    """The tiny sample at 640x480 with SIMPLE_RADIAL cameras: undistortion outlasts the start of its child."""
    return write_workspace(SAMPLES / "tiny", tmp_path / "ws", scale=4)


def _temporaries(cache: Path) -> list[Path]:
    return list((cache / "undistorted").glob(f"{TEMP_PREFIX}*"))


def _wait_for_child(cache: Path, timeout: float = 60) -> dict:
    """The owner record of the running undistortion, once its child has started."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for folder in _temporaries(cache):
            try:
                owner = json.loads((folder / "owner.json").read_text())
            except (OSError, ValueError):
                continue
            if "child" in owner:
                return owner
        time.sleep(0.02)
    raise AssertionError("no undistortion child started")


def _gone(pid: int, timeout: float = 10) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            return True
        if state in ("Z", "X"):
            return True
        time.sleep(0.05)
    return False


def test_parent_killed_mid_undistortion_leaves_a_folder_the_next_load_removes(large, tmp_path):
    cache = tmp_path / "cache"
    parent = subprocess.Popen([sys.executable, "-c", LOAD, str(large), str(cache)], cwd=REPO,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        owner = _wait_for_child(cache)
    finally:
        parent.kill()
        parent.wait()
    assert _gone(owner["child"])  # the child dies with its parent
    assert len(_temporaries(cache)) == 1  # what SIGKILL leaves
    lines = []
    scene = load_scene(large, SceneOptions(cache_dir=str(cache)), report=lines.append)
    assert len(scene.views) == 5 and scene.image(0).shape[2] == 3
    assert _temporaries(cache) == [] and "undistorted 5 images" in lines[-1]


def test_child_killed_mid_undistortion_is_one_line_and_leaves_nothing(large, tmp_path):
    cache = tmp_path / "cache"
    errors = []

    def load() -> None:
        try:
            load_scene(large, SceneOptions(cache_dir=str(cache)), report=lambda line: None)
        except DeepCError as exc:
            errors.append(str(exc))

    thread = threading.Thread(target=load)
    thread.start()
    os.kill(_wait_for_child(cache)["child"], signal.SIGKILL)
    thread.join(60)
    assert len(errors) == 1 and "\n" not in errors[0]
    assert errors[0].startswith(f"{large}: undistortion with pycolmap failed (killed by SIGKILL")
    assert _temporaries(cache) == []
    assert len(load_scene(large, SceneOptions(cache_dir=str(cache)), report=lambda line: None).views) == 5


def test_interrupted_parent_removes_its_folder_and_child(large, tmp_path):
    cache = tmp_path / "cache"
    # at full size: at the working size the undistortion can end before the signal lands (a race on a busy machine)
    full = LOAD.replace("SceneOptions(cache_dir=sys.argv[2])", "SceneOptions(cache_dir=sys.argv[2], max_image_size=0)")
    parent = subprocess.Popen([sys.executable, "-c", full, str(large), str(cache)], cwd=REPO,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    owner = _wait_for_child(cache)
    parent.send_signal(signal.SIGINT)
    assert parent.wait(60) == 130, parent.stderr.read()
    assert _gone(owner["child"], 1) and _temporaries(cache) == []


def test_native_abort_of_pycolmap_becomes_one_line(tmp_path):
    # images 160x120, cameras 480x360: pycolmap's thread pool aborts (SIGABRT) or raises, by timing
    workspace = write_workspace(SAMPLES / "tiny", tmp_path / "ws", camera_factor=3.0)
    cache = tmp_path / "cache"
    with pytest.raises(DeepCError) as info:
        undistort_workspace(workspace, workspace / "sparse", cache, key="mismatch")
    text = str(info.value)
    assert "\n" not in text and text.startswith(f"{workspace}: undistortion with pycolmap failed (")
    assert ("SIGABRT" in text or "exit status 1" in text) and "mismatch.failed.log" in text
    assert sorted(p.name for p in cache.iterdir()) == ["mismatch.failed.log"]


def test_only_folders_of_gone_processes_are_stale(tmp_path):
    alive, dead, fresh = (tmp_path / f"{TEMP_PREFIX}{name}" for name in ("alive", "dead", "fresh"))
    for folder in (alive, dead, fresh):
        folder.mkdir()
    (alive / "owner.json").write_text(json.dumps({"pid": os.getpid()}))
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    (dead / "owner.json").write_text(json.dumps({"pid": gone.pid, "child": gone.pid}))
    assert remove_stale_temporaries(tmp_path) == [dead]  # "fresh" has no owner yet: kept for a minute
    old = time.time() - 3600
    os.utime(fresh, (old, old))
    assert remove_stale_temporaries(tmp_path) == [fresh] and alive.is_dir()
