"""Long row kernels as blocks of rows of a fraction of a second each, with a stop request honoured between them.

A numba call cannot be interrupted: a signal's request (``engine.core.interrupt``) waits until it returns, and one
half-step of PatchMatch over a whole 1251×703 view took minutes on a loaded machine. :class:`RowPacer` runs such a
kernel over row blocks sized from the time per pixel it measured (about ``BLOCK_SECONDS`` each) and calls
``check_interrupt`` between them. Only the time of a call depends on the blocks: the kernels that take a block must
give every pixel the same result however the rows are split (``engine.patchmatch.kernels``,
``engine.refinement.graph``).
"""

from __future__ import annotations

import time
from collections.abc import Callable

from engine.core.interrupt import check_interrupt

BLOCK_SECONDS = 0.5  # a block's target time: a stop request waits at most about this (plus the estimate's error)
MIN_ROWS = 2  # the smallest block (a row of a large view took 0.25 s on the loaded 2-core machine)
FIRST_SHARE = 0.25  # a call's first block aims at this share of BLOCK_SECONDS (the rate may come from cheaper calls)
GROWTH = 4  # a block has at most this many times the rows of the block before it in the same call


class RowPacer:
    """Splits a kernel's rows into blocks of about ``target_s`` seconds, from the seconds per pixel that earlier
    blocks of the same ``kind`` of kernel took (kept across calls: the first call starts at ``MIN_ROWS`` rows)."""

    def __init__(self, target_s: float = BLOCK_SECONDS):
        self.target_s = target_s
        self.seconds_per_pixel: dict[str, float] = {}

    def next_rows(self, kind: str, width: int, previous: int) -> int:
        """Rows of the next block of a ``kind`` kernel over rows of ``width`` pixels; ``previous``: the rows of this
        call's block before it (0 for a call's first block)."""
        rate = self.seconds_per_pixel.get(kind)
        if rate is None:
            return MIN_ROWS
        target = self.target_s * (FIRST_SHARE if previous == 0 else 1.0)
        rows = int(target / max(rate * max(width, 1), 1e-12))
        if previous:
            rows = min(rows, GROWTH * previous)
        return max(MIN_ROWS, rows)

    def run(self, kind: str, height: int, width: int, call: Callable[[int, int], object]) -> None:
        """``call(start, stop)`` over rows [0, height) in blocks, with ``check_interrupt`` between two blocks."""
        start = rows = 0
        while start < height:
            rows = self.next_rows(kind, width, rows)
            stop = height if height - start < rows + MIN_ROWS else start + rows  # no sliver of a last block
            t0 = time.perf_counter()
            call(start, stop)
            self.seconds_per_pixel[kind] = (time.perf_counter() - t0) / ((stop - start) * max(width, 1))
            rows, start = stop - start, stop
            if start < height:
                check_interrupt()  # between blocks: the rows done so far are whole (engine/core/interrupt.py)
