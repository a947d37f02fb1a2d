"""Environment faults: read-only or full output folder, unreadable scene files, a file removed mid-run.

Each ends in one `deepc: error:` line naming the file, exit status 2, no traceback, and no partial file.
The folder faults are real (a tmpfs mounted read-only or with 64 KiB); the permission fault runs the
command without root's override of file permissions (setpriv). Both need root, as on the CI machine,
and are skipped otherwise.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import SAMPLES

from engine.run.checkpoint import CHECKPOINT_DIR
from support.interruption import FAST, check_no_partial, kill_when, saved_states, start_run

REPO = Path(__file__).resolve().parent.parent
needs_root = pytest.mark.skipif(os.geteuid() != 0, reason="mounting a tmpfs and switching user need root")


def _one_line_error(code: int, err: str, *fragments: str) -> str:
    lines = [line for line in err.splitlines() if line.strip() and not line.startswith("deepc: warning")
             and "view/s" not in line and "%|" not in line]
    errors = [line for line in lines if line.startswith("deepc: error: ")]
    assert code == 2 and len(errors) == 1 and "Traceback" not in err, err[-2000:]
    for fragment in fragments:
        assert fragment in errors[0], errors[0]
    return errors[0]


def deepc(*args: str, without_root_override: bool = False, timeout: float = 300) -> subprocess.CompletedProcess:
    """``deepc ARGS``; ``without_root_override`` drops root's right to ignore file permissions (setpriv)."""
    env = {**os.environ, "PYTHONPATH": str(REPO), "NUMBA_THREADING_LAYER": "workqueue"}
    prefix = ["setpriv", "--bounding-set", "-dac_override,-dac_read_search"] if without_root_override else []
    return subprocess.run([*prefix, sys.executable, "-m", "workbench.cli", *map(str, args)], capture_output=True,
                          text=True, timeout=timeout, env=env, cwd=REPO)


@contextlib.contextmanager
def tmpfs(path: Path, options: str):
    path.mkdir(parents=True, exist_ok=True)
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(path)], capture_output=True)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs: {mounted.stderr.decode().strip()}")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], check=False)


@needs_root
def test_read_only_output_folder(tmp_path):
    with tmpfs(tmp_path / "ro", "ro,size=1m") as ro:
        result = deepc("run", SAMPLES / "tiny", "--out", ro / "out", "--headless", *FAST)
        _one_line_error(result.returncode, result.stderr, str(ro / "out"), "Read-only file system")
        assert not any(ro.iterdir())


@needs_root
def test_full_output_folder_leaves_nothing_partial(tmp_path):
    with tmpfs(tmp_path / "full", "size=64k") as full:
        out = full / "out"
        result = deepc("run", SAMPLES / "tiny", "--out", out, "--headless", *FAST)
        _one_line_error(result.returncode, result.stderr, str(out), "No space left on device")
        check_no_partial(out)  # nothing half-written, no temporary file left


@needs_root
@pytest.mark.skipif(shutil.which("setpriv") is None, reason="needs setpriv (util-linux)")
def test_unreadable_scene_files_name_the_file(tmp_path):
    scene = tmp_path / "tiny"
    shutil.copytree(SAMPLES / "tiny", scene, ignore=shutil.ignore_patterns("ground_truth"))
    image = scene / "images" / "view_002.png"
    image.chmod(0)
    result = deepc("info", scene, without_root_override=True)
    _one_line_error(result.returncode, result.stderr, "view_002.png", "ermission denied")
    image.chmod(0o644)
    model = scene / "sparse" / "images.txt"
    model.chmod(0)
    result = deepc("info", scene, without_root_override=True)
    _one_line_error(result.returncode, result.stderr, "images.txt", "ermission denied")


def test_ground_truth_removed_mid_run_is_a_clear_error_and_resumable(tmp_path):
    scene = tmp_path / "tiny"
    shutil.copytree(SAMPLES / "tiny", scene)
    out = tmp_path / "out"
    proc = start_run(scene, out)
    gt = scene / "ground_truth" / "points.ply"
    moved = tmp_path / "points.ply"

    def remove_when_patchmatch_started() -> bool:
        if saved_states(out) >= 1 and gt.exists():
            gt.rename(moved)
        return False  # never kill: let the run meet the missing file

    code, err = kill_when(proc, remove_when_patchmatch_started, 0)
    _one_line_error(code, err, "points.ply", "not found")
    check_no_partial(out)
    assert not (out / "metrics.json").exists() and (out / CHECKPOINT_DIR / "manifest.json").is_file()
    moved.rename(gt)
    proc = start_run(scene, out, "--resume")
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    assert (out / "metrics.json").is_file() and not (out / CHECKPOINT_DIR).exists()


def test_weights_removed_mid_run_do_not_end_the_run(tmp_path):
    """The confidence weights are loaded and checked before PatchMatch and kept in memory: a weights file
    deleted, or replaced by garbage, while PatchMatch runs cannot end a long run at its last stage."""
    from engine.confidence.weights import DEFAULT_WEIGHTS

    weights = tmp_path / "copy.pt"
    shutil.copyfile(DEFAULT_WEIGHTS, weights)
    out = tmp_path / "out"
    proc = start_run(SAMPLES / "tiny", out, "--pipeline", "fast", "--weights", str(weights))

    def garble_when_patchmatch_started() -> bool:
        if saved_states(out) >= 1 and weights.exists():
            weights.unlink()
            (tmp_path / "copy.pt.partial").write_bytes(b"garbage")
            (tmp_path / "copy.pt.partial").rename(weights)  # a half-copied file where the weights were
        return False

    code, err = kill_when(proc, garble_when_patchmatch_started, 0)
    assert code == 0 and "Traceback" not in err, err[-2000:]
    assert weights.read_bytes() == b"garbage"  # the fault really happened during the run
    check_no_partial(out)
    metrics = json.loads((out / "metrics.json").read_text())
    confidence_maps = list(out.glob("stereo/confidence_maps/*.bin"))
    assert metrics["pipeline"] == "fast" and len(confidence_maps) == metrics["num_images"]
    # the next run refuses the damaged file at once, with one line naming it, and writes nothing
    result = deepc("run", SAMPLES / "tiny", "--out", tmp_path / "out2", "--headless", *FAST, "--pipeline", "fast",
                   "--weights", weights)
    _one_line_error(result.returncode, result.stderr, str(weights), "not a readable weights file")
    assert not (tmp_path / "out2").exists()
