"""Counter-based random numbers: a pure function of (seed, view, level, pass, iteration, pixel, draw).

No generator state exists, so results do not depend on how ``prange`` splits the work between
threads. The mixer is a 64-bit finaliser (splitmix64 style); ``uniform`` maps its top 24 bits to
[0, 1) exactly representable in float32.
"""

from __future__ import annotations

import numpy as np
from numba import njit

_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_GOLD = np.uint64(0x9E3779B97F4A7C15)
_S30 = np.uint64(30)
_S27 = np.uint64(27)
_S31 = np.uint64(31)
_S40 = np.uint64(40)
_INV24 = 1.0 / 16777216.0


@njit(cache=True, inline="always")
def mix64(x: np.uint64) -> np.uint64:
    """splitmix64 finaliser: a bijective avalanche mix of 64 bits."""
    x = (x ^ (x >> _S30)) * _M1
    x = (x ^ (x >> _S27)) * _M2
    return x ^ (x >> _S31)


@njit(cache=True, inline="always")
def combine(key: np.uint64, value: int) -> np.uint64:
    """Fold one more counter component into a key."""
    return mix64(np.uint64(key) ^ (np.uint64(value) + _GOLD))


@njit(cache=True)
def stream_key(seed: int, view: int, level: int, pass_id: int, iteration: int, colour: int) -> np.uint64:
    """Key of one half-step of one view; combine with the pixel index for a per-pixel stream."""
    k = mix64(np.uint64(seed) + _GOLD)
    k = combine(k, view)
    k = combine(k, level)
    k = combine(k, pass_id)
    k = combine(k, iteration)
    return combine(k, colour)


@njit(cache=True, inline="always")
def uniform(key: np.uint64, draw: int) -> float:
    """Draw number ``draw`` of the stream ``key``: a float in [0, 1)."""
    # explicit casts: numba promotes int64 + uint64 to float64
    return float(mix64(np.uint64(key) + np.uint64(draw) * _GOLD) >> _S40) * _INV24
