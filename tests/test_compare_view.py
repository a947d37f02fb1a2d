"""``deepc view RUN_A --compare RUN_B``: a run against a copy perturbed in one box of one view. The colour arrays
mark that box, the metrics table shows both fused F1s and their change, a colouring switch changes what the browser
draws, and the inspector probes one pixel in both runs."""

from __future__ import annotations

import io
import shutil

import numpy as np
import pytest
from conftest import wait_for
from PIL import Image
from test_cli import _one_line_error, deepc
from test_compare import BOX, TINY, VIEW, runs  # noqa: F401  (runs: the module's fixture)

from engine.compare.clouds import case_clouds, pixel_step
from engine.compare.pixels import CASES
from engine.io.ply import read_points, write_ply
from engine.run.folder import read_map
from engine.scene import load_scene
from support.browser import dismiss_software_webgl_notice
from support.probe_traces import HandProbe
from workbench.compare.colours import CASE_COLOURS, colour_arrays
from workbench.viewer.compare import CompareApp, metrics_table_html, open_comparison

SHIFT = 0.03  # B's fused cloud is off by 3 cm: it fails the 1 cm tolerance, passes the largest


@pytest.fixture(scope="module")
def pair(runs, tmp_path_factory):  # noqa: F811
    """(A, B) copies of test_compare's runs, with fused clouds: A's the GT points, B's shifted by SHIFT."""
    root = tmp_path_factory.mktemp("compare_view")
    points = read_points(TINY / "ground_truth" / "points.ply")
    out = []
    for run, shift in zip(runs, (0.0, SHIFT), strict=True):
        copy = shutil.copytree(run, root / run.name)
        write_ply(copy / "fused.ply", points + np.array([shift, 0, 0], np.float32))
        out.append(copy)
    return tuple(out)


@pytest.fixture(scope="module")
def comparison(pair):
    return open_comparison(*pair, maps="raw")


def _points_of(cloud, view_index):
    mine = cloud.view == view_index
    return mine, cloud.pixel[:, 0], cloud.pixel[:, 1]


def test_the_colour_arrays_mark_the_perturbed_box_and_the_perturbed_sky(comparison):
    clouds = case_clouds(comparison, max_points=10**7)  # every pixel a point: the box is exact
    colours = colour_arrays(clouds)
    view = next(v for v in comparison.views if v.name == VIEW)
    scene = comparison.scene
    gt = scene.gt_depth(view.index)
    for side in ("a", "b"):
        cloud, rgb = clouds[side], colours["who is right"][side]
        blue = (rgb == CASE_COLOURS["a_right_b_wrong"]).all(axis=1)
        mine, cols, rows = _points_of(cloud, view.index)
        in_box = mine & (rows >= BOX[0].start) & (rows < BOX[0].stop) & (cols >= BOX[1].start) & (cols < BOX[1].stop)
        has_gt = gt[rows, cols] > 0
        # A right, B wrong: exactly B's perturbed box, where GT exists (and A, GT depth itself, is right)
        np.testing.assert_array_equal(blue, in_box & has_gt)
        assert blue.sum() > 500
        assert cloud.case[blue].tolist() == [1 + CASES.index("a_right_b_wrong")] * int(blue.sum())
        # where GT is missing, the runs disagree exactly in the left third of the view's sky that B moved
        magenta = (colours["disagreement"][side] == CASE_COLOURS["disagree"]).all(axis=1)
        sky = mine & ~has_gt & (cols < 50)
        assert np.array_equal(magenta & ~in_box, sky) and sky.sum() > 100
    # B's points of the box are 5 % farther than A's: the clouds are the runs' own depths
    a_box = clouds["a"].xyz[(clouds["a"].case == 1 + CASES.index("a_right_b_wrong"))]
    b_box = clouds["b"].xyz[(clouds["b"].case == 1 + CASES.index("a_right_b_wrong"))]
    center = scene.views[view.index].camera.center
    ratio = np.linalg.norm(b_box - center, axis=1) / np.linalg.norm(a_box - center, axis=1)
    np.testing.assert_allclose(ratio, 1.05, rtol=1e-4)
    # the run colouring tells the runs apart, the image colouring does not
    assert not np.array_equal(colours["A / B"]["a"][0], colours["A / B"]["b"][0])
    np.testing.assert_array_equal(colours["image"]["a"][~blue], colours["image"]["b"][~blue])


