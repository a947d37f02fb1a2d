"""The viewer session: stage caches, previews vs exact results, colours, exports (no browser)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from engine.core.errors import DeepCError
from engine.refinement.options import RefinementOptions
from workbench.viewer.export import safe_file_name
from workbench.viewer.session import COLOR_MODES, ViewerSession, ViewParams


@pytest.fixture(scope="module")
def session(fake_run):
    return ViewerSession.open(fake_run)


def test_opens_a_run_and_knows_what_exists(session):
    assert session.pipelines == ["vanilla", "fast"]
    assert session.has_confidence and session.has_counter and session.has_gt


def test_confidence_threshold_and_mask_k_remove_points(session):
    vanilla = session.cloud(ViewParams(pipeline="vanilla"))
    fast = session.cloud(ViewParams(pipeline="fast", fused_confidence_tau=0.5))
    masked = session.cloud(ViewParams(pipeline="vanilla", mask_k=2))
    assert 0 < len(fast) < len(vanilla) and 0 < len(masked) < len(vanilla)
    assert session.cloud(ViewParams(pipeline="fast", fused_confidence_tau=0.5)) is fast  # cached, not recomputed
    scores_vanilla = session.evaluate(ViewParams(pipeline="vanilla"))
    scores_fast = session.evaluate(ViewParams(pipeline="fast", fused_confidence_tau=0.5))
    assert scores_vanilla["accuracy"] > 90  # GT depth fused: nearly every point is accurate
    assert scores_fast["completeness"] < scores_vanilla["completeness"]


def test_full_pipeline_keeps_trusted_estimates_and_filters_refined_ones_by_their_own_confidence(fake_run,
                                                                                                 tmp_path):
    import shutil

    from engine.run.folder import read_map, write_map
    run = shutil.copytree(fake_run, tmp_path / "run")
    session = ViewerSession.open(run)
    for v in session.scene.views:  # refined = vanilla maps, but the second network trusts the other half
        write_map(run, "refined_depth", v.name, read_map(run, "depth", v.name))
        write_map(run, "refined_normal", v.name, read_map(run, "normal", v.name))
        write_map(run, "refined_confidence", v.name, 1.0 - read_map(run, "confidence", v.name))
    session = ViewerSession.open(run)
    assert "full" in session.pipelines
    params = dict(fused_confidence_tau=0.5)
    for (d_fast, _), (d_full, _), d in zip(session.filtered_maps(ViewParams(pipeline="fast", **params)),
                                           session.filtered_maps(ViewParams(pipeline="full", **params)),
                                           session.data, strict=True):
        # network 1 trusts the top rows little: there the refined estimate stands, judged by network 2
        trusted = d.confidence >= RefinementOptions().keep_confident
        expected = (d.depth > 0) & (np.where(trusted, d.confidence, d.refined_confidence) >= 0.5)
        assert np.array_equal(d_full > 0, expected) and (d_full[~trusted] > 0).any()
        assert not np.array_equal(d_full > 0, d_fast > 0)
    full = session.cloud(ViewParams(pipeline="full", **params))
    assert np.nanmin(full.mean_confidence) >= 0.5  # the cloud carries the confidence of what it fused


def test_a_fusion_change_reuses_the_filtered_maps(session):
    params = ViewParams(pipeline="fast", fused_confidence_tau=0.3)
    maps = session.filtered_maps(params)
    stricter = dataclasses.replace(params, fusion=params.fusion.replace(max_normal_error=5.0))
    assert session.filtered_maps(stricter) is maps
    assert len(session.cloud(stricter)) < len(session.cloud(params))


def test_exact_clouds_are_cached_within_a_byte_budget(session, monkeypatch):
    import workbench.viewer.session as session_module

    params = ViewParams()
    cloud = session.cloud(params)
    size = session_module._nbytes(cloud)
    assert size >= cloud.xyz.nbytes + cloud.normal.nbytes + cloud.rgb.nbytes > 0
    cache = session_module._LRU(8, max_bytes=int(2.5 * size))
    for i in range(4):  # four clouds of the same size: only the two newest fit
        cache.put(i, cloud)
    assert list(cache) == [2, 3]
    cache = session_module._LRU(8, max_bytes=1)
    cache.put("only", cloud)  # the newest entry stays even when it alone exceeds the budget
    assert list(cache) == ["only"]
    assert session._clouds.max_bytes == session_module.CLOUD_CACHE_BYTES


def test_min_views_preview_is_exact(session):
    params = ViewParams(pipeline="vanilla")
    base = session.base_cloud(params)
    for m in (2, 3, 5):
        strict = dataclasses.replace(params, fusion=params.fusion.replace(min_num_pixels=m))
        exact = session.cloud(strict)
        preview = base.subset(ViewerSession.preview_mask(base, strict))
        assert len(preview) == len(exact)
        np.testing.assert_array_equal(preview.xyz, exact.xyz)


def test_preview_approximates_the_exact_cloud(session):
    params = ViewParams(pipeline="fast", fused_confidence_tau=0.5)
    base = session.base_cloud(params)
    preview = ViewerSession.preview_mask(base, params).sum()
    exact = len(session.cloud(params))
    assert abs(preview - exact) / exact < 0.35


def test_colour_modes_and_view_images(session):
    cloud = session.cloud(ViewParams(pipeline="fast"))
    for mode in COLOR_MODES:
        colors = session.colors(cloud, mode)
        assert colors.shape == (len(cloud), 3) and colors.dtype == np.uint8
    with pytest.raises(DeepCError):
        session.colors(cloud, "sparkles")
    images = session.view_images(2)
    assert set(images) == {"image", "depth", "normal", "counter", "confidence"}
    assert all(im.dtype == np.uint8 and im.ndim == 3 for im in images.values())


def test_unknown_pipeline_and_bad_paths(session, tmp_path):
    with pytest.raises(DeepCError, match="full"):
        session.cloud(ViewParams(pipeline="full"))
    with pytest.raises(DeepCError, match="neither"):
        ViewerSession.open(tmp_path)


@pytest.mark.parametrize("name,expected", [("cloud", "cloud.ply"), ("../../etc/passwd", "passwd.ply"),
                                           ("/abs/x y", "x_y.ply"), ("..", "export.ply"), ("a\x00b", "a_b.ply")])
def test_export_names_cannot_leave_the_export_folder(name, expected):
    assert safe_file_name(name, ".ply") == expected
