"""Training the confidence network (Kuhn et al. 2020, §3.2): random labelled crops, Adam, ROC-AUC validation
every epoch, best-checkpoint selection, resumable and deterministic for a seed.

Pure engine code: data comes in as :class:`ViewSample` lists, progress goes out through a callback
``progress(event: dict)`` with ``event["kind"]`` in {"step", "epoch", "resume"}.

Determinism: the model is initialised from ``seed``; the crops of epoch e are drawn from a generator
seeded with (seed, e); the learning rate is a function of the global step. A checkpoint written at the
end of every epoch holds the fp32 model, the optimiser state and the history, so a resumed training
continues exactly as an uninterrupted one would.
"""

from __future__ import annotations

import dataclasses
import datetime
import io
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from engine.confidence.data import ViewSample, flip_horizontal
from engine.confidence.inference import autocast, predict_confidence
from engine.confidence.inputs import NORMAL, encode_normals
from engine.confidence.losses import loss_function
from engine.confidence.metrics import roc_auc
from engine.confidence.network import ConfidenceNet, parameter_count
from engine.confidence.options import TrainOptions  # noqa: F401  (re-exported: the options live torch-free)
from engine.confidence.weights import save_weights
from engine.core.errors import DeepCError
from engine.io.atomic import atomic_write_bytes


@dataclasses.dataclass
class ValidationSet:
    """Held-out views scored together (pooled ROC-AUC)."""

    name: str
    samples: list[ViewSample]


def learning_rate(options: TrainOptions, step: int) -> float:
    total = options.epochs * options.steps_per_epoch
    frac = min(1.0, step / max(1, total - 1))
    return options.lr_final + 0.5 * (options.lr - options.lr_final) * (1 + math.cos(math.pi * frac))


def crop_size(options: TrainOptions, samples: list[ViewSample]) -> tuple[int, int]:
    """The crop (height, width): ``options.crop`` clamped to the smallest map, multiples of 16."""
    h = min(s.labels.shape[0] for s in samples)
    w = min(s.labels.shape[1] for s in samples)
    ch, cw = min(options.crop, h - h % 16), min(options.crop, w - w % 16)
    if ch < 16 or cw < 16:
        raise DeepCError(f"training maps are too small for crops ({h}x{w} pixels)")
    return ch, cw


def draw_batch(samples: list[ViewSample], options: TrainOptions, size: tuple[int, int],
               rng: np.random.Generator, probabilities: np.ndarray | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """A batch of random crops with at least ``min_labelled`` labelled pixels (best of 20 tries); views are
    drawn uniformly, or with ``probabilities`` (one per sample, summing to 1)."""
    ch, cw = size
    xs, ys = [], []
    for _ in range(options.batch):
        best = None
        for _ in range(20):
            index = rng.integers(len(samples)) if probabilities is None else rng.choice(len(samples), p=probabilities)
            s = samples[int(index)]
            h, w = s.labels.shape
            y0, x0 = int(rng.integers(h - ch + 1)), int(rng.integers(w - cw + 1))
            labels = s.labels[y0:y0 + ch, x0:x0 + cw]
            frac = float((labels >= 0).mean())
            if best is None or frac > best[0]:
                best = (frac, s, y0, x0)
            if frac >= options.min_labelled:
                break
        _, s, y0, x0 = best
        x, y = s.inputs[:, y0:y0 + ch, x0:x0 + cw], s.labels[y0:y0 + ch, x0:x0 + cw]
        if options.flip and rng.random() < 0.5:
            x, y = flip_horizontal(x, y)
        x = np.array(x, np.float32)
        if options.normal_noise > 0:
            perturb_normals(x, rng.uniform(0, options.normal_noise), rng)
        if options.color_jitter > 0:
            s_ = options.color_jitter
            gain = rng.uniform(1 - s_, 1 + s_) * rng.uniform(1 - s_ / 4, 1 + s_ / 4, 3)
            bias = rng.uniform(-s_ / 2, s_ / 2)
            x[:3] = np.clip(x[:3] * gain[:, None, None] + bias, 0.0, 1.0)
        xs.append(x)
        ys.append(np.asarray(y, np.int64))
    return torch.from_numpy(np.stack(xs)), torch.from_numpy(np.stack(ys))[:, None]


def perturb_normals(x: np.ndarray, sigma: float, rng: np.random.Generator) -> None:
    """Add isotropic Gaussian noise of size ``sigma`` to the unit normals encoded in (6, H, W) ``x`` (in place);
    the result is renormalised and re-encoded; invalid pixels stay (0, 0)."""
    theta_e, phi_e = x[NORMAL.start], x[NORMAL.start + 1]
    valid = (theta_e != 0) | (phi_e != 0)
    theta, phi = theta_e * np.pi, phi_e * (2 * np.pi) - np.pi
    n = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), -np.cos(theta)], axis=-1)
    n = n + rng.normal(0.0, sigma, n.shape).astype(np.float32)
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-6)
    enc = encode_normals(n)
    x[NORMAL] = np.where(valid, np.moveaxis(enc, -1, 0), 0)


