"""Reuse of the large per-pass arrays between the view passes of a run.

Every view pass needs the same large arrays (the reference window terms, 113 MB at 768x512, and the cost
caches, 145 MB with 5 sources). Freshly allocated, each 4 KiB page of them faults when first written, inside
the parallel kernels, and on this virtual machine that cost varies a lot from run to run. Reused arrays
make one view's window terms 1.07x and its initial cost plus a half-step 1.06x faster in the committed
measurement (``benchmarks/results/bench_patchmatch_buffers.json``, best of 9); repeat with
``benchmarks/performance/bench_patchmatch_buffers.py``, whose ratios change from run to run with the machine.
"""

from __future__ import annotations

import numpy as np


class BufferPool:
    """Arrays handed back after a pass, taken again by the next one of the same shape and dtype.

    ``take`` has ``np.empty``'s contract (contents undefined). Arrays given back must no longer be
    referenced by anything that reads them later. A take that finds nothing to reuse drops everything the
    pool holds (views of other sizes, a new pyramid level): the pool never holds more than what the last
    pass gave back. ``clear`` drops everything."""

    def __init__(self) -> None:
        self._free: dict[tuple, list[np.ndarray]] = {}

    def take(self, shape: tuple[int, ...] | int, dtype: type | np.dtype = np.float64) -> np.ndarray:
        shape = (shape,) if isinstance(shape, int) else tuple(int(s) for s in shape)
        free = self._free.get((shape, np.dtype(dtype).str))
        if free:
            return free.pop()
        self._free.clear()
        return np.empty(shape, dtype)

    def give(self, *arrays: np.ndarray | None) -> None:
        for a in arrays:
            # only whole arrays that own their memory (a view would keep its base alive and alias it)
            if a is not None and a.base is None and a.flags.c_contiguous:
                self._free.setdefault((a.shape, a.dtype.str), []).append(a)

    def clear(self) -> None:
        self._free.clear()

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for arrays in self._free.values() for a in arrays)
