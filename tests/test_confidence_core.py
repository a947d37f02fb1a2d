"""Confidence network building blocks: label rule, input encoding, network, losses, AUC, tiling, weights."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch

from engine.confidence.data import flip_horizontal
from engine.confidence.inference import predict_confidence
from engine.confidence.inputs import encode_normals, network_inputs
from engine.confidence.labels import label_map
from engine.confidence.losses import bce_loss, deepc_loss, loss_function
from engine.confidence.metrics import roc_auc, sparsification
from engine.confidence.network import ConfidenceNet, parameter_count
from engine.confidence.weights import load_weights, read_weights_file, save_weights
from engine.core.camera import Camera
from engine.core.errors import DeepCError


def _look_at(center: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    z = target - center
    z /= np.linalg.norm(z)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    return R, -R @ center


def _random_cameras(rng: np.random.Generator, n: int, w: int = 24, h: int = 18) -> list[Camera]:
    cams = []
    for _ in range(n):
        R, t = _look_at(np.array([rng.uniform(-1, 1), rng.uniform(-0.5, 0.5), -4.0]), np.zeros(3))
        cams.append(Camera.from_params(w, h, rng.uniform(20, 30), rng.uniform(20, 30), w / 2 + rng.uniform(-2, 2),
                                       h / 2 + rng.uniform(-2, 2), R, t))
    return cams


def _label_reference(depth, gt, cam, sources, max_depth, thr=2.0):
    """Plain per-pixel loop of Kuhn et al. 2020, §3.2."""
    out = np.full(depth.shape, -1, np.int8)
    Ki = np.linalg.inv(cam.K_idx)
    for r, c in itertools.product(range(depth.shape[0]), range(depth.shape[1])):
        z, zs = depth[r, c], gt[r, c]
        if not (z > 0 and np.isfinite(zs) and zs > 0 and z <= max_depth):
            continue
        ray = Ki @ np.array([c, r, 1.0])
        points = [cam.R.T @ (ray * d - cam.t) for d in (z, zs)]
        counted = inlier = False
        for src in sources:
            proj = []
            for X in points:
                Xc = src.R @ X + src.t
                uvw = src.K_idx @ Xc
                proj.append((uvw[:2] / uvw[2], Xc[2]))
            (a, za), (b, zb) = proj
            inside = any(-0.5 <= p[0] < src.width - 0.5 and -0.5 <= p[1] < src.height - 0.5 for p in (a, b))
            if za > 0 and zb > 0 and inside:
                counted = True
                inlier |= bool(np.hypot(*(a - b)) < thr)
        if counted:
            out[r, c] = int(inlier)
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_label_map_matches_a_plain_loop(seed):
    rng = np.random.default_rng(seed)
    ref, *sources = _random_cameras(rng, 4)
    gt = rng.uniform(3.0, 5.0, (ref.height, ref.width))
    gt[rng.random(gt.shape) < 0.1] = 0
    gt[0, 0] = np.inf
    depth = gt * np.exp(rng.normal(0, 0.08, gt.shape))  # mix of inliers and outliers
    depth[rng.random(gt.shape) < 0.1] = 0
    depth[1, 1] = 50.0  # unreasonably far
    depth[2, 2] = 0.01  # so near that its projection leaves every source image
    labels = label_map(depth, gt, ref, sources, max_depth=10.0)
    np.testing.assert_array_equal(labels, _label_reference(depth, gt, ref, sources, 10.0))
    assert labels[1, 1] == -1 and (labels == 1).any() and (labels == 0).any()
    exact = label_map(np.where(depth > 0, gt, 0), gt, ref, sources, max_depth=10.0)
    assert set(np.unique(exact)) <= {-1, 1}  # the GT depth itself is always an inlier


def test_polar_normal_encoding_and_flip():
    rng = np.random.default_rng(0)
    n = rng.normal(size=(5, 7, 3))
    n[0, 1] = (0.0, 0.6, 0.8)  # facing away: θ > 90° stays distinct from grazing
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    n[0, 0] = 0.0
    n[1, 1] = (0.0, 0.0, -1.0)
    enc = encode_normals(n)
    assert enc.shape == (5, 7, 2) and enc.dtype == np.float32
    assert (enc[0, 0] == 0).all() and enc[1, 1, 0] == 0 and enc[0, 1, 0] > 0.5
    assert (enc >= 0).all() and (enc <= 1).all()
    theta = enc[..., 0] * np.pi
    np.testing.assert_allclose(np.cos(theta)[n.any(-1)], -n[..., 2][n.any(-1)], atol=1e-6)
    phi = enc[..., 1] * 2 * np.pi - np.pi
    keep = n.any(-1) & (np.hypot(n[..., 0], n[..., 1]) > 1e-3)
    np.testing.assert_allclose(np.cos(phi)[keep] * np.hypot(n[..., 0], n[..., 1])[keep], n[..., 0][keep], atol=1e-5)

    rgb = rng.integers(0, 255, (5, 7, 3), dtype=np.uint8)
    counter = rng.integers(0, 6, (5, 7))
    x = network_inputs(rgb, n, counter, 4)
    assert x.shape == (6, 5, 7) and x[5].max() == 1.0 and np.isclose(x[0, 2, 3], rgb[2, 3, 0] / 255)
    np.testing.assert_allclose(x[5], np.minimum(counter, 4) / 4)
    mirrored = n[:, ::-1].copy()
    mirrored[..., 0] *= -1
    expected = network_inputs(rgb[:, ::-1], mirrored, counter[:, ::-1], 4)
    labels = rng.integers(-1, 2, (5, 7)).astype(np.int8)
    flipped, flipped_labels = flip_horizontal(x, labels)
    # φ wraps at ±π: compare on the circle
    diff = np.abs(flipped - expected)
    diff[4] = np.minimum(diff[4], 1 - diff[4])
    assert diff.max() < 1e-5
    np.testing.assert_array_equal(flipped_labels, labels[:, ::-1])


def test_network_shapes_and_parameter_counts():
    middle, early = ConfidenceNet("middle"), ConfidenceNet("early")
    assert 7.9e6 < parameter_count(middle) < 8.2e6  # "≈8 M" of Kuhn et al. 2020, §3.2
    assert parameter_count(early) < parameter_count(middle) / 2
    torch.manual_seed(0)
    x = torch.rand(2, 6, 48, 64)
    for model in (middle, early):
        assert model.eval()(x).shape == (2, 1, 48, 64)
    with pytest.raises(ValueError):
        ConfidenceNet("late")


def test_losses_match_hand_computation():
    logits = torch.tensor([[[[0.0, 2.0], [-1.0, 3.0]]]])
    labels = torch.tensor([[[[1, 0], [-1, 1]]]])
    c = torch.sigmoid(logits).flatten()
    pos, neg = c[[0, 3]], c[[1]]
    squared = ((pos - 1) ** 2).mean() + (neg ** 2).mean()
    l2 = torch.sqrt(((pos - 1) ** 2).sum()) / 2 + torch.sqrt((neg ** 2).sum()) / 1
    assert torch.isclose(deepc_loss(logits, labels, "squared"), squared)
    assert torch.isclose(deepc_loss(logits, labels, "l2"), l2)
    only_pos = torch.tensor([[[[1, -1], [-1, 1]]]])  # empty outlier class: its term is dropped
    assert torch.isclose(deepc_loss(logits, only_pos, "squared"), ((pos - 1) ** 2).mean())
    y = torch.tensor([1.0, 0.0, 1.0])
    p = c[[0, 1, 3]]
    bce = -(y * torch.log(p) + (1 - y) * torch.log(1 - p)).mean()
    w = torch.tensor([1.0, 3.0, 1.0])
    wbce = -(w * (y * torch.log(p) + (1 - y) * torch.log(1 - p))).sum() / w.sum()
    assert torch.isclose(loss_function("bce")(logits, labels), bce, atol=1e-6)
    assert torch.isclose(loss_function("wbce")(logits, labels), wbce, atol=1e-6)
    assert bce_loss(logits, torch.full_like(labels, -1)) == 0


def test_roc_auc_equals_brute_force_pairs():
    rng = np.random.default_rng(3)
    scores = rng.integers(0, 6, 300) / 5.0  # many ties
    labels = rng.integers(-1, 2, 300)
    pos, neg = scores[labels == 1], scores[labels == 0]
    brute = np.mean([(a > b) + 0.5 * (a == b) for a in pos for b in neg])
    assert roc_auc(scores, labels) == pytest.approx(brute, abs=1e-12)
    assert roc_auc(np.array([0.9, 0.1]), np.array([1, 0])) == 1.0
    assert np.isnan(roc_auc(np.array([0.9, 0.1]), np.array([1, 1])))
    perfect = sparsification(np.array([0.9, 0.8, 0.2, 0.1]), np.array([1, 1, 0, 0]))
    worst = sparsification(np.array([0.1, 0.2, 0.8, 0.9]), np.array([1, 1, 0, 0]))
    assert perfect["auc"] < worst["auc"]


def test_tiled_inference_equals_untiled():
    torch.manual_seed(0)
    model = ConfidenceNet().eval()
    rng = np.random.default_rng(0)
    x = rng.random((6, 100, 150)).astype(np.float32)
    whole = predict_confidence(model, x, tile=512)
    tiled = predict_confidence(model, x, tile=96, overlap=32)
    assert whole.shape == (100, 150) and (whole >= 0).all() and (whole <= 1).all()
    assert np.abs(whole - tiled).max() < 0.02  # padding differs at tile borders only within the overlap
    masked = predict_confidence(model, x, tile=512, zero_backfacing=True)
    away = x[3] > 0.5  # θ > 90°: the estimated surface faces away from the camera
    assert away.any() and (masked[away] == 0).all() and np.array_equal(masked[~away], whole[~away])


def test_weights_round_trip_and_errors(tmp_path):
    torch.manual_seed(1)
    model = ConfidenceNet("early")
    path = save_weights(tmp_path / "w.pt", model, {"note": "test"})
    loaded = load_weights(path)
    assert loaded.fusion == "early" and loaded.meta == {"note": "test"}
    x = torch.rand(1, 6, 32, 32)
    with torch.inference_mode():
        assert torch.allclose(model.eval()(x), loaded(x), atol=5e-2)  # fp16 storage
    with pytest.raises(DeepCError, match="missing.pt.*not found"):
        load_weights(tmp_path / "missing.pt")
    (tmp_path / "corrupt.pt").write_bytes(path.read_bytes()[:5000])
    with pytest.raises(DeepCError, match="corrupt.pt.*corrupt"):
        load_weights(tmp_path / "corrupt.pt")
    torch.save({"weights": 1}, tmp_path / "other.pt")
    with pytest.raises(DeepCError, match="other.pt.*not a DeepC confidence weights file"):
        read_weights_file(tmp_path / "other.pt")
    with pytest.raises(DeepCError, match="w.pt.*fusion='early', expected 'middle'"):
        load_weights(path, expect={"fusion": "middle"})
    data = torch.load(path, weights_only=True)
    data["architecture"]["fusion"] = "middle"  # claims another architecture than its tensors
    torch.save(data, tmp_path / "liar.pt")
    with pytest.raises(DeepCError, match="liar.pt.*do not fit") as info:
        load_weights(tmp_path / "liar.pt")
    assert "\n" not in str(info.value)


def test_shipped_weights_load():
    from engine.confidence.weights import DEFAULT_WEIGHTS

    model = load_weights()
    assert model.fusion == "middle" and DEFAULT_WEIGHTS.stat().st_size <= 20 * 2**20
    assert model.meta["validation"]["sets"]