def network_widths(options: TrainOptions) -> tuple[int, ...]:
    """Channels of the four U-Net levels: ``base_width`` doubled per level."""
    return tuple(options.base_width * 2 ** k for k in range(4))


def training_device(name: str) -> torch.device:
    """``auto``: a CUDA GPU when torch sees one, else the CPU."""
    if name == "cuda" and not torch.cuda.is_available():
        raise DeepCError("--device cuda: torch sees no CUDA GPU on this machine")
    return torch.device("cuda" if name == "cuda" or (name == "auto" and torch.cuda.is_available()) else "cpu")


def validate_model(model: ConfidenceNet, sets: list[ValidationSet], bf16: bool = True) -> dict[str, Any]:
    """Pooled ROC-AUC ×100 per validation set, per view, and their mean (the selection score)."""
    result: dict[str, Any] = {"sets": {}}
    for vs in sets:
        scores, labels, per_view = [], [], {}
        for s in vs.samples:
            c = predict_confidence(model, s.inputs.astype(np.float32), bf16=bf16)
            keep = s.labels >= 0
            scores.append(c[keep])
            labels.append(s.labels[keep])
            per_view[s.view] = 100 * roc_auc(c[keep], s.labels[keep])
        pooled = 100 * roc_auc(np.concatenate(scores), np.concatenate(labels))
        result["sets"][vs.name] = {"auc": pooled, "per_view": per_view,
                                   "inlier_fraction": float(np.concatenate(labels).mean())}
    aucs = [v["auc"] for v in result["sets"].values() if np.isfinite(v["auc"])]
    result["score"] = float(np.mean(aucs)) if aucs else float("nan")
    return result


def _state_bytes(obj: Any) -> bytes:
    buffer = io.BytesIO()
    torch.save(obj, buffer)
    return buffer.getvalue()