def test_the_inspector_probes_the_same_pixel_in_a_and_in_b(comparison, pair):
    scene = load_scene(TINY)
    hands = {str(run): HandProbe(scene, run) for run in pair}
    app = CompareApp(comparison, port=0, max_points=5_000,
                     probe=lambda run_dir, view, pixels, progress=None: hands[str(run_dir)].probe(
                         run_dir, view, pixels, progress))
    try:
        app.select_view(next(v.index for v in comparison.views if v.name == VIEW))
        x, y = int(app.pixel_x.value), int(app.pixel_y.value)  # the form suggests a pixel where the runs differ
        assert BOX[0].start <= y < BOX[0].stop and BOX[1].start <= x < BOX[1].stop
        app.inspect(x, y)
        assert app.wait_idle(30)
        a_depth, b_depth = (read_map(run, "depth", VIEW)[y, x] for run in pair)
        assert b_depth == pytest.approx(1.05 * a_depth, rel=1e-5)
        for side, depth in (("a", a_depth), ("b", b_depth)):
            text = app.inspect_text[side].content
            assert f"pixel ({x}, {y})" in text and f"depth {depth:.4g}" in text
        assert "✔" in app.inspect_text["a"].content and "✘" in app.inspect_text["b"].content
        # a click on the cloud inspects the pixel its point came from, in both runs
        view = comparison.scene.views[app.selected.index]
        step = pixel_step(comparison, 5_000)  # the clouds keep every step-th pixel: take one inside the box
        col, row = (-(-s.start // step) * step + step for s in (BOX[1], BOX[0]))
        ray = view.camera.R.T @ view.camera.pixel_rays()[row, col]
        app.select_view(0)
        assert app.pick(view.camera.center, ray / np.linalg.norm(ray)) == (view.index, col, row)
        assert app.selected.name == VIEW and app.wait_idle(30)
        assert f"pixel ({col}, {row})" in app.inspect_text["b"].content
    finally:
        app.stop()


def test_the_viewer_opens_before_the_fused_clouds_are_scored_and_shows_their_f1_when_they_are(comparison, pair):
    """``deepc view A --compare B`` opens on the pixel comparison (scoring a foreign cloud takes seconds), says the
    clouds are being scored, then shows the same F1s ``deepc compare`` gives."""
    unscored = open_comparison(*pair, maps="raw", evaluate_fused=False)
    assert unscored.fused == {"a": None, "b": None}
    app = CompareApp(unscored, port=0, max_points=5_000, score_fused=True)
    try:
        assert app.wait_scored(120)
        table = app.metrics.content
        assert "scoring" not in table
        assert unscored.fused["a"]["f1"] == comparison.fused["a"]["f1"]
        assert f"{comparison.fused['b']['f1'][0]:.2f}" in table
    finally:
        app.stop()
    pending = metrics_table_html(unscored, unscored.views[0], scoring=True)
    assert "scoring both clouds" in pending


def test_view_compare_with_a_missing_run_is_one_line_and_exit_2(pair, tmp_path):
    _one_line_error(deepc("view", pair[0], "--compare", tmp_path / "nowhere", "--port", "0"), "nowhere")
    _one_line_error(deepc("view", pair[0], "--compare", pair[1], "--tolerance", "100"), "--tolerance")


def _canvas(page) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(page.locator("canvas").first.screenshot(timeout=60_000))))[..., :3]


@pytest.mark.browser
@pytest.mark.timeout(300)
def test_in_the_browser_the_table_shows_both_f1s_and_switching_colours_repaints(browser_context, comparison):
    fa, fb = comparison.fused["a"], comparison.fused["b"]
    assert fa["f1"][0] > fb["f1"][0] + 10  # the shift costs B at the finest tolerance
    app = CompareApp(comparison, port=0, max_points=8_000)
    page = browser_context.new_page()
    try:
        page.goto(f"http://127.0.0.1:{app.port}/")
        wait_for(lambda: len(app.server.get_clients()) > 0)
        page.get_by_text("Connected").wait_for()
        table = page.locator(".deepc-compare-metrics")
        table.wait_for()
        text = table.inner_text()
        for value in (f"{fa['f1'][0]:.2f}", f"{fb['f1'][0]:.2f}", f"{fb['f1'][0] - fa['f1'][0]:+.2f}"):
            assert value in text, f"{value} not in the metrics table: {text}"
        dismiss_software_webgl_notice(page)
        page.wait_for_timeout(1500)  # the first camera's view of the scene, the clouds in the left part
        scene_part = (slice(None), slice(0, 600))  # the panel covers the right of the canvas
        before = _canvas(page)[scene_part]
        assert before.std() > 10, "the canvas rendered nothing"
        page.locator(f'[id="{app.colouring._impl.uuid}"]').click()
        page.get_by_role("option", name="A / B").click()
        wait_for(lambda: app.colouring.value == "A / B" and app.switch_seconds)
        page.wait_for_timeout(1500)
        after = _canvas(page)[scene_part]
        changed = np.abs(after.astype(int) - before.astype(int)).sum(axis=2) > 60
        assert changed.mean() > 0.2, f"only {changed.mean():.3f} of the scene changed colour"
        assert max(app.switch_seconds) < 1.0  # the arrays were made before: the switch only sends them
    finally:
        page.close()
        app.stop()
