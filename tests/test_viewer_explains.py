"""The viewer explains itself (no browser): it opens on the run's own settings and can go back to them,
controls that cannot act are disabled with a reason, colour modes without data are left out with one,
every colour mode and map has a legend, and metrics compare against the run and the previous setting."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from conftest import running_viewer

from engine.core.errors import DeepCError
from engine.fusion import FUSION_PRESETS
from engine.run.folder import read_metrics, write_metrics
from workbench.viewer.session import GT_DISTANCE, ViewerSession, ViewParams


def _with_options(run, tmp_path, name: str, **metrics):
    """A copy of ``run`` whose metrics.json says what the run used (pipeline, options, eval, points)."""
    copy = shutil.copytree(run, tmp_path / name)
    data = read_metrics(copy)
    options = {**data.get("options", {}), **metrics.pop("options", {})}
    write_metrics(copy, {**data, **metrics, "options": options})
    return copy


@pytest.fixture(scope="module")
def deepc_fast_run(fake_run, tmp_path_factory):
    """A fast run with τ 0.3 and the paper's fusion thresholds, scored by the run at two tolerances."""
    return _with_options(fake_run, tmp_path_factory.mktemp("runs"), "fast_deepc", pipeline="fast",
                         fused_points=12_345,
                         eval={"tolerances": [0.02, 0.05], "accuracy": [90.0, 95.0], "completeness": [50.0, 60.0],
                               "f1": [64.3, 73.5]},
                         options={"pipeline": "fast", "confidence": {"tau": 0.3},
                                  "fusion": FUSION_PRESETS["deepc"].to_dict()})


@pytest.fixture(scope="module")
def app(deepc_fast_run):
    with running_viewer(deepc_fast_run) as viewer:
        yield viewer


def test_opens_on_the_runs_pipeline_threshold_and_fusion_and_names_them(app):
    assert (app.pipeline.value, app.fused_confidence_tau.value, app.preset.value) == ("fast", 0.3, "deepc")
    assert app.cloud_params == ViewParams(pipeline="fast", fused_confidence_tau=0.3, fusion=FUSION_PRESETS["deepc"])
    assert "run: fast · deepc · confidence.tau 0.3" in app.run_text.content
    assert app.fused_confidence_tau.label == "confidence.tau"  # the option the slider moves
    assert not app.reset_button.disabled


def test_metrics_compare_with_the_run_and_the_previous_setting_at_every_tolerance(app):
    assert app.wait_idle(60)
    table = app.metrics_table.content
    assert "F1 @ 2 cm" in table and "F1 @ 5 cm" in table and "Δ run" in table
    f1 = app.session.evaluate(app.cloud_params)["by_tolerance"][0.05]["f1"]
    assert f"{f1 - 73.5:+.1f}" in table  # the change against the run's own 5 cm score
    before = len(app.cloud)
    app.mask_k.value = 3
    assert app.wait_idle(60)
    assert f"{len(app.cloud) - before:+,}" in app.metrics_table.content  # points against the previous setting
    app.reset_to_run()
    assert app.wait_idle(60)
    assert app.params() == app.run_params and app.mask_k.value == 0 and len(app.cloud) == before


def test_tau_is_disabled_with_a_reason_under_vanilla_and_a_typed_value_does_not_stick(app):
    app.pipeline.value = "vanilla"
    assert app.wait_idle(60)
    assert app.fused_confidence_tau.disabled
    assert "vanilla pipeline has no confidence filter" in app.control_notes.content
    app.fused_confidence_tau.value = 0.8  # typed into the disabled box
    assert app.fused_confidence_tau.value == 0.3 and app.params().fused_confidence_tau == 0.0
    app.reset_to_run()
    assert app.wait_idle(60)
    assert not app.fused_confidence_tau.disabled and app.control_notes.content == ""


def test_previews_say_they_are_approximate(app):
    text = app._metrics_text(app.cloud, None, preview=True, count=10, stale_fusion=True)
    assert "approximate" in text and "previous fusion thresholds" in text
    assert "· exact" in app._metrics_text(app.cloud, None)
    # once the exact result is in, it says how far the preview was from it
    app._last_preview = (app.cloud_params, len(app.cloud) + 7)
    assert "approximate preview showed" in app._metrics_text(app.cloud, None, params=app.cloud_params)
    assert "(+7)" in app._metrics_text(app.cloud, None, params=app.cloud_params)


def test_every_colour_mode_has_a_legend_with_its_unit_and_the_no_data_colour(app):
    for mode, unit in (("confidence", "no confidence"), ("views", "views"), (GT_DISTANCE, "cm")):
        app.color_mode.value = mode
        assert unit in app.color_legend.content and "linear-gradient" in app.color_legend.content
    assert "≥ 4 cm" in app.session.cloud_legend(GT_DISTANCE)
    app.color_mode.value = "rgb"
    assert app.wait_idle(60)