def train(train_samples: list[ViewSample], validation: list[ValidationSet], options: TrainOptions,
          checkpoint: str | Path, weights_out: str | Path | None = None,
          progress: Callable[[dict], None] | None = None, data_names: list[str] | None = None,
          max_epochs: int | None = None, init: ConfidenceNet | None = None,
          init_name: str = "", inputs: dict[str, Any] | None = None,
          probabilities: np.ndarray | None = None) -> dict[str, Any]:
    """Train (or resume from ``checkpoint``) and write the best model to ``weights_out`` (fp16).

    ``data_names`` identify the training data in the checkpoint: resuming with other data or options is
    an error. ``max_epochs`` stops early (after that many epochs in total) without changing the schedule.
    ``init``: start from these weights (warm start, named ``init_name`` in the checkpoint) instead of a
    seeded random initialisation; it must have the architecture ``options.fusion`` asks for.
    ``inputs`` describes maps other than vanilla PatchMatch ones (e.g. refined maps and the weights that guided
    the refinement); it is part of the checkpoint's identity and of the weights' meta (``meta["inputs"]``).
    ``probabilities``: how often each training view is drawn (default: uniformly); part of the identity.
    Returns the history (per-epoch loss, validation, seconds) and the best epoch."""
    options = options.validate()
    progress = progress or (lambda event: None)
    if not train_samples:
        raise DeepCError("no training views")
    if not any((s.labels >= 0).any() for s in train_samples):
        raise DeepCError("the training views have no labelled pixels")
    if options.num_threads:
        torch.set_num_threads(options.num_threads)
    torch.manual_seed(options.seed)
    device = training_device(options.device)
    model = ConfidenceNet(options.fusion, network_widths(options))
    if init is not None:
        if init.architecture != model.architecture:
            raise DeepCError(f"initial weights are for {init.architecture}, training asks for {model.architecture}",
                             init_name or None)
        model.load_state_dict(init.state_dict())
    model.to(device)
    optimizer = torch.optim.Adam(model.parameters(), lr=options.lr, betas=(0.9, 0.999))
    loss_fn = loss_function(options.loss)
    checkpoint = Path(checkpoint)
    # where it trains is not part of what it learns: a checkpoint resumes on another device
    identity = {"options": {k: v for k, v in options.to_dict().items() if k != "device"},
                "data": list(data_names or []), "init": init_name}
    if probabilities is not None:
        probabilities = np.asarray(probabilities, np.float64) / np.sum(probabilities)
        identity["sampling"] = [round(float(p), 9) for p in probabilities]
    if inputs:  # only then, so checkpoints of trainings on vanilla maps stay resumable
        identity["inputs"] = inputs
    state: dict[str, Any] = {"epoch": 0, "history": [], "best": None}
    if checkpoint.is_file():
        try:
            saved = torch.load(checkpoint, map_location="cpu", weights_only=False)
        except Exception as exc:  # noqa: BLE001 - any unreadable checkpoint is reported the same way
            raise DeepCError(f"cannot read training checkpoint ({type(exc).__name__}); delete it to start over",
                             checkpoint) from None
        if saved.get("identity") != identity:
            raise DeepCError("checkpoint was made with other training options or data; use another "
                             "--checkpoint or delete it to start over", checkpoint)
        model.load_state_dict(saved["model"])
        optimizer.load_state_dict(saved["optimizer"])  # Adam moves its state to the parameters' device
        state = {k: saved[k] for k in ("epoch", "history", "best")}
        progress({"kind": "resume", "epoch": state["epoch"]})
    size = crop_size(options, train_samples)
    stop = options.epochs if max_epochs is None else min(options.epochs, max_epochs)
    for epoch in range(state["epoch"], stop):
        rng = np.random.Generator(np.random.PCG64([options.seed, epoch]))
        model.train()
        t0, losses = time.perf_counter(), []
        for i in range(options.steps_per_epoch):
            step = epoch * options.steps_per_epoch + i
            for group in optimizer.param_groups:
                group["lr"] = learning_rate(options, step)
            x, y = draw_batch(train_samples, options, size, rng, probabilities)
            x, y = x.to(device), y.to(device)
            with autocast(options.bf16, device.type):
                logits = model(x.contiguous(memory_format=torch.channels_last))
            loss = loss_fn(logits.float(), y)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            losses.append(float(loss.detach()))
            progress({"kind": "step", "epoch": epoch, "step": i, "steps": options.steps_per_epoch,
                      "loss": losses[-1]})
        train_seconds = time.perf_counter() - t0
        val = validate_model(model, validation, options.bf16) if validation else {"score": float("nan"), "sets": {}}
        model.to(device)  # validation runs on the CPU, as inference does
        entry = {"epoch": epoch + 1, "loss": float(np.mean(losses)), "lr": learning_rate(options, step),
                 "train_seconds": train_seconds, "validation_seconds": time.perf_counter() - t0 - train_seconds,
                 "validation": val}
        state["history"].append(entry)
        score = val["score"]
        improved = state["best"] is None or (np.isfinite(score) and not score <= state["best"]["score"]) or (
            not validation)
        if improved:
            state["best"] = {"epoch": epoch + 1, "score": score, "validation": val}
            if weights_out is not None:
                save_weights(weights_out, model, {**_meta(options, state, data_names, model, init_name),
                                                  **({"inputs": inputs} if inputs else {})})
        state["epoch"] = epoch + 1
        atomic_write_bytes(checkpoint, _state_bytes({
            "identity": identity, "model": model.state_dict(), "optimizer": optimizer.state_dict(), **state}))
        progress({"kind": "epoch", **entry, "best_epoch": state["best"]["epoch"], "improved": improved})
    return {"history": state["history"], "best": state["best"], "epochs_done": state["epoch"],
            "parameters": parameter_count(model)}


def _meta(options: TrainOptions, state: dict, data_names: list[str] | None, model: ConfidenceNet,
          identity_init: str = "") -> dict:
    return {"trained": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            "options": options.to_dict(), "epoch": state["best"]["epoch"], "validation": state["best"]["validation"],
            "train_data": list(data_names or []), "init": identity_init, "parameters": parameter_count(model),
            "train_seconds": float(sum(h["train_seconds"] for h in state["history"])),
            "device": str(next(model.parameters()).device)}
