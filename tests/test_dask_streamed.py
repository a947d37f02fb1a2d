"""The driver of an executor run streams its later stages from the run folder (engine/run/distributed/streamed.py;
metrics through engine/run/scores.py and engine/evaluation/pooled.py): pooled sums and ROC-AUC accumulated view by
view equal numpy's on the concatenation to the last bit, and the streamed fusion and metrics equal the in-process
pipeline's on the same maps."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from engine.confidence.metrics import roc_auc
from engine.evaluation.depth import DEPTH_KEYS, depth_metrics
from engine.evaluation.pooled import PooledRankSum, pairwise_sum
from engine.fusion import FUSION_PRESETS, FusedCloud, fuse, views_from_scene
from engine.fusion.cached import CacheStats
from engine.run.distributed.streamed import fuse_run_folder, streamed_metrics
from engine.run.folder import read_map, write_map
from engine.run.fused_maps import FusionRule
from engine.run.per_view import view_auc
from engine.run.scores import confidence_auc, depth_block
from engine.scene import load_scene
from support.fake_run import make_fake_run
from tests.conftest import SAMPLES, make_noisy_run


@pytest.mark.parametrize("n", [0, 1, 7, 8, 100, 128, 129, 1000, 8191, 8193, 40_001, 300_017])
@pytest.mark.parametrize("block", [128, 1000, 1 << 20])
def test_pairwise_sum_is_numpys_sum_of_the_concatenation(n, block):
    rng = np.random.default_rng(n)
    values = rng.random(n) * rng.exponential(size=n)
    cuts = np.sort(rng.integers(0, n + 1, 7))
    chunks = np.split(values, cuts)
    assert pairwise_sum(iter(chunks), n, block) == np.add.reduce(values)
    with pytest.raises(ValueError, match="more than"):
        pairwise_sum([values, np.ones(3)], n, block)


def test_pooled_rank_sum_is_roc_auc_of_the_concatenation():
    rng = np.random.default_rng(0)
    pooled, scores, labels = PooledRankSum(), [], []
    for _ in range(6):
        s = np.round(rng.random(5000), 2).astype(np.float32)  # many ties, within and across views
        y = np.where(rng.random(5000) < s, 1, 0) - (rng.random(5000) < 0.1)  # -1: unlabelled
        pooled.add(s, y)
        scores.append(s)
        labels.append(y)
    assert pooled.auc() == roc_auc(np.concatenate(scores), np.concatenate(labels))
    empty = PooledRankSum()
    empty.add(np.ones(3), np.ones(3))
    assert np.isnan(empty.auc())


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Run folders of sample_scenes/tiny: made from GT depth with confidence ramps (no outliers), and with outlier
    blobs and a confidence of two decimals (ties) that partly tells them apart."""
    fake = make_fake_run(SAMPLES / "tiny", tmp_path_factory.mktemp("fake"))
    noisy = make_noisy_run(SAMPLES / "tiny", tmp_path_factory.mktemp("noisy"))
    scene = load_scene(SAMPLES / "tiny")
    rng = np.random.default_rng(1)
    for v in scene.views:
        counter = read_map(noisy, "counter", v.name)
        write_map(noisy, "confidence", v.name, np.round(counter / 5 * rng.random(counter.shape), 2))
    return scene, fake, noisy


def _maps(scene, out, kinds):
    return [[read_map(out, kind, v.name) for v in scene.views] for kind in kinds]


@pytest.mark.parametrize("which", [1, 2])
def test_streamed_metrics_are_the_in_process_ones(runs, which):
    scene, run = runs[0], runs[which]
    depth, confidence = _maps(scene, run, ("depth", "confidence"))
    # the reference: numpy on the concatenated views, as the pipeline scored before it pooled view by view
    gt = [scene.gt_depth(v.index) for v in scene.views]
    pooled = depth_metrics(np.concatenate([d.ravel() for d in depth]), np.concatenate([g.ravel() for g in gt]))
    want_depth = {k: pooled[k] for k in DEPTH_KEYS}
    want_per_view = [{"view": v.name, **depth_metrics(d, g)} for v, d, g in zip(scene.views, depth, gt, strict=True)]
    entries = [view_auc(scene, v, d, c) for v, d, c in zip(scene.views, depth, confidence, strict=True)]
    auc = {"pooled": 100 * roc_auc(np.concatenate([e[1] for e in entries]), np.concatenate([e[2] for e in entries])),
           "per_view": [e[0] for e in entries]}
    # in memory (the in-process pipeline) and read back from the run folder (streamed): the same, to the bit
    assert json.dumps(depth_block(scene, lambda i: depth[i])) == json.dumps((want_depth, want_per_view))
    assert json.dumps(confidence_auc(scene, lambda i: depth[i], lambda i: confidence[i])) == json.dumps(auc)
    tau = 0.4
    kept = sum(int((np.where(c >= tau, d, 0) > 0).sum()) for d, c in zip(depth, confidence, strict=True))
    got = streamed_metrics(scene, run, FusionRule("fast", tau))
    assert list(got) == ["depth", "depth_per_view", "confidence_auc", "confidence_auc_per_view",
                         "confidence_kept_pct"]
    want = {"depth": want_depth, "depth_per_view": want_per_view}
    # as metrics.json stores them: floats written exactly, NaN as NaN (the GT-depth maps have no outliers: no AUC)
    assert json.dumps(got) == json.dumps({**want, "confidence_auc": auc["pooled"],
                                          "confidence_auc_per_view": auc["per_view"],
                                          "confidence_kept_pct": 100.0 * kept / sum(int((d > 0).sum()) for d in depth)})
    assert np.isnan(got["confidence_auc"]) == (which == 1)
    assert json.dumps(streamed_metrics(scene, run, FusionRule("vanilla"))) == json.dumps(want)


@pytest.mark.parametrize("tau", [None, 0.3])
def test_streamed_fusion_is_the_in_process_cloud(runs, tau):
    from engine.filtering import filter_by_confidence

    scene, _, out = runs
    depth, normal, confidence = _maps(scene, out, ("depth", "normal", "confidence"))
    if tau is not None:
        depth, normal = zip(*(filter_by_confidence(d, n, c, tau) for d, n, c in zip(depth, normal, confidence,
                                                                                     strict=True)), strict=True)
    options = FUSION_PRESETS["pixels"]
    want = fuse(views_from_scene(scene, list(depth), list(normal), confidence if tau is not None else None),
                options)
    stats = CacheStats()
    cache = None if tau is None else 4  # None: 1 + the longest overlap list, every view of tiny
    rule = FusionRule("vanilla") if tau is None else FusionRule("fast", tau)
    got = fuse_run_folder(scene, out, options, rule, cache_views=cache, stats=stats)
    assert (stats.evictions > 0) == (cache is not None) and stats.peak_resident == (cache or 5) and len(want) > 1000
    for f in dataclasses.fields(FusedCloud):
        assert getattr(got, f.name).tobytes() == getattr(want, f.name).tobytes(), f.name
