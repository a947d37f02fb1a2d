"""What the tuning viewer's labels say (no browser): units on the point size, a mask k no higher than the views
can give, "error" that says which error and in which unit, and a region re-run whose figures show the change
and whose maps have colour scales."""

from __future__ import annotations

import pytest
from conftest import running_viewer, wait_for

from workbench.viewer.panel import SizeSlider
from workbench.viewer.region import change_text
from workbench.viewer.session import GT_DISTANCE


@pytest.fixture(scope="module")
def app(fake_run):
    with running_viewer(fake_run) as viewer:
        yield viewer


def test_point_size_names_its_unit_and_has_round_ends(app):
    label = app.point_size.label
    unit = label[label.index("(") + 1:label.index(")")]
    assert unit in ("mm", "cm", "m")
    for value in (app.point_size.min, app.point_size.max, app.point_size.step, app.point_size.value):
        assert round(value, 3) == value  # no 0.001222 … 0.122166
    app.point_size.value = app.point_size.max
    per_metre = {"mm": 1000.0, "cm": 100.0, "m": 1.0}[unit]
    assert app.cloud_handle.point_size == pytest.approx(app.point_size.max / per_metre)
    app.point_size.value = app.point_size.step * 10
    # the reported case: a default of 1.222 mm is a 0.1 … 12.2 mm slider
    assert SizeSlider.around(0.001222) == SizeSlider("mm", 1000.0, 0.1, 12.2, 0.1, 1.2)


def test_mask_k_goes_no_higher_than_the_runs_source_views(app):
    sources = max(len(v.source_views) for v in app.session.scene.views)
    assert app.mask_k.max == sources < 10


def test_the_error_colour_says_which_error_and_its_unit(app):
    assert "error" not in app.color_mode.options and GT_DISTANCE in app.color_mode.options
    app.color_mode.value = GT_DISTANCE
    assert "distance to the nearest GT point" in app.color_legend.content and "cm" in app.color_legend.content
    app.color_mode.value = "rgb"
    assert app.wait_idle(60)


def test_a_small_change_shows_in_the_region_figures():
    assert change_text(61.76, 61.84) == "61.76 % → 61.84 % (+0.08 points)"  # was "61.8 % → 61.8 % (+0.1)"
    assert change_text(61.75, 62.5) == "61.8 % → 62.5 % (+0.7 points)"  # the change is that of the figures shown
    assert change_text(40.0, 40.0) == "40.0 % (unchanged)"


def test_region_rerun_maps_come_with_their_colour_scales(inspector_app):
    inspector = inspector_app.inspector
    inspector.rerun(0, (10, 10, 40, 30))
    wait_for(lambda: inspector.region is not None and inspector.wait_idle(1))
    legend = inspector.region_legend.content
    assert legend.count("linear-gradient") == 2  # depth, and the error against GT
    assert "region depth" in legend and " m<" in legend and "% of the GT depth" in legend and "≥ 5 %" in legend
    assert "points)" in inspector.region_numbers.content or "unchanged" in inspector.region_numbers.content
