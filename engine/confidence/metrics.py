"""Confidence metrics (Kuhn et al. 2020, §3.2): exact ROC-AUC and sparsification curves."""

from __future__ import annotations

import numpy as np


def roc_auc(scores: np.ndarray, labels: np.ndarray) -> float:
    """ROC-AUC = P(c+ > c-) + ½ P(c+ = c-) over labelled pixels (labels 1 / 0; others ignored), exact
    via Mann-Whitney ranks (ties get average ranks). NaN when a class is empty. Not ×100."""
    scores = np.asarray(scores, np.float64).ravel()
    labels = np.asarray(labels).ravel()
    keep = (labels == 0) | (labels == 1)
    scores, positive = scores[keep], labels[keep] == 1
    n_pos, n_neg = int(positive.sum()), int((~positive).sum())
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    from scipy.stats import rankdata  # lazy: scipy.stats costs ~33 MiB in every process that imports this

    ranks = rankdata(scores)
    return float((ranks[positive].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


def sparsification(scores: np.ndarray, labels: np.ndarray, steps: int = 20) -> dict[str, float]:
    """Sparsification AUC (lower is better): keep the top q of labelled pixels by confidence for
    q = 1/steps … 1, outlier rate ε(q) among them, trapezoid integral over q ∈ [0, 1] (ε(0) := ε(1/steps)).
    Returns ``auc``, ``optimal`` = ε + (1 − ε) ln(1 − ε) and their ratio."""
    scores = np.asarray(scores, np.float64).ravel()
    labels = np.asarray(labels).ravel()
    keep = (labels == 0) | (labels == 1)
    scores, outlier = scores[keep], labels[keep] == 0
    if scores.size == 0:
        return {"auc": float("nan"), "optimal": float("nan"), "ratio": float("nan")}
    order = np.argsort(-scores, kind="stable")
    cum = np.cumsum(outlier[order])
    q = np.arange(1, steps + 1) / steps
    counts = np.maximum(1, np.round(q * scores.size).astype(int))
    eps = cum[counts - 1] / counts
    auc = float(np.trapezoid(np.concatenate([[eps[0]], eps]), np.concatenate([[0.0], q])))
    e = float(outlier.mean())
    optimal = e + (1 - e) * np.log(1 - e) if e < 1 else 1.0
    return {"auc": auc, "optimal": float(optimal), "ratio": auc / optimal if optimal > 0 else float("nan")}
