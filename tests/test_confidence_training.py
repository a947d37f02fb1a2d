"""Training on the tiny scene (loss falls, resume is exact), `deepc train` and `deepc run --pipeline fast`."""

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

from engine.confidence.data import load_run
from engine.confidence.network import ConfidenceNet
from engine.confidence.weights import save_weights
from engine.core.errors import DeepCError
from engine.fusion import DEFAULT_PRESET, FUSION_PRESETS
from engine.training.trainer import TrainOptions, ValidationSet, train

REPO = Path(__file__).resolve().parent.parent
TINY = REPO / "sample_scenes" / "tiny"


@pytest.fixture(scope="module")
def noisy_run(tmp_path_factory) -> Path:
    return make_noisy_run(TINY, tmp_path_factory.mktemp("noisy_run"))


OPTIONS = TrainOptions(epochs=2, steps_per_epoch=4, batch=2, crop=64, bf16=False, lr=2e-3, lr_final=1e-3, seed=5)


def test_labels_of_a_run(noisy_run):
    samples = load_run(noisy_run)
    assert len(samples) == 5
    labels = np.concatenate([s.labels.ravel() for s in samples])
    assert 0.05 < (labels == 0).mean() < 0.6 and (labels == 1).mean() > 0.3


def test_training_loss_falls_and_resume_is_exact(noisy_run, tmp_path):
    samples = load_run(noisy_run)
    val = [ValidationSet("tiny", samples[:1])]
    full = train(samples[1:], val, OPTIONS, tmp_path / "a.ckpt", tmp_path / "a.pt", data_names=["tiny"])
    losses = [h["loss"] for h in full["history"]]
    assert losses[-1] < losses[0]
    assert (tmp_path / "a.pt").is_file() and 0 <= full["best"]["score"] <= 100

    events = []
    part = train(samples[1:], val, OPTIONS, tmp_path / "b.ckpt", tmp_path / "b.pt", data_names=["tiny"],
                 max_epochs=1)
    assert part["epochs_done"] == 1
    resumed = train(samples[1:], val, OPTIONS, tmp_path / "b.ckpt", tmp_path / "b.pt", data_names=["tiny"],
                    progress=events.append)
    assert events[0] == {"kind": "resume", "epoch": 1}
    assert [h["loss"] for h in resumed["history"]] == pytest.approx(losses, rel=1e-6)
    a = torch.load(tmp_path / "a.ckpt", weights_only=False)["model"]
    b = torch.load(tmp_path / "b.ckpt", weights_only=False)["model"]
    assert all(torch.allclose(a[k].float(), b[k].float(), atol=1e-6) for k in a)

    with pytest.raises(DeepCError, match="other training options"):
        train(samples[1:], val, OPTIONS.replace(loss="bce"), tmp_path / "b.ckpt")


