"""The viewer app without a browser: GUI callbacks, exports, bind address, shutdown."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import running_viewer, wait_for

from engine.io.ply import read_ply


@pytest.fixture(scope="module")
def app(fake_run):
    with running_viewer(fake_run) as viewer:
        yield viewer


def test_binds_loopback_by_default(app):
    assert app.host == "127.0.0.1" and app.port > 0


def test_gui_changes_recompute_and_update_the_metrics(app):
    app.pipeline.value = "fast"  # runs the callbacks on this thread, as viser does for Python-side changes
    assert app.wait_idle(60)
    app.fused_confidence_tau.value = 0.6
    assert app.wait_idle(60)
    strict = len(app.cloud)
    app.fused_confidence_tau.value = 0.1
    assert app.wait_idle(60)
    assert len(app.cloud) > strict
    assert f"{len(app.cloud):,} points" in app.metrics.content and "F1" in app.metrics.content
    app.color_mode.value = "confidence"
    assert app.cloud_handle.colors.shape == (len(app.cloud), 3)


def test_fusion_preset_dropdown_sets_the_sliders_and_follows_them(app):
    assert app.preset.value == "pixels"  # the fake run's metrics.json names no fusion: deepc run's default
    app.preset.value = "dense"
    assert app.per_pixel.value is False
    assert app.wait_idle(60)
    dense = len(app.cloud)
    app.preset.value = "deepc"  # the paper's thresholds
    assert (app.reproj.value, app.depth_err.value, app.normal_err.value, app.min_views.value) == (1.0, 0.01, 20.0, 3)
    assert app.per_pixel.value is False
    assert app.wait_idle(60)
    paper = len(app.cloud)
    assert paper < dense  # 1 px clusters merge several pixels per view: a sparser cloud
    app.min_views.value = 4  # a slider moved by hand: no preset has these values
    assert app.preset.value == "custom"
    app.min_views.value = 3
    assert app.preset.value == "deepc"
    app.per_pixel.value = True  # the checkbox counts as well
    assert app.preset.value == "custom"
    assert app.wait_idle(60)
    assert len(app.cloud) >= 3 * paper  # the same clusters of >= 3 pixels, every pixel a point
    app.preset.value = "pixels"  # what `deepc run` fused with
    assert (app.reproj.value, app.min_views.value, app.per_pixel.value) == (1.0, 2, True)
    assert app.wait_idle(60)
    assert len(app.cloud) > 2 * dense
    app.preset.value = "dense"
    assert (app.reproj.value, app.min_views.value, app.per_pixel.value) == (0.5, 2, False)
    assert app.wait_idle(60)
    assert len(app.cloud) == dense


def test_large_clouds_are_sent_voxel_thinned_but_scored_and_exported_whole(app):
    from engine.core.thinning import voxel_keys
    from workbench.viewer.app import POINT_BUDGET

    assert app.wait_idle(60)
    total = len(app.cloud)
    budget = total // 4
    app.point_budget.value = budget  # as if typed in the browser: runs the callbacks
    assert app.wait_idle(60)
    wait_for(lambda: app._sent is not None and app._sent[0] is app.cloud and app._sent[1] <= budget)
    sent, voxel = app._sent[1], app._sent[2]
    assert app.cloud_handle.points.shape == (sent, 3) and app.cloud_handle.colors.shape == (sent, 3)
    assert budget // 2 <= sent <= budget and voxel > 0
    # one point of the cloud per occupied voxel: every voxel of the whole cloud is there once
    xyz = np.asarray(app.cloud.xyz, np.float64)
    keys = voxel_keys(xyz, xyz.min(axis=0), voxel)
    assert len(np.unique(keys)) == sent
    assert f"{sent:,} sent of {total:,}" in app.budget_note.content and "thinned" in app.budget_note.content
    assert f"**{total:,} points** ({sent:,} sent, thinned)" in app.metrics.content
    assert len(read_ply(app.export_ply("whole"))["x"]) == total
    shown = app.cloud
    app.cloud = shown.subset(np.arange(10))  # as while a preview (a thinned mask of the base cloud) is shown
    try:
        assert len(read_ply(app.export_ply("during_preview"))["x"]) == total  # the export is the exact cloud
    finally:
        app.cloud = shown
    app.point_budget.value = POINT_BUDGET
    assert app.wait_idle(60)
    wait_for(lambda: app.cloud_handle.points.shape[0] == total)
    assert "whole cloud sent" in app.budget_note.content


def test_exports_stay_inside_the_output_folder(app, fake_run):
    path = app.export_ply("../../escape attempt")
    assert path.parent == fake_run / "exports" and path.name == "escape_attempt.ply"
    columns = read_ply(path)
    assert len(columns["x"]) == len(app.cloud) and "num_views" in columns
    rrd = app.save_rrd("state")
    assert rrd == fake_run / "exports" / "state.rrd" and rrd.stat().st_size > 1000
    from rerun.chunk import RrdReader
    summary = str(RrdReader(str(rrd)).stream().collect().summary())
    assert "/world/fused/" in summary and "/world/cameras/" in summary


def test_selecting_a_view_updates_its_images(app):
    app.select_view(2)
    assert "view 2:" in app.view_title.content
    assert app.view_images["depth"].image.ndim == 3
    assert np.asarray(app.view_images["confidence"].image).dtype == np.uint8
