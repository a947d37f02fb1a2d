"""Confidence maps from a trained network (Kuhn et al. 2020, §3.2): tiled, bounded memory, CPU.

Large maps are cut into tiles of at most ``tile``×``tile`` pixels with ``overlap`` pixels of context
on each side; each tile's prediction is kept only in its centre (the overlap is discarded), so the
result matches untiled inference up to the network's receptive-field effects at tile borders. Peak
memory grows with the tile size, not the image size.
"""

from __future__ import annotations

import contextlib

import numpy as np
import torch

from engine.confidence.inputs import NORMAL
from engine.confidence.network import ConfidenceNet, pad_to_multiple
from engine.core.interrupt import check_interrupt


def autocast(bf16: bool, device: str = "cpu"):
    if bf16 and (device == "cuda" or torch.backends.mkldnn.is_available()):
        return torch.autocast(device, dtype=torch.bfloat16)
    return contextlib.nullcontext()


def _forward(model: ConfidenceNet, x: np.ndarray, bf16: bool) -> np.ndarray:
    t = torch.from_numpy(np.ascontiguousarray(x))[None]
    t, (h, w) = pad_to_multiple(t)
    with autocast(bf16):
        logits = model(t.contiguous(memory_format=torch.channels_last))
    return torch.sigmoid(logits.float())[0, 0, :h, :w].numpy()


def _starts(size: int, core: int) -> list[int]:
    return list(range(0, size, core)) if size > 0 else [0]


def facing_away(inputs: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels of a (6, H, W) network input whose normal faces away from the camera (θ > 90°)."""
    return inputs[NORMAL.start] > 0.5


def predict_confidence(model: ConfidenceNet, inputs: np.ndarray, tile: int = 1024, overlap: int = 64,
                       bf16: bool = False, zero_backfacing: bool = False) -> np.ndarray:
    """(6, H, W) network input -> (H, W) float32 confidence in [0, 1]; with ``zero_backfacing``, 0 where
    the normal faces away from the camera (see :class:`ConfidenceOptions`)."""
    out = _predict(model, inputs, tile, overlap, bf16)
    if zero_backfacing:
        out[facing_away(inputs)] = 0.0
    return out


def _predict(model: ConfidenceNet, inputs: np.ndarray, tile: int, overlap: int, bf16: bool) -> np.ndarray:
    model.eval().cpu()  # a model trained on a GPU predicts on the CPU, as the pipeline does
    _, h, w = inputs.shape
    out = np.empty((h, w), np.float32)
    with torch.inference_mode():
        if h <= tile and w <= tile:
            out[:] = _forward(model, inputs, bf16)
            return out
        core = tile - 2 * overlap
        for y0 in _starts(h, core):
            for x0 in _starts(w, core):
                y1, x1 = min(h, y0 + core), min(w, x0 + core)
                ya, xa = max(0, y0 - overlap), max(0, x0 - overlap)
                yb, xb = min(h, y1 + overlap), min(w, x1 + overlap)
                check_interrupt()  # between tiles (engine/core/interrupt.py)
                pred = _forward(model, inputs[:, ya:yb, xa:xb], bf16)
                out[y0:y1, x0:x1] = pred[y0 - ya:y1 - ya, x0 - xa:x1 - xa]
    return out


@contextlib.contextmanager
def torch_threads(n: int):
    """Temporarily use ``n`` torch threads (0 = leave as is)."""
    old = torch.get_num_threads()
    if n > 0:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(old)
