"""Shared fixtures: paths to the shipped sample scenes and to ../shared/data (optional)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SAMPLES = REPO / "sample_scenes"
SHARED_DATA = REPO.parent / "shared" / "data"


def sample_scene_dirs() -> list[Path]:
    return sorted(p for p in SAMPLES.iterdir() if (p / "sparse").is_dir())


def shared_scene_dirs() -> list[Path]:
    if not SHARED_DATA.is_dir():
        return []
    return sorted(p for p in SHARED_DATA.iterdir() if (p / "sparse").is_dir())


@pytest.fixture
def temple_copy(tmp_path: Path) -> Path:
    """A writable copy of the shipped Middlebury temple scene (text model, no GT)."""
    dst = tmp_path / "temple"
    shutil.copytree(SAMPLES / "middlebury_temple", dst)
    return dst


@pytest.fixture
def fountain_copy(tmp_path: Path) -> Path:
    """A writable copy of the shipped fountain_p11 scene (binary model, GT depth and points)."""
    dst = tmp_path / "fountain"
    shutil.copytree(SAMPLES / "fountain_p11", dst, ignore=shutil.ignore_patterns("points.ply"))
    return dst
