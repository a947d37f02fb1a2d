"""support/rerun_panels.py, which the replay browser tests use to read a named panel's pixels, on drawn pages."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib import colormaps

from layouts import LAYOUTS, Contents
from support.rerun_panels import (
    SEPARATOR,
    explanation_problem,
    find_panel,
    layout_fractions,
    map_problem,
    panels_match,
    settled_from,
    text_lines,
)
from workbench.rerun.stream import entity_name

VIEW = entity_name(0, "a.png")


def _page(width: int = 1000, height: int = 700, top: int = 35, bottom: int = 550) -> np.ndarray:
    """A white page with rerun's separators: below the top bar, above the time panel and around each panel of the
    iterations layout (as egui_tiles draws them: the maps grid's 3 × 2 cells in the left 3/5, over the top 2/3)."""
    page = np.full((height, width, 3), 255, np.uint8)
    page[[top, bottom]] = SEPARATOR
    for x in (199, 399, 599):
        page[top + 1:bottom, x] = SEPARATOR
    for y in (207, 378):
        page[y, :599] = SEPARATOR
    return page


def test_a_panel_is_found_where_the_layout_puts_it_and_its_pixels_read():
    blueprint = LAYOUTS["iterations"](Contents([VIEW]), VIEW)
    place = layout_fractions(blueprint)["000 · depth (m)"]
    assert (place.x0, place.y0, place.x1, place.y1) == pytest.approx((0, 0, 0.2, 1 / 3))
    page = _page()
    depth = find_panel(page, blueprint, "000 · depth (m)")
    cost = find_panel(page, blueprint, "000 · cost")
    assert (depth.x0, depth.y0, depth.x1, depth.y1) == (0, 36, 199, 207)
    assert (cost.x0, cost.y0, cost.x1, cost.y1) == (400, 36, 599, 207)
    body = depth.body()
    assert "0% of the panel in turbo" in map_problem(body.pixels(page), "turbo")  # an empty panel
    ramp = (colormaps["turbo"](np.linspace(0, 1, body.x1 - body.x0))[:, :3] * 255).astype(np.uint8)
    page[body.y0:body.y1, body.x0:body.x1] = ramp[None]
    assert map_problem(body.pixels(page), "turbo") is None
    assert "in magma colours" in map_problem(body.pixels(page), "magma")
    page[body.y0:body.y1, body.x0:body.x1] = ramp[len(ramp) // 2]  # one flat colour of the scale
    assert "one flat colour" in map_problem(body.pixels(page), "turbo")
    with pytest.raises(AssertionError, match="no panel '000 · nope'"):
        find_panel(page, blueprint, "000 · nope")
    bare = _page()
    bare[36:550] = 255  # no panels between the top bar and the time panel (another layout, or none yet)
    with pytest.raises(AssertionError, match="the layout puts it at"):
        find_panel(bare, blueprint, "000 · cost")


def test_an_explanation_is_lines_of_dark_text_on_a_light_panel():
    panel = np.full((160, 200, 3), 255, np.uint8)
    assert text_lines(panel) == 0 and "0 lines" in explanation_problem(panel)
    for row in (10, 25, 40):  # three lines of 9-px glyphs
        panel[row:row + 9, 12:150:3] = 30
    assert text_lines(panel) == 3 and explanation_problem(panel) is None
    panel[10:34] = 255  # one line left: "(empty)" or "No data available."
    assert "1 lines" in explanation_problem(panel)
    panel[60:150, 20:180] = 0  # a dark picture is not an explanation
    assert explanation_problem(panel) is not None


def test_a_panel_settles_at_the_first_shot_from_which_all_later_ones_match_the_last():
    """bench_replay_load's detector: a state shown briefly and replaced does not count, a blend of a few pixels
    (a blinking cursor, anti-aliasing) does not break a run of matches, and a panel not yet on the page (None) is no
    state."""
    rng = np.random.default_rng(0)
    states = [rng.integers(0, 256, (40, 60, 3), dtype=np.uint8) for _ in range(3)]
    final = states[2]
    flicker = final.copy()
    flicker[0, :4] ^= 0xFF  # 4 of 2400 pixels: within the tolerance
    assert panels_match(final, flicker) and not panels_match(final, states[1])
    assert not panels_match(final, final[:, :-1]) and not panels_match(final, None) and panels_match(None, None)
    assert settled_from([None, states[0], states[1], final, flicker, final]) == 3
    # the final state shown once before, then replaced: only the last run of matches counts
    assert settled_from([None, final, states[1], final, final]) == 3
    assert settled_from([final]) == 0 and settled_from([None, None]) == 0
    with pytest.raises(ValueError):
        settled_from([])
