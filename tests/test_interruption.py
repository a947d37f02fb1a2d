"""`deepc run` killed with SIGINT/SIGTERM at several moments: no partial file, and --resume ends identical."""

from __future__ import annotations

import json
import random
import signal
import time

import pytest
from conftest import SAMPLES

from engine.run.checkpoint import CHECKPOINT_DIR
from support.interruption import check_no_partial, differences, kill_when, saved_states, start_run

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("reference")
    proc = start_run(SAMPLES / "tiny", out)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    assert not (out / CHECKPOINT_DIR).exists()  # a finished run leaves no saved states
    return out


# (signal, moment): states saved by the checkpoint before the kill, or "writing" = first map written
# "writing" lands in the map writes or the fusion kernel: a SIGTERM there used to crash the process
# (SIGSEGV: the handler raised inside numba's boxing of the kernel's result, see engine/core/interrupt.py)
MOMENTS = [(signal.SIGTERM, 3), (signal.SIGINT, 14), (signal.SIGTERM, "writing")]


@pytest.mark.parametrize(("sig", "moment"), MOMENTS, ids=["SIGTERM-3", "SIGINT-14", "SIGTERM-writing"])
def test_interrupted_run_leaves_no_partial_file_and_resumes_identically(reference, tmp_path, sig, moment):
    out = tmp_path / "out"
    rng = random.Random(f"{sig}-{moment}")
    if moment == "writing":
        def condition():
            return any((out / "stereo" / "depth_maps").glob("*.bin"))
    else:
        def condition():
            return saved_states(out) >= moment
    code, err = kill_when(start_run(SAMPLES / "tiny", out), condition, sig, delay=rng.uniform(0, 0.05))
    if moment != "writing":  # PatchMatch takes seconds: the kill must land inside it
        assert code == 130 and "deepc: interrupted" in err and "Traceback" not in err, err
    assert code in (0, 130), err
    check_no_partial(out)
    if code == 130 and moment != "writing":
        assert saved_states(out) >= moment  # the checkpoint still lists the states saved before the kill

    stale = out / "stereo" / ".depth.bin.abcd1234.tmp"  # what a SIGKILL would leave: the resume removes it
    stale.parent.mkdir(parents=True, exist_ok=True)
    stale.write_bytes(b"half")
    proc = start_run(SAMPLES / "tiny", out, "--resume")
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    assert "removed 1 temporary file" in err and not stale.exists()
    if code == 130 and moment != "writing":
        assert "saved PatchMatch view states reused, 0 rejected" in err
    assert differences(reference, out) == []
    assert not (out / CHECKPOINT_DIR).exists()



# one level of tiny at 160x120 with a dense 41x41 window: one initial cost or half-step call over a whole view took
# 2.4 s (from random hypotheses) on the 2-core machine at a load average of 15, about 0.2 s at 5; the calls of a
# real size are longer (benchmarks/reliability/bench_stop_latency.py: 8.9 s for a 768x512 half-step under load)
SLOW_KERNELS = ["--max-image-size", "160", "--levels", "1", "--geom-passes", "0", "--iterations", "1",
                "--set", "patchmatch.window=41", "--set", "patchmatch.window_step=1"]


def test_sigint_during_a_long_kernel_stops_within_two_seconds_and_resumes_identically(tmp_path):
    """The kernels run as row blocks of ~0.5 s (engine/core/blocks.py): a SIGINT that lands in a view's
    kernels ends the run within 2 s (the process's exit included), and --resume then finishes with the maps of an
    uninterrupted run."""
    reference, out = tmp_path / "reference", tmp_path / "out"
    proc = start_run(SAMPLES / "tiny", reference, *SLOW_KERNELS)
    _, err = proc.communicate(timeout=900)
    assert proc.returncode == 0, err
    seconds = json.loads((reference / "metrics.json").read_text())["seconds"]["patchmatch"]
    per_call = seconds / (5 * 3)  # 5 views x (initial cost + 2 half-steps), counter maps included
    proc = start_run(SAMPLES / "tiny", out, *SLOW_KERNELS)
    deadline = time.monotonic() + 900
    while saved_states(out) < 1 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.005)
    time.sleep(0.6 * per_call)  # inside the next view's kernels
    assert proc.poll() is None
    sent = time.monotonic()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    latency = time.monotonic() - sent
    assert proc.returncode == 130 and "deepc: interrupted" in err and "Traceback" not in err, err
    assert latency < 2.0, f"stopped {latency:.2f} s after SIGINT (one kernel call: {per_call:.1f} s on average)"
    check_no_partial(out)
    proc = start_run(SAMPLES / "tiny", out, *SLOW_KERNELS, "--resume")
    _, err = proc.communicate(timeout=900)
    assert proc.returncode == 0, err
    assert "saved PatchMatch view states reused, 0 rejected" in err
    assert differences(reference, out) == []
