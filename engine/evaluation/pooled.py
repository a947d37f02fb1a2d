"""Metrics pooled over every pixel of every view, accumulated one view at a time, equal to the numbers of the pooled
numpy computations (``engine.evaluation.depth.depth_metrics`` and ``engine.confidence.metrics.roc_auc`` of the
concatenated views) to the last bit, without holding all the pixels.

- A mean of float64 values: numpy sums a contiguous float64 array pairwise (``pairwise_sum`` in numpy's
  ``loops_utils.h``: halves rounded down to a multiple of 8, blocks of at most 128 summed with 8 accumulators). The
  tree depends only on the number of values, so with that number known (a first pass over the views) the sum is
  rebuilt by descending the tree and summing each subtree of at most ``block`` values with numpy itself.
- ROC-AUC by Mann-Whitney ranks with ties averaged: the sum of the positives' ranks is a sum of half-integers, exact
  in float64 (below 2^52) whatever the order, so counts per distinct score give it exactly.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable

import numpy as np


def pairwise_sum(chunks: Iterable[np.ndarray], n: int, block: int = 1 << 20) -> float:
    """``np.add.reduce(np.concatenate(chunks))`` for float64 chunks holding ``n`` values in all, holding at most
    ``block`` (>= 128) values at once besides the current chunk."""
    if block < 128:
        raise ValueError(f"block must be at least 128, got {block}")
    source = iter(chunks)
    pending: deque[np.ndarray] = deque()

    def take(m: int) -> np.ndarray:
        parts, got = [], 0
        while got < m:
            if not pending:
                pending.append(np.asarray(next(source), np.float64).ravel())
                continue
            head = pending.popleft()
            if got + head.size > m:
                pending.appendleft(head[m - got:])
                head = head[:m - got]
            parts.append(head)
            got += head.size
        return np.concatenate(parts) if len(parts) != 1 else np.ascontiguousarray(parts[0])

    def subtree(m: int) -> float:
        if m <= block:
            return np.add.reduce(take(m)) if m else np.float64(0.0)
        half = m // 2
        half -= half % 8
        return subtree(half) + subtree(m - half)

    total = subtree(n)
    if any(p.size for p in pending) or next((c for c in source if np.size(c)), None) is not None:
        raise ValueError(f"the chunks hold more than {n} values")
    return total


class PooledRankSum:
    """ROC-AUC (×1, as ``roc_auc``) of scores pooled over views, from the counts of positives and negatives per
    distinct score (memory: the distinct scores seen, not the pixels)."""

    def __init__(self):
        self.values = np.zeros(0, np.float64)
        self.pos = np.zeros(0, np.int64)
        self.neg = np.zeros(0, np.int64)
        self.has_nan = False
        self.views = 0

    def add(self, scores: np.ndarray, labels: np.ndarray) -> None:
        """One view's scores and labels (1 inlier, 0 outlier, others ignored)."""
        scores = np.asarray(scores, np.float64).ravel()
        labels = np.asarray(labels).ravel()
        keep = (labels == 0) | (labels == 1)
        scores, positive = scores[keep], labels[keep] == 1
        self.views += 1
        if np.isnan(scores).any():
            self.has_nan = True  # rankdata propagates NaN
            return
        values, inverse = np.unique(np.concatenate([self.values, scores]), return_inverse=True)
        size = len(values)
        pos = np.bincount(inverse[:len(self.values)], self.pos, size) + np.bincount(
            inverse[len(self.values):], positive, size)
        neg = np.bincount(inverse[:len(self.values)], self.neg, size) + np.bincount(
            inverse[len(self.values):], ~positive, size)
        self.values, self.pos, self.neg = values, pos.astype(np.int64), neg.astype(np.int64)

    def auc(self) -> float:
        """P(s+ > s-) + ½ P(s+ = s-); NaN when a class is empty or a score was NaN."""
        n_pos, n_neg = int(self.pos.sum()), int(self.neg.sum())
        if n_pos == 0 or n_neg == 0 or self.has_nan:
            return float("nan")
        count = self.pos + self.neg
        below = np.cumsum(count) - count
        # average rank of a tie group = below + (count + 1) / 2; twice the positives' rank sum is an integer
        twice = int(np.sum(self.pos * (2 * below + count + 1)))
        return float((np.float64(twice / 2) - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))
