"""The default working size (half the images, within 640..2560 px, never above full size; engine.scene) and the
per-view shares at the end of a run (engine.run.view_shares)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from conftest import SAMPLES

from engine.fusion import FUSION_PRESETS
from engine.run.distributed.streamed import fuse_run_folder, read_view_map
from engine.run.folder import RunMetrics, read_map, write_map
from engine.run.fused_maps import FusionRule
from engine.run.view_shares import view_share_lines, view_shares, weak_views
from engine.scene import (
    SceneOptions,
    default_image_size,
    load_scene,
    resolved_image_size,
    survey_scene,
    working_size_line,
)
from support.colmap_workspaces import write_workspace
from support.fake_run import make_fake_run
from workbench.cli.run import print_run_summary


@pytest.mark.parametrize(("longest", "size"), [(160, 0), (640, 0), (700, 640), (1251, 640), (1536, 768),
                                                (1920, 960), (4000, 2000), (6000, 2560)])
def test_default_halves_within_640_and_2560_never_above_full_size(longest, size):
    assert default_image_size(longest) == size


def test_an_explicit_size_wins_and_saved_runs_keep_theirs():
    sizes = [(1251, 703), (703, 1251), (640, 480)]
    assert resolved_image_size(SceneOptions(), sizes) == 640
    assert resolved_image_size(SceneOptions(max_image_size=0), sizes) == 0
    assert resolved_image_size(SceneOptions(max_image_size=1000), sizes) == 1000
    # a run saves the resolved number; one saved without the key ran at full size
    assert SceneOptions.from_dict({}, saved=True).max_image_size == 0
    assert SceneOptions.from_dict({"max_image_size": 384}, saved=True).max_image_size == 384


@pytest.mark.parametrize("scene", ["tiny", "small", "fountain_p11", "middlebury_temple"])
def test_sample_scenes_keep_their_size(scene):
    survey = survey_scene(SAMPLES / scene)
    assert survey.options.max_image_size == 0  # saved as before: the baselines see no option change
    assert all(v.camera.size == v.original_size for v in survey.views)


def test_info_and_run_print_the_working_size():
    result = subprocess.run([sys.executable, "-m", "workbench.cli", "info", SAMPLES / "small", "--max-image-size",
                             "200"], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "working size: 320×240 → 200×150 px (--max-image-size 200; 0 for full size)" in result.stdout


def test_a_view_far_below_the_others_is_warned_about(tmp_path, capsys):
    run = make_fake_run(SAMPLES / "tiny", tmp_path / "run", with_confidence=False)
    scene = load_scene(SAMPLES / "tiny")
    empty = scene.views[2].name
    for kind in ("depth", "counter"):
        write_map(run, kind, empty, np.zeros_like(read_map(run, kind, empty)))
    cloud = fuse_run_folder(scene, run, FUSION_PRESETS["pixels"], FusionRule())  # vanilla
    names = [v.name for v in scene.views]
    entries = view_shares(names, cloud.source_view, lambda i: read_view_map(run, "counter", names[i]))
    assert [e["view"] for e in entries] == names
    assert entries[2]["fused_pct"] == 0 and entries[2]["confirmed_pct"] == 0
    assert all(0 < e["fused_pct"] <= 100 and 0 < e["confirmed_pct"] <= 100 for i, e in enumerate(entries) if i != 2)
    assert [e["view"] for e in weak_views(entries)[0]] == [empty]
    lines, warnings = view_share_lines(entries)
    assert len(lines) == 5 and len(warnings) == 1 and empty in warnings[0]
    metrics = RunMetrics(scene="tiny", scene_path=str(SAMPLES / "tiny"), pipeline="vanilla", num_images=5,
                         image_size=(160, 120), seconds={"total": 1.0, "patchmatch": 0.5, "fusion": 0.1},
                         fused_points=len(cloud), views=entries)
    print_run_summary(metrics, str(run))
    out, err = capsys.readouterr()
    assert all(f"view {n}" in out for n in names)
    assert [line for line in err.splitlines() if line.startswith("warning: ")] == warnings


@pytest.mark.parametrize("model", ["PINHOLE", "SIMPLE_RADIAL"])
def test_a_large_workspace_is_halved_and_the_line_names_the_image_size(tmp_path, model):
    workspace = write_workspace(SAMPLES / "tiny", tmp_path / "ws", camera_model=model, scale=8)  # 1280x960
    survey = survey_scene(workspace, SceneOptions(cache_dir=str(tmp_path / "cache")))
    assert survey.options.max_image_size == 640 and all(max(v.camera.size) <= 640 for v in survey.views)
    line = working_size_line(survey.views, None, survey.image_sizes)
    assert line.startswith("working size: 1280×960 → ") and "--max-image-size N to change, 0 for full size" in line
    if model == "PINHOLE":  # undistortion changes the size a little; a pinhole workspace at 0 stays whole
        full = survey_scene(workspace, SceneOptions(max_image_size=0))
        assert working_size_line(full.views, 0, full.image_sizes) == \
            "working size: 1280×960 px, full size (--max-image-size 0)"