def test_histograms_draw_the_current_thresholds(app):
    app.fused_confidence_tau.value = 0.5
    assert app.wait_idle(60)
    assert "confidence.tau 0.5:" in app.histograms.content and "<svg" in app.histograms.content
    app.reset_to_run()
    assert app.wait_idle(60)


def test_view_dropdown_and_buttons_switch_the_maps_of_the_current_pipeline(app):
    first = np.asarray(app.view_images["depth"].image).copy()
    app.step_view(+1)
    assert app.view_dropdown.value.startswith("1: ") and "view 1:" in app.view_title.content
    assert not np.array_equal(np.asarray(app.view_images["depth"].image), first)
    app.view_dropdown.value = app.view_dropdown.options[0]
    assert "view 0:" in app.view_title.content
    app.step_view(-1)
    assert app.view_dropdown.value.startswith(f"{len(app.session.scene.views) - 1}: ")
    kinds = {k for k, h in app.view_images.items() if h.visible}
    assert {"image", "depth", "normal", "cost", "counter", "confidence", "kept", "GT error"} <= kinds
    assert "refined depth" not in kinds  # only the full pipeline fuses refined maps
    assert "kept" in app.view_metrics.content and "within 1 %" in app.view_metrics.content
    for kind in kinds:
        assert app.view_legends[kind].content


def test_a_vanilla_run_without_gt_or_confidence_offers_only_what_it_has(fake_run, tmp_path):
    run = _with_options(fake_run, tmp_path, "vanilla", pipeline="vanilla")
    for v in ViewerSession.open(run).scene.views:
        (run / "stereo" / "confidence_maps" / f"{v.name}.bin").unlink()
    session = ViewerSession.open(run)
    modes = session.color_modes()
    assert modes["confidence"] and "no confidence maps" in modes["confidence"] and modes[GT_DISTANCE] is None
    with pytest.raises(DeepCError, match="confidence"):
        session.colors(session.cloud(ViewParams()), "confidence")
    session.scene.gt_points_path = None  # a scene without GT points: no error colouring, and it says why
    assert "no GT points" in session.color_modes()[GT_DISTANCE] and "no GT points" in session.cloud_legend(GT_DISTANCE)
    with running_viewer(run) as viewer:
        assert viewer.pipeline.value == "vanilla" and viewer.pipeline.disabled and viewer.fused_confidence_tau.disabled
        assert "confidence" not in viewer.color_mode.options
        assert "no confidence maps" in viewer.color_notes.content
        assert "fast needs confidence maps" in viewer.control_notes.content


def test_a_full_run_opens_with_its_refined_threshold_and_sky_filter(fake_run, tmp_path):
    from engine.refinement.views import sky_filter_views
    from engine.run.folder import read_map, write_map

    run = _with_options(fake_run, tmp_path, "full", pipeline="full",
                        options={"pipeline": "full", "refinement": {"refined_conf_tau": 0.2, "sky_filter": True}})
    for v in ViewerSession.open(run).scene.views:  # refined maps: the PatchMatch ones, trusted by network 2
        write_map(run, "refined_depth", v.name, read_map(run, "depth", v.name))
        write_map(run, "refined_normal", v.name, read_map(run, "normal", v.name))
        write_map(run, "refined_confidence", v.name, read_map(run, "confidence", v.name))
    session = ViewerSession.open(run)
    params = session.run_params()
    assert (params.pipeline, params.fused_confidence_tau, session.sky_filter) == ("full", 0.2, True)
    maps = session.filtered_maps(params)
    unfiltered = [session.candidates(i, "full") for i in range(len(session.data))]
    by_tau = [(np.where(m.confidence >= 0.2, m.depth, 0), np.where((m.confidence >= 0.2)[..., None], m.normal, 0))
              for m in unfiltered]
    expected, _, _ = sky_filter_views(session.scene, [d for d, _ in by_tau], [n for _, n in by_tau],
                                      [d.depth for d in session.data], [d.confidence for d in session.data])
    for (depth, _), want in zip(maps, expected, strict=True):
        np.testing.assert_array_equal(depth, want)
    with running_viewer(run) as viewer:
        assert "run: full · pixels · refinement.refined_confidence_tau 0.2 · sky filter" in viewer.run_text.content
        assert viewer.fused_confidence_tau.label == "refinement.refined_confidence_tau"
        viewer.pipeline.value = "fast"  # the same slider now moves confidence.tau
        assert viewer.fused_confidence_tau.label == "confidence.tau"
        assert viewer.view_images["refined depth"].visible


def test_a_bare_scene_says_there_is_no_run_to_tune():
    from conftest import SAMPLES

    from workbench.viewer.app import ViewerApp

    app = ViewerApp(ViewerSession.open(SAMPLES / "tiny"), port=0)
    try:
        assert "no run" in app.run_text.content and app.reset_button.disabled
        assert "open the output folder of deepc run" in app.control_notes.content
        assert [k for k, h in app.view_images.items() if h.visible] == ["image"]
        app.step_view(+1)
        assert "view 1:" in app.view_title.content
    finally:
        app.stop()
