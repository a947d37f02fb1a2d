"""Refined maps of finished runs (engine/run/refine.py): refine_run, its stamp-checked cache,
load_run(refined=True) and `deepc train --refined` on the tiny scene."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import make_noisy_run

from engine.confidence.data import load_run, view_labels
from engine.confidence.weights import DEFAULT_WEIGHTS
from engine.consistency import compute_counter_maps
from engine.core.errors import DeepCError
from engine.patchmatch import ViewMaps
from engine.refinement.options import RefinementOptions
from engine.run.folder import STAMP, file_sha256, map_path, read_map, read_stamp
from engine.run.pipeline import PipelineOptions, patchmatch_views
from engine.run.refine import refine_run
from engine.scene import load_scene

REPO = Path(__file__).resolve().parent.parent
TINY = REPO / "sample_scenes" / "tiny"
# a short refinement: a few seconds for the 5 views of tiny
CHEAP = RefinementOptions(scales=2, fast_iters=(60, 40), iters=(10, 10), lr=(0.01, 0.01), lr_slots=(1, 1))
OPTIONS = PipelineOptions(pipeline="full", refinement=CHEAP)
CHEAP_FLAGS = ["--set", "refinement.scales=2", "--set", "refinement.fast_iters=60,40", "--set",
               "refinement.iters=10,10", "--set", "refinement.lr=0.01,0.01", "--set", "refinement.lr_slots=1,1"]


@pytest.fixture(scope="module")
def vanilla_run(tmp_path_factory) -> Path:
    return make_noisy_run(TINY, tmp_path_factory.mktemp("vanilla_run"))


@pytest.fixture(scope="module")
def network1():
    from engine.confidence.weights import load_weights
    return load_weights()


@pytest.fixture(scope="module")
def refined_run(vanilla_run, network1, tmp_path_factory):
    run = tmp_path_factory.mktemp("refined") / "run"
    shutil.copytree(vanilla_run, run)
    lines: list[str] = []
    result = refine_run(run, options=OPTIONS, model=network1, log=lines.append)
    return run, result, lines


def _files(run: Path) -> dict[Path, int]:
    return {p: p.stat().st_mtime_ns for p in (run / "refined").rglob("*") if p.is_file()}


def test_refine_run_writes_whole_refined_maps_with_their_own_counter_maps(vanilla_run, refined_run):
    run, result, lines = refined_run
    assert not result.reused and result.views == 5 and result.seconds["refinement"] > 0
    assert len(lines) == 5 and lines[0].startswith("tiny: view 1/5 view_000.png refined")
    scene = load_scene(TINY)
    refined = []
    for v in scene.views:
        depth, vanilla = read_map(run, "refined_depth", v.name), read_map(vanilla_run, "depth", v.name)
        normal = read_map(run, "refined_normal", v.name)
        assert depth.shape == vanilla.shape == (120, 160) and normal.shape == (120, 160, 3)
        # dense (the vanilla holes are filled) and moved away from the vanilla depth (the confidence-weighted
        # data term holds the confident half or so of the pixels in place with this short schedule)
        assert (depth > 0).mean() > 0.95 > (vanilla > 0).mean()
        both = (depth > 0) & (vanilla > 0)
        assert np.mean(np.abs(depth[both] - vanilla[both]) > 1e-4 * vanilla[both]) > 0.3
        refined.append(ViewMaps(depth, normal, np.zeros_like(depth), np.zeros(depth.shape, np.uint32)))
        assert not (run / "refined" / "confidence_maps").exists()  # no second network ran
    # the counter maps are those of the refined maps, not the vanilla ones
    expected = compute_counter_maps(patchmatch_views(scene), refined, OPTIONS.counter)
    for v, k in zip(scene.views, expected, strict=True):
        counter = read_map(run, "refined_counter", v.name)
        np.testing.assert_array_equal(counter, k)
        assert not np.array_equal(counter, read_map(vanilla_run, "counter", v.name))
    stamp = read_stamp(run)
    assert stamp["key"]["weights_sha256"] == file_sha256(DEFAULT_WEIGHTS)
    assert stamp["key"]["refinement"]["scales"] == 2 and stamp["weights"] == str(DEFAULT_WEIGHTS)


def test_refined_maps_are_reused_only_while_the_stamp_matches(refined_run, network1, tmp_path, monkeypatch):
    run = tmp_path / "run"
    shutil.copytree(refined_run[0], run)
    before = _files(run)
    first = read_map(run, "refined_depth", "view_000.png")
    # same weights, inputs and options (a filter threshold after refinement does not count): reused
    again = refine_run(run, DEFAULT_WEIGHTS, OPTIONS.replace(refinement=CHEAP.replace(refined_confidence_tau=0.5)),
                       model=network1)
    assert again.reused and _files(run) == before

    other = OPTIONS.replace(refinement=CHEAP.replace(lambda_reg=3.0))
    result = refine_run(run, options=other, model=network1)
    assert not result.reused and result.views == 5
    assert not np.array_equal(read_map(run, "refined_depth", "view_000.png"), first)
    assert read_stamp(run)["key"]["refinement"]["lambda_reg"] == 3.0

    # a rewrite that dies half-way leaves no stamp, so the mixed maps are never taken for either refinement
    import engine.run.folder as runs
    writes = []

    def failing_write(out, kind, name, array):
        writes.append(kind)
        if len(writes) == 4:
            raise OSError("disk full")
        return runs_write(out, kind, name, array)

    runs_write = runs.write_map
    monkeypatch.setattr(runs, "write_map", failing_write)
    with pytest.raises(OSError):
        refine_run(run, options=OPTIONS, model=network1)
    assert not (run / STAMP).exists() and len(writes) == 4


def test_load_run_refined_reads_the_refined_maps_and_labels_them(vanilla_run, refined_run):
    with pytest.raises(DeepCError, match="no refined depth map for view view_000.png") as err:
        load_run(vanilla_run, refined=True)
    assert str(map_path(vanilla_run, "refined_depth", "view_000.png")) in str(err.value)

    run = refined_run[0]
    scene = load_scene(TINY)
    samples, vanilla = load_run(run, refined=True), load_run(vanilla_run)
    for s, v, view in zip(samples, vanilla, scene.views, strict=True):
        depth = read_map(run, "refined_depth", view.name)
        np.testing.assert_array_equal(s.labels, view_labels(scene, view.index, depth))
        assert s.labelled_fraction > v.labelled_fraction  # the refined maps are dense
        assert not np.array_equal(s.inputs, v.inputs)


def test_train_refined_refines_each_run_and_learns_on_the_refined_maps(vanilla_run, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(vanilla_run, run)
    out, card = tmp_path / "w.pt", tmp_path / "CARD.md"
    result = subprocess.run(
        [sys.executable, "-m", "workbench.cli", "train", str(run), "--refined", *CHEAP_FLAGS, "--out", str(out),
         "--model-card", str(card), "--epochs", "2", "--steps-per-epoch", "4", "--batch", "2", "--crop", "64",
         "--no-bf16", "--lr", "2e-3", "--lr-final", "1e-3", "--seed", "5"],
        capture_output=True, text=True, timeout=300, cwd=REPO)
    assert result.returncode == 0, result.stderr
    assert "refining tiny: view 5/5 view_004.png refined" in result.stderr
    assert "training data (refined maps)" in result.stderr
    assert read_stamp(run)["key"]["refinement"]["fast_iters"] == [60, 40]
    losses = [h["loss"] for h in json.loads(out.with_name("w.history.json").read_text())["history"]]
    assert losses[-1] < losses[0]
    meta = torch.load(out, weights_only=True)["meta"]
    assert meta["inputs"]["maps"] == "refined" and meta["inputs"]["refine_weights"] == str(DEFAULT_WEIGHTS)
    text = card.read_text()
    assert "Network inputs: refined maps" in text and f"`{DEFAULT_WEIGHTS.name}`" in text

    from workbench.cli.main import build_parser
    from workbench.cli.train import cmd_train
    for flags in (["--refine-weights", str(out)], ["--set", "refinement.scales=2"]):
        with pytest.raises(DeepCError, match="only make sense with --refined"):
            cmd_train(build_parser().parse_args(["train", str(run), *flags]))
    with pytest.raises(DeepCError, match="fusion.max_normal_error.*only the stages refinement, counter, confidence"):
        cmd_train(build_parser().parse_args(["train", str(run), "--refined", "--set", "fusion.max_normal_error=3"]))


def test_the_refinement_weights_its_data_by_the_confidence_before_the_back_facing_rule(vanilla_run, network1):
    """Zeroing back-facing estimates in the data term left fountain_p11's ground without data (its normals went
    wrong by 70 degrees); the rule still holds for filtering and for the written confidence maps."""
    from engine.confidence.inference import facing_away
    from engine.confidence.inputs import network_inputs
    from engine.confidence.options import ConfidenceOptions
    from engine.run.pipeline import confidence_stage, refinement_confidence

    scene = load_scene(TINY)
    maps, counter = [], []
    for v in scene.views:
        depth, normal = read_map(vanilla_run, "depth", v.name), read_map(vanilla_run, "normal", v.name)
        normal[:, : normal.shape[1] // 4] *= -1  # a band of estimates facing away from the camera
        maps.append(ViewMaps(depth, normal, np.zeros_like(depth), np.zeros(depth.shape, np.uint32)))
        counter.append(read_map(vanilla_run, "counter", v.name))
    raw: list[np.ndarray] = []
    ruled = confidence_stage(scene, maps, counter, ConfidenceOptions(zero_backfacing=True), network1, raw=raw)
    away_total = 0
    for v, m, k, c, r in zip(scene.views, maps, counter, ruled, raw, strict=True):
        away = facing_away(network_inputs(scene.image(v.index), m.normal, k, len(v.source_views))) & (m.depth > 0)
        away_total += int(away.sum())
        assert np.all(c[away] == 0) and np.array_equal(c[~away], r[~away])
    assert away_total > 0 and any(np.any(r > c) for r, c in zip(raw, ruled, strict=True))
    assert refinement_confidence(ruled, raw, RefinementOptions()) is raw
    assert refinement_confidence(ruled, raw, RefinementOptions(backfacing_rule=True)) is ruled
