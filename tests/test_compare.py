"""``deepc compare``: a run against itself agrees everywhere, against a perturbed copy the perturbed region is found
(per view, overall, in the maps and in the report), the fused clouds of both are scored."""

from __future__ import annotations

import json
import os
import shutil

import numpy as np
import pytest
from conftest import SAMPLES
from PIL import Image
from test_cli import _one_line_error, deepc

from engine.compare.comparison import compare_runs, reference_scene
from engine.compare.our_fusion import fuse_run
from engine.compare.sources import open_run
from engine.io.ply import read_points, write_ply
from engine.run.folder import read_map, write_map
from engine.scene import load_scene
from support.fake_run import make_fake_run
from support.foreign_runs import write_colmap_run
from support.gt_normals import depth_normals
from workbench.compare.report import COLOURS, map_file

TINY = SAMPLES / "tiny"
VIEW = "view_002.png"
BOX = (slice(40, 70), slice(60, 120))  # rows, columns of the perturbed region
SKY_DEPTH = 50.0


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """(A, B): a fake run of the tiny scene with depth in the sky too (where there is no GT), and a copy whose depth
    is 5 % off in BOX of VIEW and 10 % off in the left third of VIEW's sky."""
    root = tmp_path_factory.mktemp("compare")
    a = make_fake_run(TINY, root / "a")
    scene = reference_scene(open_run(a, "raw"), open_run(a, "raw"))
    for v in scene.views:
        depth = read_map(a, "depth", v.name)
        depth[scene.gt_depth(v.index) == 0] = SKY_DEPTH
        write_map(a, "depth", v.name, depth)
    b = root / "b"
    shutil.copytree(a, b)
    depth = read_map(b, "depth", VIEW)
    depth[BOX] *= 1.05
    depth[:, :50][depth[:, :50] == SKY_DEPTH] *= 1.1
    write_map(b, "depth", VIEW, depth)
    return a, b


def _raw(run):
    return open_run(run, "raw")


def test_a_run_compared_with_itself_agrees_everywhere(runs, tmp_path):
    a, _ = runs
    result = deepc("compare", a, a, "--maps", "raw", "--report", tmp_path / "report")
    assert result.returncode == 0, result.stderr
    summary = json.loads((tmp_path / "report" / "compare.json").read_text())
    overall = summary["overall"]
    assert overall["gt"] > 0 and overall["no_gt"] > 0
    assert overall["a_right"] == overall["b_right"] > 0 and overall["a_right_pct"] == overall["b_right_pct"] > 50
    assert overall["a_right_b_wrong"] == overall["b_right_a_wrong"] == overall["disagree"] == 0
    assert overall["difference_pct"] == overall["disagree_pct"] == 0
    assert "all views" in result.stdout and "5 views compared" in result.stdout
    for view in summary["views"]:
        pixels = np.asarray(Image.open(tmp_path / "report" / "maps" / map_file(view["view"], "a_right_b_wrong")))
        assert not (pixels == COLOURS["a_right_b_wrong"]).all(axis=2).any()


def test_a_perturbed_copy_is_found_where_it_was_perturbed(runs):
    a, b = runs
    scene = reference_scene(_raw(a), _raw(b))
    comparison = compare_runs(_raw(a), _raw(b), scene, evaluate_fused=False)
    worst = comparison.most_different(1)[0]
    assert worst.name == VIEW
    assert all(v.difference == 0 for v in comparison.views if v.name != VIEW)
    gt = scene.gt_depth(worst.index)
    a_depth = read_map(a, "depth", VIEW)
    a_right = (gt > 0) & (np.abs(a_depth - gt) < 0.01 * gt)
    expected = np.zeros(gt.shape, bool)
    expected[BOX] = True
    np.testing.assert_array_equal(worst.maps["a_right_b_wrong"], expected & a_right)
    assert not worst.maps["b_right_a_wrong"].any()
    sky = np.zeros(gt.shape, bool)
    sky[:, :50] = gt[:, :50] == 0
    np.testing.assert_array_equal(worst.maps["disagree"], sky)
    assert comparison.total.a_right_b_wrong == int((expected & a_right).sum())
    assert comparison.total.disagree == int(sky.sum()) > 0


def test_the_report_shows_the_view_that_differs_most_first(runs, tmp_path):
    a, b = runs
    result = deepc("compare", a, b, "--maps", "raw", "--report", tmp_path / "r", "--views", "2")
    assert result.returncode == 0, result.stderr
    assert VIEW in result.stdout and (tmp_path / "r" / "report.html").is_file()
    page = (tmp_path / "r" / "report.html").read_text()
    section = page[page.index("Where they differ most"):]
    assert section.index(VIEW) < min(section.index(n) for n in ("view_000.png", "view_001.png", "view_003.png",
                                                                  "view_004.png") if n in section)
    pixels = np.asarray(Image.open(tmp_path / "r" / "maps" / map_file(VIEW, "a_right_b_wrong")))
    coloured = (pixels == COLOURS["a_right_b_wrong"]).all(axis=2)
    rows, cols = np.nonzero(coloured)
    assert coloured.any() and rows.min() >= BOX[0].start and rows.max() < BOX[0].stop
    assert cols.min() >= BOX[1].start and cols.max() < BOX[1].stop


