"""The similarity graph N(i), w_ij of the piece-wise planar regulariser (Rossi et al. 2020).

For every pixel i, the candidates j are the other pixels of a ``window`` x ``window`` search window.
Their patch dissimilarity on the grey image (``patch`` x ``patch``, replicate padding) and their
spatial distance give ŵ_ij = exp(-PD_ij / (2 σ_I²) - |x_i - x_j|² / (2 σ_x²)); candidates outside the
image get 0. The ``degree`` largest ŵ are kept and normalised to sum 1 per pixel. The graph is
directed. Empty slots (weight 0) point to i itself, so they contribute nothing to any term.

The kernel runs over blocks of rows (``engine.core.blocks.RowPacer``, about half a second each) with a stop request
(Ctrl-C, ``engine.core.interrupt``) honoured between them: one call per scale took seconds on fountain_p11 at
768×512 on the loaded machine (docs/reliability.md). Every pixel's neighbours and weights depend only on the grey
image, so the graph is the same bit for bit however the rows are split.
"""

from __future__ import annotations

import dataclasses

import numba
import numpy as np

from engine.core.blocks import RowPacer

PACER = RowPacer()  # the row blocks of this process's graph builds (only their time depends on it)


@dataclasses.dataclass(eq=False)
class SimilarityGraph:
    """A directed K-regular graph over the pixels of an H x W image.

    Attributes:
        height, width: image size.
        neighbors: (H*W, K) int32 linear index j = row * W + col of each neighbour of pixel i.
        weights: (H*W, K) float32 w_ij >= 0, each row sums to 1 (or 0 for a pixel without neighbours).
    """

    height: int
    width: int
    neighbors: np.ndarray
    weights: np.ndarray

    _offsets: np.ndarray | None = dataclasses.field(default=None, repr=False)

    @property
    def offsets(self) -> np.ndarray:
        """(H*W, K, 2) int8 x_i - x_j with x = (col, row) in pixels (computed once)."""
        if self._offsets is None:
            self._offsets = np.empty(self.neighbors.shape + (2,), np.int8)
            _edge_offsets(self.neighbors, self.width, self._offsets)
        return self._offsets


@numba.njit(parallel=True, cache=True)
def _edge_offsets(neighbors, width, out):
    n, k_max = neighbors.shape
    for i in numba.prange(n):
        for k in range(k_max):
            j = neighbors[i, k]
            out[i, k, 0] = i % width - j % width
            out[i, k, 1] = i // width - j // width


def window_offsets(window: int) -> np.ndarray:
    """(window² - 1, 2) int (drow, dcol) of the search window, centre excluded, row-major."""
    r = window // 2
    return np.array([(dy, dx) for dy in range(-r, r + 1) for dx in range(-r, r + 1) if (dy, dx) != (0, 0)])


@numba.njit(parallel=True, cache=True)
def _graph_kernel(gray, offsets, patch_radius, inv_2si2, inv_2sx2, row_start, row_stop, neighbors, weights):
    """Neighbours and weights of the pixels of rows [row_start, row_stop) (each pixel independent of the others)."""
    h, w = gray.shape
    n_cand = offsets.shape[0]
    k_max = neighbors.shape[1]
    for p in numba.prange((row_stop - row_start) * w):
        i = row_start * w + p
        r, c = i // w, i % w
        top_w = np.zeros(k_max)
        top_j = np.full(k_max, i, np.int64)
        count = 0
        for n in range(n_cand):
            dy, dx = offsets[n, 0], offsets[n, 1]
            rj, cj = r + dy, c + dx
            if rj < 0 or rj >= h or cj < 0 or cj >= w:
                continue
            pd = 0.0
            for oy in range(-patch_radius, patch_radius + 1):
                ra = min(max(r + oy, 0), h - 1)
                rb = min(max(rj + oy, 0), h - 1)
                for ox in range(-patch_radius, patch_radius + 1):
                    diff = gray[ra, min(max(c + ox, 0), w - 1)] - gray[rb, min(max(cj + ox, 0), w - 1)]
                    pd += diff * diff
            wh = np.exp(-pd * inv_2si2 - (dy * dy + dx * dx) * inv_2sx2)
            if wh <= 0.0:
                continue
            if count == k_max and wh <= top_w[k_max - 1]:
                continue
            # Insert into the descending list (strictly greater moves ahead: earlier candidates win ties).
            pos = min(count, k_max - 1)
            while pos > 0 and top_w[pos - 1] < wh:
                top_w[pos] = top_w[pos - 1]
                top_j[pos] = top_j[pos - 1]
                pos -= 1
            top_w[pos] = wh
            top_j[pos] = rj * w + cj
            if count < k_max:
                count += 1
        total = 0.0
        for k in range(count):
            total += top_w[k]
        total = max(total, 1e-12)
        for k in range(k_max):
            neighbors[i, k] = top_j[k]
            weights[i, k] = top_w[k] / total if k < count else 0.0


def similarity_graph(gray: np.ndarray, window: int = 9, patch: int = 3, sigma_int: float = 0.07,
                     sigma_spa: float = 3.0, degree: int = 20, pacer: RowPacer | None = PACER) -> SimilarityGraph:
    """Build the graph of Rossi et al. 2020 from an (H, W) grey image in [0, 1] (numba kernel).

    ``pacer``: the blocks of rows the kernel runs over, with a stop request honoured between two of them (raised
    there as KeyboardInterrupt, the graph then unfinished); None: one call over the whole image.
    """
    gray = np.ascontiguousarray(gray, np.float64)
    h, w = gray.shape
    offs = window_offsets(window).astype(np.int64)
    k = min(degree, len(offs))
    neighbors = np.empty((h * w, k), np.int32)
    weights = np.empty((h * w, k), np.float32)
    terms = (gray, offs, patch // 2, 1.0 / (2 * sigma_int ** 2), 1.0 / (2 * sigma_spa ** 2))
    if pacer is None:
        _graph_kernel(*terms, 0, h, neighbors, weights)
    else:
        pacer.run("similarity graph", h, w, lambda start, stop: _graph_kernel(*terms, start, stop, neighbors, weights))
    return SimilarityGraph(h, w, neighbors, weights)


