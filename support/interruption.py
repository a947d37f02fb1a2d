"""Kill `deepc run` at chosen moments and check what it leaves behind.

Used by the tests and by benchmarks/reliability/bench_interrupt.py.

A run is started in its own session with SIGINT at its default disposition (a background child may
inherit it ignored); :func:`kill_when` sends SIGINT or SIGTERM once a condition on the output folder
holds (e.g. "the checkpoint lists 7 view states", "the first depth map exists") plus a delay.
:func:`check_no_partial` asserts the folder holds only complete files; :func:`differences` compares two
output folders byte for byte (metrics.json without its timings).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

from engine.core.errors import DeepCError
from engine.io.dense import read_dense_map
from engine.io.ply import read_ply
from engine.run.checkpoint import CHECKPOINT_DIR

REPO = Path(__file__).resolve().parent.parent
# tiny scene, fast schedule: 2 levels x (photometric + 1 geometric) x 1 iteration, 5 views of 96x72
FAST = ["--max-image-size", "96", "--levels", "2", "--geom-passes", "1", "--iterations", "1", "--seed", "5"]


def start_run(scene: Path, out: Path, *extra: str) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(REPO), "NUMBA_THREADING_LAYER": "workqueue"}
    return subprocess.Popen([sys.executable, "-m", "workbench.cli", "run", str(scene), "--out", str(out),
                             "--headless", *FAST, *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env, cwd=REPO, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def saved_states(out: Path) -> int:
    """View-pass states the running `deepc run` has saved so far (0 when unreadable or absent)."""
    try:
        return int(json.loads((out / CHECKPOINT_DIR / "manifest.json").read_text()).get("saved_by_this_run", 0))
    except (OSError, ValueError):
        return 0


def kill_when(proc: subprocess.Popen, condition: Callable[[], bool], sig: int, delay: float = 0.0,
              timeout: float = 300.0) -> tuple[int, str]:
    """Send ``sig`` ``delay`` s after ``condition()`` first holds; returns (exit status, stderr)."""
    deadline = time.monotonic() + timeout
    while proc.poll() is None and not condition():
        if time.monotonic() > deadline:
            proc.kill()
            raise TimeoutError("the run never reached the moment to interrupt it")
        time.sleep(0.005)
    time.sleep(delay)
    if proc.poll() is None:
        proc.send_signal(sig)
    _, err = proc.communicate(timeout=timeout)
    return proc.returncode, err


def check_no_partial(out: Path) -> int:
    """Every file under ``out`` is complete (maps and PLY parse, JSON parses); no temporary file is left.
    Returns the number of files checked; raises AssertionError naming a bad file."""
    checked = 0
    for path in sorted(p for p in out.rglob("*") if p.is_file()):
        assert not path.name.endswith(".tmp"), f"temporary file left behind: {path}"
        try:
            if path.suffix == ".bin":
                read_dense_map(path)
            elif path.suffix == ".ply":
                read_ply(path)
            elif path.suffix == ".json":
                json.loads(path.read_text())
        except (DeepCError, ValueError) as exc:
            raise AssertionError(f"partial or corrupt file after interruption: {exc}") from None
        checked += 1
    return checked


def differences(reference: Path, out: Path) -> list[str]:
    """Files that differ between two run folders (checkpoint folder ignored; metrics without seconds and without the
    PatchMatch work this process did, which a resumed run counts only for the passes it recomputed; the probe's
    recorded states, ``history/states/``, ignored: a cache keyed on the history files' times, which a resumed run
    holds only for the views it ran whole, and the first probe of a view makes the others)."""
    def files(root: Path) -> set[str]:
        return {str(p.relative_to(root)) for p in root.rglob("*") if p.is_file() and CHECKPOINT_DIR not in p.parts
                and p.relative_to(root).parts[:2] != ("history", "states")}

    names = files(reference) | files(out)
    diff = []
    for name in sorted(names):
        a, b = reference / name, out / name
        if not (a.is_file() and b.is_file()):
            diff.append(f"{name} (missing)")
        elif name == "metrics.json":
            ma, mb = json.loads(a.read_text()), json.loads(b.read_text())
            for m in (ma, mb):
                m.pop("seconds", None)
                m.pop("patchmatch_early_stops", None)
            if ma != mb:
                diff.append(name)
        elif a.read_bytes() != b.read_bytes():
            diff.append(name)
    return diff
