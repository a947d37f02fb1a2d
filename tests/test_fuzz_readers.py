"""Fuzzing every reader with damaged files: a result or one clear error naming the file, nothing else.

Bounded and derandomised here (same inputs every run); ``benchmarks/fuzz_readers.py`` runs many more.
"""

from __future__ import annotations

import shutil
import subprocess
import sys

import pytest
from conftest import REPO, SAMPLES
from fuzzing import TARGETS, FuzzCounts, check_input, damaged_inputs
from hypothesis import HealthCheck, given, settings

# examples per target in CI: the COLMAP targets load a scene per example (~0.1 s)
EXAMPLES = {"dense_bin": 150, "ply": 150, "colmap_text": 60, "colmap_binary": 60, "eth3d_mlp": 100, "images": 100}


@pytest.fixture(scope="module")
def targets(tmp_path_factory):
    made = {}
    for name, build in TARGETS.items():
        made[name] = build(tmp_path_factory.mktemp(name))
    return made


@pytest.mark.parametrize("name", sorted(TARGETS))
def test_reader_survives_damaged_files(name, targets):
    target = targets[name]
    target.read(target.root)  # the undamaged input loads
    counts = FuzzCounts()

    @settings(max_examples=EXAMPLES[name], deadline=None, derandomize=True, database=None,
              suppress_health_check=list(HealthCheck))
    @given(damage=damaged_inputs(target))
    def fuzz(damage):
        check_input(target, damage, counts)

    fuzz()
    assert counts.tried >= EXAMPLES[name] * 0.8, counts
    assert counts.clear_errors > 0, "no damaged input was refused: the mutations do not reach the reader"


def _deepc(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "workbench.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=120, cwd=REPO)


def test_half_copied_binary_model_is_refused_at_the_command_line(tmp_path):
    """A truncated points3D.bin (a half-copied dataset) made pycolmap read past the end for ever; the model is
    now checked byte by byte first: exit 2 and one line naming the file."""
    scene = tmp_path / "small"
    shutil.copytree(SAMPLES / "small" / "sparse", scene / "sparse")
    (scene / "images").symlink_to(SAMPLES / "small" / "images", target_is_directory=True)
    points = scene / "sparse" / "points3D.bin"
    points.write_bytes(points.read_bytes()[:240964])
    result = _deepc("info", scene)
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert result.returncode == 2 and len(lines) == 1, result.stderr
    assert lines[0].startswith("deepc: error: ") and str(points) in lines[0] and "truncated" in lines[0]