def test_a_fast_runs_fused_maps_lose_what_its_confidence_filter_dropped(runs):
    a, _ = runs
    fused, raw = open_run(a, "fused"), open_run(a, "raw")
    comparison = compare_runs(fused, raw, reference_scene(fused, raw), evaluate_fused=False)
    assert comparison.total.b_right_a_wrong > 0 and comparison.total.a_right_b_wrong == 0
    top = comparison.views[0].maps["b_right_a_wrong"]
    assert top[: top.shape[0] // 4].mean() > top[-top.shape[0] // 4:].mean()  # confidence ramps up downwards


def test_both_fused_clouds_are_scored(runs, tmp_path):
    a, b = runs
    points = read_points(TINY / "ground_truth" / "points.ply")
    for run, shift in ((a, 0.0), (b, 0.03)):
        write_ply(run / "fused.ply", points + np.array([shift, 0, 0], np.float32))
    try:
        comparison = compare_runs(_raw(a), _raw(b), reference_scene(_raw(a), _raw(b)))
    finally:
        for run in (a, b):
            (run / "fused.ply").unlink()
    fa, fb = comparison.fused["a"], comparison.fused["b"]
    assert fa["tolerances"] == fb["tolerances"] and len(fa["f1"]) > 3
    assert fa["f1"][0] > 90 and fb["f1"][0] < fa["f1"][0] - 10  # 3 cm off fails the 1 cm tolerance
    assert fb["f1"][-1] > 90  # and passes the largest


def test_our_fusion_scores_both_runs_maps_through_one_fusion(tmp_path):
    scene = load_scene(TINY)
    gt = {v.name: scene.gt_depth(v.index) for v in scene.views}
    normal = {v.name: depth_normals(v.camera, gt[v.name]) for v in scene.views}
    names = list(gt)
    with_normals = write_colmap_run(TINY, tmp_path / "n", lambda n: np.where(normal[n].any(axis=2), gt[n], 0),
                                    names, normal_of=lambda n: normal[n])
    without = write_colmap_run(TINY, tmp_path / "d", lambda n: gt[n], names)
    a, b = open_run(with_normals), open_run(without)
    comparison = compare_runs(a, b, scene, evaluate_fused=False, fuse_ours=True)
    assert comparison.ours_fused["a"]["f1"][2] > 80  # GT maps fused: near complete and accurate at 5 cm
    assert comparison.ours_fused["b"] is None
    assert any("B's maps not fused by ours" in n and "normal map" in n for n in comparison.fused_notes)
    cloud = fuse_run(a, scene)
    assert len(cloud) > 1000 and (cloud.num_views >= 2).all()


def test_bad_arguments_are_one_line_and_exit_2(runs, tmp_path):
    a, _ = runs
    assert "usage: deepc compare" in deepc("compare", "--help").stdout
    _one_line_error(deepc("compare", a, a, "--tolerance", "0"), "--tolerance")
    _one_line_error(deepc("compare", a, a, "--scene", tmp_path / "nowhere"), "nowhere")


def test_a_deepc_runs_saved_score_of_its_cloud_stands_while_it_holds(runs, tmp_path):
    from engine.compare.comparison import fused_scores, score_clouds
    from engine.evaluation import EvaluationOptions

    a = shutil.copytree(runs[0], tmp_path / "a")
    write_ply(a / "fused.ply", read_points(TINY / "ground_truth" / "points.ply")[::3])
    run = _raw(a)
    scene = reference_scene(run, run)
    computed = score_clouds({"a": a / "fused.ply"}, scene)["a"]
    metrics = json.loads((a / "metrics.json").read_text())
    saved = {**computed, "f1": [-1.0] * len(computed["f1"])}  # no scoring gives this: seen only when reused
    metrics["eval"], metrics["options"]["evaluation"] = saved, EvaluationOptions().to_dict()
    (a / "metrics.json").write_text(json.dumps(metrics))
    assert fused_scores(run, run, scene)[0] == {"a": saved, "b": saved}
    # other evaluation options, or a cloud written after metrics.json: scored again
    other = EvaluationOptions(tolerances=(0.01, 0.05))
    assert fused_scores(run, run, scene, other)[0]["a"]["f1"] == [computed["f1"][0], computed["f1"][2]]
    later = (a / "metrics.json").stat().st_mtime + 10
    os.utime(a / "fused.ply", (later, later))
    assert fused_scores(run, run, scene)[0]["a"] == computed


def test_our_fusion_of_a_run_fuses_as_our_pipelines_do(fake_run):
    """``deepc compare --fuse`` fuses with what every pipeline fuses with by default, so our own vanilla maps
    through it give the run's own cloud (it once used the fusion's bare defaults: 7 F1 points less at 1 cm on
    fountain_p11)."""
    from engine.run.pipeline import PipelineOptions

    scene = reference_scene(_raw(fake_run), _raw(fake_run))
    run = _raw(fake_run)
    default = fuse_run(run, scene)
    pipeline = fuse_run(run, scene, PipelineOptions().fusion)
    assert np.array_equal(default.xyz, pipeline.xyz) and len(default) > 0
