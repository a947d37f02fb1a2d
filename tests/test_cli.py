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


@pytest.mark.parametrize("args", [["eval", "a.ply", "b.ply"], ["view", "x"], ["replay", "x.rrd"], ["regress"],
                                  ["train"]])
def test_stages_that_do_not_exist_yet_say_so(args):
    _one_line_error(deepc(*args), "does not exist yet")