def deepc(*args, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "workbench.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, cwd=REPO)


def test_train_command_refuses_scenes_without_gt(tmp_path):
    result = deepc("train", REPO / "sample_scenes" / "middlebury_temple", "--cache", tmp_path / "cache",
                   "--out", tmp_path / "w.pt")
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "middlebury_temple" in lines[0] and "ground-truth depth" in lines[0]
    assert not (tmp_path / "w.pt").exists()


def test_train_command_on_a_run_writes_weights(noisy_run, tmp_path):
    out = tmp_path / "w.pt"
    result = deepc("train", noisy_run, "--out", out, "--epochs", "1", "--steps-per-epoch", "2", "--batch", "1",
                   "--crop", "64", "--no-bf16")
    assert result.returncode == 0, result.stderr
    assert "epoch 1: loss" in result.stderr
    assert json.loads(result.stdout.strip().splitlines()[-1])["epochs_done"] == 1
    history = json.loads(out.with_name("w.history.json").read_text())
    assert history["epochs_done"] == 1 and out.is_file()


@pytest.mark.slow
def test_run_fast_writes_confidence_maps_and_auc(tmp_path):
    torch.manual_seed(0)
    weights = save_weights(tmp_path / "random.pt", ConfidenceNet())
    out = tmp_path / "out"
    result = deepc("run", TINY, "--out", out, "--pipeline", "fast", "--headless", "--iterations", "1",
                   "--levels", "1", "--weights", weights, "--set", "confidence.tau=0.5")
    assert result.returncode == 0, result.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["pipeline"] == "fast" and 0 <= metrics["confidence_auc"] <= 100
    assert metrics["seconds"]["confidence"] > 0 and metrics["options"]["confidence"]["tau"] == 0.5
    from engine.run.folder import read_map
    from engine.scene import load_scene
    kept = valid = 0
    for v in load_scene(TINY).views:
        c, depth = read_map(out, "confidence", v.name), read_map(out, "depth", v.name)
        assert c is not None and c.shape == (120, 160) and (c >= 0).all() and (c <= 1).all()
        kept += int(((c >= 0.5) & (depth > 0)).sum())
        valid += int((depth > 0).sum())
    assert metrics["confidence_kept_pct"] == pytest.approx(100 * kept / valid)

    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not torch")
    result = deepc("run", TINY, "--out", tmp_path / "o2", "--pipeline", "fast", "--headless", "--weights", bad)
    assert result.returncode == 2 and "bad.pt" in result.stderr and len(result.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "o2").exists()


@pytest.mark.slow
def test_run_full_writes_refined_maps_and_fuses_them(tmp_path):
    out = tmp_path / "out"
    result = deepc("run", TINY, "--out", out, "--pipeline", "full", "--headless", "--iterations", "1",
                   "--levels", "1", "--set", "refinement.scales=2", "--set", "refinement.fast_iters=60,40",
                   "--set", "refinement.iters=10,10", "--set", "refinement.lr=0.01,0.01",
                   "--set", "refinement.lr_slots=1,1")
    assert result.returncode == 0, result.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["pipeline"] == "full" and metrics["seconds"]["refinement"] > 0
    assert metrics["options"]["fusion"] == FUSION_PRESETS[DEFAULT_PRESET].to_dict()  # same default as vanilla
    # refinement fills holes: every GT pixel has a refined estimate, while PatchMatch's own maps stay as they were
    assert metrics["refined_depth"]["valid_fraction"] > 99.0
    assert metrics["refined_depth"]["within_5pct"] >= metrics["depth"]["within_5pct"] - 5.0
    # what full fuses: PatchMatch's confident estimates, refined ones elsewhere (refinement.keep_confident)
    assert metrics["full_depth"]["valid_fraction"] >= metrics["depth"]["valid_fraction"]
    assert metrics["full_depth"]["within_1pct"] != metrics["refined_depth"]["within_1pct"]
    from engine.io.ply import read_points
    from engine.run.folder import read_map
    from engine.scene import load_scene
    for v in load_scene(TINY).views:
        depth, normal = read_map(out, "refined_depth", v.name), read_map(out, "refined_normal", v.name)
        assert depth.shape == (120, 160) and normal.shape == (120, 160, 3)
        valid = depth > 0
        assert valid.mean() > 0.9 and np.allclose(np.linalg.norm(normal[valid], axis=-1), 1.0, atol=1e-3)
        assert read_map(out, "confidence", v.name) is not None
        # the refined maps' own counter maps and confidence (training data of a second network)
        counter, confidence = read_map(out, "refined_counter", v.name), read_map(out, "refined_confidence", v.name)
        assert counter.shape == confidence.shape == (120, 160) and counter[valid].max() >= 1
        assert (confidence[~valid] == 0).all() and 0 < confidence[valid].mean() <= 1
    assert metrics["fused_points"] == len(read_points(out / "fused.ply")) > 0
    assert 0 <= metrics["refined_confidence_auc"] <= 100

    # refine_run on the same run and options takes the full run's refined maps as they are, and refining its
    # vanilla maps again gives exactly those maps
    from engine.run.folder import REFINED_KINDS
    from engine.run.pipeline import PipelineOptions
    from engine.run.refine import refine_run
    options = PipelineOptions.from_dict({k: v for k, v in metrics["options"].items() if k != "scene"})
    assert refine_run(out, options=options).reused
    with pytest.raises(DeepCError, match="would overwrite outputs of the run"):
        refine_run(out, options=options.replace(refinement=options.refinement.replace(lambda_reg=2.0)))
    names = [v.name for v in load_scene(TINY).views]
    saved = {(k, n): read_map(out, k, n) for k in REFINED_KINDS for n in names}
    shutil.rmtree(out / "refined")
    assert not refine_run(out, options=options).reused
    for (kind, name), array in saved.items():
        np.testing.assert_array_equal(read_map(out, kind, name), array, err_msg=f"{kind} {name}")


def test_views_are_drawn_by_their_probabilities(noisy_run):
    from engine.training.trainer import crop_size, draw_batch

    samples = load_run(noisy_run)
    options = TrainOptions(batch=1, crop=32, flip=False, normal_noise=0, color_jitter=0, min_labelled=0)
    rng = np.random.default_rng(0)
    probabilities = np.array([0.0, 0.0, 1.0, 0.0, 0.0])
    size = crop_size(options, samples)
    target = samples[2].inputs.astype(np.float32)
    for _ in range(5):  # every crop comes from view 2, the only one with a non-zero probability
        x, _ = draw_batch(samples, options, size, rng, probabilities)
        crop = x[0].numpy()
        windows = np.lib.stride_tricks.sliding_window_view(target[0], crop.shape[1:])
        assert np.any(np.all(windows == crop[0], axis=(-1, -2)))


def test_training_on_a_missing_gpu_is_a_clear_error(noisy_run, tmp_path):
    if torch.cuda.is_available():
        pytest.skip("this machine has a CUDA GPU")
    samples = load_run(noisy_run)
    with pytest.raises(DeepCError, match="no CUDA GPU"):
        train(samples, [], OPTIONS.replace(device="cuda"), tmp_path / "c.ckpt")
    assert not (tmp_path / "c.ckpt").exists()


def test_training_width_sets_the_architecture(noisy_run, tmp_path):
    from engine.confidence.weights import load_weights

    samples = load_run(noisy_run)
    train(samples, [], OPTIONS.replace(base_width=4, epochs=1, steps_per_epoch=1), tmp_path / "d.ckpt",
          tmp_path / "d.pt")
    assert load_weights(tmp_path / "d.pt").widths == (4, 8, 16, 32)
