"""Confidence maps and their ROC-AUC for an existing run folder (used by benchmarks and evaluation)."""

from __future__ import annotations

from typing import Any

import numpy as np

from engine.confidence.data import ViewSample
from engine.confidence.inference import predict_confidence, torch_threads
from engine.confidence.metrics import roc_auc, sparsification
from engine.confidence.network import ConfidenceNet
from engine.confidence.options import ConfidenceOptions


def predict_samples(model: ConfidenceNet, samples: list[ViewSample],
                    options: ConfidenceOptions | None = None) -> list[np.ndarray]:
    """(H, W) confidence per sample; 0 where the sample has no estimate (all-zero normal encoding and counter
    are not a reliable test, so callers mask with their depth maps)."""
    options = (options or ConfidenceOptions()).validate()
    with torch_threads(options.num_threads):
        return [predict_confidence(model, s.inputs.astype(np.float32), options.tile, options.overlap, options.bf16,
                                   options.zero_backfacing) for s in samples]


def auc_report(samples: list[ViewSample], confidence: list[np.ndarray]) -> dict[str, Any]:
    """Pooled ROC-AUC ×100, mean of per-view AUCs, inlier rate and sparsification AUC over labelled pixels."""
    scores = np.concatenate([c[s.labels >= 0] for s, c in zip(samples, confidence, strict=True)])
    labels = np.concatenate([s.labels[s.labels >= 0] for s in samples])
    per_view = [100 * roc_auc(c[s.labels >= 0], s.labels[s.labels >= 0])
                for s, c in zip(samples, confidence, strict=True)]
    sp = sparsification(scores, labels)
    return {"auc": 100 * roc_auc(scores, labels), "auc_mean_per_view": float(np.nanmean(per_view)),
            "per_view": {s.view: a for s, a in zip(samples, per_view, strict=True)},
            "labelled": int(labels.size), "inlier_pct": 100 * float(labels.mean()),
            "sparsification_auc": sp["auc"], "sparsification_optimal": sp["optimal"]}

