"""Fuzzing every reader with damaged files: a result or one clear error naming the file, nothing else.

Bounded and derandomised here (same inputs every run); ``benchmarks/fuzz_readers.py`` runs many more.
"""

from __future__ import annotations

import subprocess
import sys

import pytest
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
