"""The viewer explains itself in a real browser (Debian chromium + playwright): it opens on the run's own
settings, a control that cannot act is disabled with its reason, colour modes have legends, and the view
dropdown switches the maps shown. Every wait has a timeout; the server and the pages are always closed."""

from __future__ import annotations

import shutil

import pytest
from conftest import running_viewer, wait_for

from engine.fusion import FUSION_PRESETS
from engine.run.folder import read_metrics, write_metrics

pytestmark = [pytest.mark.browser, pytest.mark.timeout(300)]


@pytest.fixture(scope="module")
def app(fake_run, tmp_path_factory):
    """A fake fast run made with τ 0.3 and the paper's fusion thresholds."""
    run = shutil.copytree(fake_run, tmp_path_factory.mktemp("runs") / "fast_tau")
    data = read_metrics(run)
    options = {**data["options"], "pipeline": "fast", "confidence": {"tau": 0.3},
               "fusion": FUSION_PRESETS["deepc"].to_dict()}
    write_metrics(run, {**data, "pipeline": "fast", "options": options})
    with running_viewer(run) as viewer:
        yield viewer


@pytest.fixture
def page(browser_context, app):
    page = browser_context.new_page()
    try:
        page.goto(f"http://127.0.0.1:{app.port}/")
        wait_for(lambda: len(app.server.get_clients()) > 0)
        page.get_by_text("Connected").wait_for()
        yield page
    finally:
        page.close()
        app.reset_to_run()
        assert app.wait_idle(60)


def _element(page, handle):
    return page.locator(f'[id="{handle._impl.uuid}"]')


def _choose(page, handle, option: str) -> None:
    _element(page, handle).click()
    page.get_by_role("option", name=option, exact=True).click()


def test_opens_on_the_runs_pipeline_and_threshold_and_says_so(page, app):
    page.get_by_text("run: fast · deepc · confidence.tau 0.3").wait_for()
    assert _element(page, app.pipeline).input_value() == "fast"
    thumb = _element(page, app.fused_confidence_tau).locator('[role="slider"]')
    assert thumb.get_attribute("aria-valuenow") == "0.3"
    page.get_by_text("Δ run").first.wait_for()  # the metrics compare with the run


def test_tau_is_disabled_under_vanilla_with_its_reason(page, app):
    page.get_by_text("run: fast").first.wait_for()
    _choose(page, app.pipeline, "vanilla")
    page.get_by_text("the vanilla pipeline has no confidence filter").wait_for()
    wait_for(lambda: app.fused_confidence_tau.disabled and app.wait_idle(1))
    slider = _element(page, app.fused_confidence_tau)
    page.wait_for_function("id => document.getElementById(id).querySelector('[role=slider]')"
                           ".getAttribute('aria-disabled') === 'true'", arg=app.fused_confidence_tau._impl.uuid,
                           timeout=20_000)
    # viser 1.1 leaves the number box of a disabled slider editable: a value typed there is put back
    box = slider.locator("xpath=..").locator("input.mantine-NumberInput-input")
    box.fill("0.8")
    box.press("Enter")
    page.wait_for_timeout(500)
    wait_for(lambda: app.fused_confidence_tau.value == 0.3 and box.input_value() == "0.3")
    assert app.params().fused_confidence_tau == 0.0 and app.params().pipeline == "vanilla"


def test_a_colour_mode_shows_its_legend_with_unit(page, app):
    page.get_by_text("Colour").first.wait_for()
    _choose(page, app.color_mode, "GT distance (cm)")
    page.get_by_text("distance to the nearest GT point").wait_for()
    page.get_by_text("≥ 4 cm").wait_for()
    page.get_by_text("confidence of the fast estimates").wait_for()  # the histogram with τ
    page.get_by_text("confidence.tau 0.3:").wait_for()


def test_the_view_dropdown_switches_the_maps_shown(page, app):
    before = page.locator("img").evaluate_all("images => images.map(i => i.src)")
    name = app.session.scene.views[2].name
    _choose(page, app.view_dropdown, f"2: {name}")
    page.get_by_text(f"view 2: {name}").wait_for()
    page.get_by_text("kept mask (pipeline filters)").first.wait_for()
    wait_for(lambda: page.locator("img").evaluate_all("images => images.map(i => i.src)") != before)
    page.get_by_role("button", name="next view ▶").click()
    page.get_by_text(f"view 3: {app.session.scene.views[3].name}").wait_for()
