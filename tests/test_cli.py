"""The deepc command line: subcommands, help, exit codes, one-line errors."""

from __future__ import annotations

import shutil
import subprocess
import sys

import pytest
from conftest import SAMPLES

SUBCOMMANDS = ["run", "eval", "view", "replay", "regress", "train"]


def deepc(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "workbench.cli", *map(str, args)], capture_output=True,
                          text=True, timeout=timeout)


def test_help_lists_every_subcommand():
    result = deepc("--help")
    assert result.returncode == 0
    for name in SUBCOMMANDS:
        assert f"    {name} " in result.stdout


@pytest.mark.parametrize("name", SUBCOMMANDS + ["info"])
def test_each_subcommand_has_help(name):
    result = deepc(name, "--help")
    assert result.returncode == 0 and "usage: deepc " + name in result.stdout


def test_run_help_shows_the_contract_flags():
    text = deepc("run", "--help").stdout
    for flag in ("--out", "--pipeline", "--max-image-size", "--num-source-views", "--schedule", "--iterations",
                 "--seed", "--record", "--headless"):
        assert flag in text


def test_info_prints_the_views(tmp_path):
    result = deepc("info", SAMPLES / "middlebury_temple", "--max-image-size", "160")
    assert result.returncode == 0, result.stderr
    assert "16 views" in result.stdout and "160x120" in result.stdout


def _one_line_error(result: subprocess.CompletedProcess, *fragments: str) -> None:
    assert result.returncode == 2, (result.stdout, result.stderr)
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("deepc: error: "), result.stderr
    assert "Traceback" not in result.stderr
    for fragment in fragments:
        assert fragment in lines[0]


def test_bad_scene_gives_exit_2_and_one_line(tmp_path):
    scene = tmp_path / "temple"
    shutil.copytree(SAMPLES / "middlebury_temple", scene)
    (scene / "images" / "templeSR0007.png").unlink()
    _one_line_error(deepc("info", scene), "templeSR0007.png", "missing")
    out = tmp_path / "out"
    _one_line_error(deepc("run", scene, "--out", out, "--headless"), "templeSR0007.png")
    assert not out.exists()  # nothing written for a scene that failed to load


def test_bad_option_values_give_exit_2(tmp_path):
    _one_line_error(deepc("info", SAMPLES / "middlebury_temple", "--num-source-views", "0"), "num_source_views")
    _one_line_error(deepc("info", SAMPLES / "middlebury_temple", "--depth-range", "3,1"), "depth_range")
    result = deepc("info", SAMPLES / "middlebury_temple", "--depth-range", "x")
    assert result.returncode == 2 and "--depth-range" in result.stderr


def test_set_refuses_unknown_stages_and_options(tmp_path):
    base = ["run", SAMPLES / "tiny", "--out", tmp_path / "o", "--headless"]
    _one_line_error(deepc(*base, "--set", "nonsense.x=1"), "unknown stage")
    _one_line_error(deepc(*base, "--set", "patchmatch.tua0=1"), "tua0")
    _one_line_error(deepc(*base, "--set", "stream.every=0"), "every")
    assert not (tmp_path / "o").exists()


def test_view_and_replay_refuse_bad_paths(tmp_path):
    _one_line_error(deepc("view", tmp_path), "neither")
    _one_line_error(deepc("replay", tmp_path / "missing.rrd"), "not found")
    (tmp_path / "bad.rrd").write_bytes(b"garbage")
    _one_line_error(deepc("replay", tmp_path / "bad.rrd", "--web"), "bad.rrd")


def test_eval_prints_the_table_and_writes_json(tmp_path):
    import json

    import numpy as np

    from engine.io.ply import write_ply
    rng = np.random.default_rng(0)
    gt = rng.uniform(0, 1, (4000, 3))
    write_ply(tmp_path / "gt.ply", gt)
    write_ply(tmp_path / "rec.ply", gt[:2000] + rng.normal(0, 0.002, (2000, 3)), coordinate_dtype="f8")
    result = deepc("eval", tmp_path / "rec.ply", tmp_path / "gt.ply", "--tolerances", "0.01,0.05",
                   "--json", tmp_path / "out.json")
    assert result.returncode == 0, result.stderr
    assert "F1" in result.stdout
    scores = json.loads((tmp_path / "out.json").read_text())
    assert scores["tolerances"] == [0.01, 0.05]
    assert scores["accuracy"][1] > 95 and 40 < scores["completeness"][0] < 65  # half the GT is covered
    _one_line_error(deepc("eval", tmp_path / "rec.ply", tmp_path / "gt.ply", "--tolerances", "0,-1"), "toleran")


