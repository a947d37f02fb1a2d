"""Workspaces of the kinds users bring (issue 46), generated from the tiny sample: distorted models, shared and
per-image cameras, text and binary, portrait among landscape, unregistered images; the pixel-free checks come before
any undistortion, and ``deepc info`` undistorts nothing."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import pytest
from conftest import REPO, SAMPLES

from engine.core.errors import DeepCError
from engine.scene import SceneOptions, load_scene, survey_scene
from support.colmap_workspaces import write_workspace

KINDS = {
    "simple_radial-shared-text": dict(camera_model="SIMPLE_RADIAL"),
    "opencv-per_image-binary": dict(camera_model="OPENCV", per_image=True, binary=True),
    "simple_radial-portrait-unregistered-binary": dict(portrait=(1, 3), unregistered=2, binary=True),
    "pinhole-portrait-per_image-text": dict(camera_model="PINHOLE", portrait=(0,), per_image=True),
}


def deepc(*args, cache, timeout: float = 120) -> tuple[subprocess.CompletedProcess, float]:
    env = dict(os.environ, DEEPC_CACHE=str(cache))
    start = time.monotonic()
    result = subprocess.run([sys.executable, "-m", "workbench.cli", *map(str, args)], capture_output=True, text=True,
                            timeout=timeout, cwd=REPO, env=env)
    return result, time.monotonic() - start


@pytest.mark.parametrize("max_size", [0, 128])
@pytest.mark.parametrize("kind", list(KINDS))
def test_workspace_loads_as_surveyed(tmp_path, kind, max_size):
    workspace = write_workspace(SAMPLES / "tiny", tmp_path / "ws", **KINDS[kind])
    options = SceneOptions(max_image_size=max_size, cache_dir=str(tmp_path / "cache"))
    survey = survey_scene(workspace, options)
    lines = []
    scene = load_scene(workspace, options, report=lines.append)
    distorted = KINDS[kind].get("camera_model", "SIMPLE_RADIAL") != "PINHOLE"
    assert bool(lines) == distorted and bool(survey.distorted) == distorted
    assert len(scene.views) == 5
    for planned, view in zip(survey.views, scene.views, strict=True):
        assert planned.name == view.name and planned.camera.size == view.camera.size
        np.testing.assert_allclose(planned.camera.K, view.camera.K)
        assert planned.depth_range == view.depth_range and planned.source_views == view.source_views
        assert view.source_views and 0 < view.depth_range[0] < view.depth_range[1]
        if max_size:
            assert max(view.camera.size) <= max_size
        image = scene.image(view.index)
        assert image.shape == (view.camera.height, view.camera.width, 3)
    portrait = KINDS[kind].get("portrait", ())
    assert [v.camera.height > v.camera.width for v in scene.views] == [i in portrait for i in range(5)]
    assert all(c.model in ("PINHOLE", "SIMPLE_PINHOLE") for c in scene.model.cameras.values())
    assert not list((tmp_path / "cache").rglob(".undistort-*"))
    if distorted:  # a second load reuses the cache, silently
        again = []
        load_scene(workspace, options, report=again.append)
        assert again == []


def test_size_mismatch_under_a_distorted_model_is_one_line_before_any_undistortion(tmp_path):
    # the case measured in issue 46: cameras 3031x2006 (SIMPLE_RADIAL), images 1000x660
    workspace = write_workspace(SAMPLES / "tiny", tmp_path / "ws", camera_factor=3.0)
    cache = tmp_path / "cache"
    with pytest.raises(DeepCError, match=r"view_000.png: image is 160x120 but its COLMAP camera 1 \(SIMPLE_RADIAL\) "
                                         r"is 480x360"):
        load_scene(workspace, SceneOptions(cache_dir=str(cache)))
    for command in (["info", workspace], ["run", workspace, "--out", tmp_path / "out", "--headless"]):
        result, seconds = deepc(*command, cache=cache)
        lines = [line for line in result.stderr.splitlines() if line.strip()]
        assert result.returncode == 2 and len(lines) == 1, result.stderr
        assert lines[0].startswith("deepc: error: ") and "view_000.png" in lines[0] and "480x360" in lines[0]
        assert seconds < 20  # 2-4 s here on a loaded 2-core machine; the target is 5 s
    assert not cache.exists() and not (tmp_path / "out").exists()  # nothing undistorted, nothing started


def test_pixel_free_problems_of_a_distorted_workspace_come_before_undistortion(tmp_path):
    workspace = write_workspace(SAMPLES / "tiny", tmp_path / "ws", camera_model="OPENCV")
    (workspace / "images" / "view_003.png").unlink()
    with pytest.raises(DeepCError, match="view_003.png: image listed in the model is missing"):
        load_scene(workspace, SceneOptions(cache_dir=str(tmp_path / "cache")))
    (workspace / "images" / "view_003.png").write_bytes(b"not an image")
    with pytest.raises(DeepCError, match="view_003.png: unreadable image"):
        load_scene(workspace, SceneOptions(cache_dir=str(tmp_path / "cache")))
    assert not (tmp_path / "cache").exists()


def test_info_on_a_distorted_model_undistorts_nothing(tmp_path):
    workspace = write_workspace(SAMPLES / "tiny", tmp_path / "ws", camera_model="OPENCV", per_image=True,
                                portrait=(2,), unregistered=1)
    cache = tmp_path / "cache"
    result, seconds = deepc("info", workspace, "--max-image-size", "128", cache=cache)
    assert result.returncode == 0, result.stderr
    text = result.stdout
    assert "5 views" in text and "1 file(s) in images/ are not registered" in text
    assert "OPENCV" in text and "160x120" in text and "120x160" in text
    assert "5 images (OPENCV) would be undistorted at 128 px" in text and "not cached yet" in text
    assert "memory: estimated peak" in text and "view_004.png" in text
    assert result.stderr.strip() == ""  # no pycolmap log lines
    assert not cache.exists()
    assert seconds < 30  # 2-5 s here under load


def test_info_loads_no_kernels(tmp_path):
    """`deepc info` is pixel-free and kernel-free: it imports neither numba nor the pipeline's stages (they were half
    of its CPU time: about 10 s on the loaded 2-core machine for a 40-photo workspace; engine/core/lazy.py)."""
    workspace = write_workspace(SAMPLES / "tiny", tmp_path / "ws", camera_model="SIMPLE_RADIAL")
    code = ("import sys, runpy; sys.argv = ['deepc', 'info', sys.argv[1]]\n"
            "try:\n    runpy.run_module('workbench.cli', run_name='__main__')\n"
            "except SystemExit as exc:\n    assert not exc.code, exc.code\n"
            "heavy = ('numba', 'scipy.ndimage', 'torch', 'engine.run.pipeline', 'engine.patchmatch.context')\n"
            "print('loaded:', sorted(m for m in heavy if m in sys.modules))")
    env = dict(os.environ, DEEPC_CACHE=str(tmp_path / "cache"))
    result = subprocess.run([sys.executable, "-c", code, str(workspace)], capture_output=True, text=True, timeout=120,
                            cwd=REPO, env=env)
    assert result.returncode == 0, result.stderr
    assert "memory: estimated peak" in result.stdout
    assert result.stdout.strip().splitlines()[-1] == "loaded: []"
