"""Lossless packing of float32 maps for the files a run keeps for re-running views (pass history, probe states)."""

from __future__ import annotations

import zlib

import numpy as np


def pack_float32(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Any float32 array (depth (H, W), normal (H, W, 3), ...) -> (bytes as uint8, shape): the four bytes of every
    value grouped by significance ("byte shuffle", as HDF5's filter), then zlib level 1: about 0.64 of the raw
    size on PatchMatch depth maps (plain zlib: 0.82), lossless."""
    d = np.ascontiguousarray(values, np.float32)
    shuffled = d.view(np.uint8).reshape(-1, 4).T.tobytes()
    return np.frombuffer(zlib.compress(shuffled, 1), np.uint8), np.array(d.shape, np.int64)


def unpack_float32(packed: np.ndarray, shape: np.ndarray) -> np.ndarray:
    """Inverse of :func:`pack_float32` (raises ``zlib.error`` or ``ValueError`` on damaged bytes)."""
    raw = np.frombuffer(zlib.decompress(packed.tobytes()), np.uint8)
    return np.ascontiguousarray(raw.reshape(4, -1).T).view(np.float32).reshape(tuple(int(s) for s in shape))