def test_run_writes_the_contract_outputs_and_a_recording(tmp_path):
    """The run folder and metrics.json on the tiny scene with a short schedule (the quality tests use the full one)."""
    import json

    from rerun.chunk import RrdReader

    from engine.io.dense import read_dense_map
    out = tmp_path / "out"
    result = deepc("run", SAMPLES / "tiny", "--out", out, "--headless", "--record", "--iterations", "2",
                   "--levels", "2", "--geom-passes", "1", timeout=600)
    assert result.returncode == 0, result.stderr[-2000:]
    names = [f"view_{i:03d}.png" for i in range(5)]
    for kind, channels in (("depth", 1), ("normal", 3), ("cost", 1), ("counter", 1)):
        for name in names:
            array = read_dense_map(out / "stereo" / f"{kind}_maps" / f"{name}.bin")
            assert array.shape[:2] == (120, 160) and (array.ndim == 2) == (channels == 1)
    assert (out / "fused.ply").stat().st_size > 1000
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["scene"] == "tiny" and metrics["pipeline"] == "vanilla" and metrics["num_images"] == 5
    assert metrics["image_size"] == [160, 120] and metrics["fused_points"] > 1000
    assert set(metrics["seconds"]) >= {"patchmatch", "confidence", "refinement", "fusion", "total"}
    assert set(metrics["depth"]) >= {"abs_rel", "within_1pct", "within_5pct", "valid_fraction"}
    assert metrics["eval"]["tolerances"] == [0.01, 0.02, 0.05, 0.1, 0.2, 0.5]
    assert len(metrics["eval"]["f1"]) == 6 and metrics["eval"]["f1"][2] > 30
    # the working size (tiny is under the default's floor: full size, saved as 0) and the per-view shares
    assert "working size: 160×120 px, full size (default" in result.stderr
    assert metrics["options"]["scene"]["max_image_size"] == 0
    assert [v["view"] for v in metrics["views"]] == names
    for v in metrics["views"]:
        assert 0 <= v["fused_pct"] <= 100 and 0 <= v["confirmed_pct"] <= 100 and v["pixels"] == 160 * 120
    assert sum(round(v["fused_pct"] * v["pixels"] / 100) for v in metrics["views"]) == metrics["fused_points"]
    for name in names:
        assert f"view {name}" in result.stdout and "% of pixels fused" in result.stdout
    # The recording: every view's maps at every iteration of every pass and level (2 levels x 2 passes x 2).
    store = RrdReader(str(out / "recording.rrd")).stream().collect()
    summary = str(store.summary())
    for entity in ("/world/cameras/", "/maps/000_view_000.png/depth", "/maps/004_view_004.png/normal",
                   "/maps/002_view_002.png/counter", "/stats/001_view_001.png/mean_cost", "/world/fused/vanilla"):
        assert entity in summary
    table = store.reader(index="iteration", contents="/maps/003_view_003.png/depth").to_arrow_table()
    assert table.num_rows == 2 * 2 * 2
    assert not list(out.rglob(".*.tmp"))


def _rerun_servers() -> set[int]:
    out = subprocess.run(["pgrep", "-f", "rerun_cli/rerun --serve-web"], capture_output=True, text=True).stdout
    return {int(p) for p in out.split()}


@pytest.mark.timeout(300)
def test_interactive_run_streams_live_serves_the_viewer_and_stops_cleanly(tmp_path):
    """Without --headless: live rerun web viewer and live 3-D viewer during the run, the 3-D viewer's server the
    tuning viewer after it; SIGTERM stops both."""
    import signal
    import time
    import urllib.request

    before = _rerun_servers()
    proc = subprocess.Popen([sys.executable, "-m", "workbench.cli", "run", str(SAMPLES / "tiny"), "--out",
                             str(tmp_path / "out"), "--iterations", "1", "--levels", "1", "--geom-passes", "0",
                             "--port", "0"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    try:
        deadline = time.monotonic() + 240
        viewer_url = None
        for line in proc.stdout:
            lines.append(line)
            if line.startswith("viewer: http://127.0.0.1:"):
                viewer_url = line.split()[1]
                break
            assert time.monotonic() < deadline, "".join(lines[-20:])
        assert viewer_url, "".join(lines[-20:])
        assert any("live PatchMatch stream: http://127.0.0.1:" in line for line in lines)
        live = [i for i, line in enumerate(lines) if line.startswith("live 3-D viewer: http://127.0.0.1:")]
        summary = [i for i, line in enumerate(lines) if line.startswith("fused cloud:")]
        assert live and summary and live[0] < summary[0], "".join(lines[-20:])  # served from the run's start
        assert lines[live[0]].split()[3] == viewer_url  # one server: the live viewer becomes the tuning viewer
        assert len(_rerun_servers() - before) == 1  # the live web viewer is up while the viewer serves
        with urllib.request.urlopen(viewer_url, timeout=20) as response:
            assert response.status == 200
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=60) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
    deadline = time.monotonic() + 20
    while _rerun_servers() - before and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not _rerun_servers() - before, "the rerun web viewer outlived the run"
    assert (tmp_path / "out" / "fused.ply").is_file()


def test_output_cut_short_by_its_reader_is_not_an_error():
    """`deepc run --help-options | head`, the reader gone before deepc writes: no traceback, no error line, exit 0."""
    proc = subprocess.Popen([sys.executable, "-m", "workbench.cli", "run", "--help-options"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, cwd=SAMPLES.parent)
    proc.stdout.close()  # closed while the interpreter still starts: its first write meets a broken pipe
    stderr = proc.communicate(timeout=120)[1]
    assert proc.returncode == 0 and stderr == b""
