"""Fuzzing every reader with damaged files: a result or one clear error naming the file, nothing else.

Bounded and derandomised here (same inputs every run); ``benchmarks/reliability/fuzz_readers.py`` runs many more.
"""

from __future__ import annotations

import shutil
import subprocess
import sys

import pytest
from conftest import REPO, SAMPLES
from hypothesis import HealthCheck, given, settings

from support.fuzzing import TARGETS, FuzzCounts, check_input, damaged_inputs

# examples per target in CI: the COLMAP targets load a scene per example (~0.1 s)
EXAMPLES = {"dense_bin": 150, "ply": 150, "colmap_text": 60, "colmap_binary": 60, "eth3d_mlp": 100, "images": 100,
            "regress_suite": 100, "confidence_weights": 150, "openmvs_dmap": 150}


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


def _damaged_weights(tmp_path) -> list:
    """Weights files as damage leaves them: half copied, and one stored number's bits flipped to NaN."""
    import torch

    from engine.confidence.network import ConfidenceNet
    from engine.confidence.weights import save_weights

    good = save_weights(tmp_path / "good.pt", ConfidenceNet("middle", (2, 4)))
    half = tmp_path / "half.pt"
    half.write_bytes(good.read_bytes()[:len(good.read_bytes()) // 2])
    model = ConfidenceNet("middle", (2, 4))
    with torch.no_grad():
        model.head.bias.fill_(float("nan"))
    return [(half, "not a readable weights file"), (save_weights(tmp_path / "nan.pt", model), "NaN")]


def test_damaged_suite_and_weights_are_refused_at_the_command_line(tmp_path):
    """`deepc regress --suite F` and `deepc run --weights F`: exit 2, one line naming the file, and nothing
    started (no report, no output folder: bad weights are refused before PatchMatch)."""
    from support.fuzzing import VALID_SUITE

    for scene in ("tiny", "small"):
        (tmp_path / scene).symlink_to(SAMPLES / scene, target_is_directory=True)
    suites = [(VALID_SUITE[:VALID_SUITE.index("[[pipeline]]") + 5], "not valid TOML"),
              (VALID_SUITE.replace("thumbnail_views = 4", "thumbnail_views = nan"), "thumbnail_views")]
    for i, (text, expected) in enumerate(suites):
        suite = tmp_path / f"suite{i}.toml"
        suite.write_text(text)
        result = _deepc("regress", "--suite", suite, "--report", tmp_path / "report")
        lines = [line for line in result.stderr.splitlines() if line.strip()]
        assert result.returncode == 2 and len(lines) == 1, result.stderr
        assert str(suite) in lines[0] and expected in lines[0], lines[0]
        assert not (tmp_path / "report").exists()
    for weights, expected in _damaged_weights(tmp_path):
        result = _deepc("run", SAMPLES / "tiny", "--out", tmp_path / "out", "--pipeline", "fast", "--weights", weights,
                        "--headless")
        lines = [line for line in result.stderr.splitlines() if line.strip()]
        assert result.returncode == 2 and len(lines) == 1, result.stderr
        assert lines[0].startswith("deepc: error: ") and str(weights) in lines[0] and expected in lines[0], lines[0]
        assert not (tmp_path / "out").exists()
