"""Training losses over labelled pixels (Kuhn et al. 2020, §3.2). All take (B, 1, H, W) logits and int labels
(1 inlier, 0 outlier, -1 unlabeled, ignored) and pool over the whole mini-batch.

- ``deepc_squared``: mean_P (c − 1)² + mean_N c² (class-balanced MSE, the default reading of eq. 1).
- ``deepc_l2``: ‖c_P − 1‖₂ / |P| + ‖c_N‖₂ / |N| (eq. 1 read literally, unsquared Euclidean norm).
  In both, a term whose class is empty in the batch is dropped.
- ``bce``: binary cross-entropy over labelled pixels.
- ``wbce``: BCE with outliers weighted ×3, normalised by the sum of weights.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from engine.confidence.options import LOSSES

NEGATIVE_WEIGHT = 3.0


def deepc_loss(logits: torch.Tensor, labels: torch.Tensor, norm: str = "squared") -> torch.Tensor:
    c = torch.sigmoid(logits)
    total = logits.new_zeros(())
    for target in (1, 0):
        mask = labels == target
        n = int(mask.sum())
        if n == 0:
            continue
        diff = c[mask] - target
        if norm == "squared":
            total = total + (diff * diff).mean()
        elif norm == "l2":
            total = total + torch.sqrt((diff * diff).sum() + 1e-12) / n
        else:
            raise ValueError(f"deepc loss norm must be 'squared' or 'l2', got {norm!r}")
    return total


def bce_loss(logits: torch.Tensor, labels: torch.Tensor, negative_weight: float = 1.0) -> torch.Tensor:
    mask = labels >= 0
    if not bool(mask.any()):
        return logits.new_zeros(())
    y = labels[mask].to(logits.dtype)
    weight = torch.where(y > 0.5, torch.ones_like(y), torch.full_like(y, negative_weight))
    return F.binary_cross_entropy_with_logits(logits[mask], y, weight=weight, reduction="sum") / weight.sum()


def loss_function(name: str):
    """The loss called ``name`` (one of :data:`LOSSES`) as f(logits, labels)."""
    table = {
        "deepc_squared": lambda lg, lb: deepc_loss(lg, lb, "squared"),
        "deepc_l2": lambda lg, lb: deepc_loss(lg, lb, "l2"),
        "bce": lambda lg, lb: bce_loss(lg, lb, 1.0),
        "wbce": lambda lg, lb: bce_loss(lg, lb, NEGATIVE_WEIGHT),
    }
    if name not in table:
        raise ValueError(f"loss must be one of {', '.join(LOSSES)}, got {name!r}")
    return table[name]
