"""The buffer pool that reuses the large per-pass arrays between view passes (engine/patchmatch/buffers.py)."""

from __future__ import annotations

import numpy as np

from engine.patchmatch.buffers import BufferPool


def test_pool_hands_back_the_same_array_only_for_the_same_shape_and_dtype() -> None:
    pool = BufferPool()
    a, b = pool.take((4, 5), np.float32), pool.take(3, np.int16)
    assert a.shape == (4, 5) and a.dtype == np.float32 and b.shape == (3,) and b.dtype == np.int16
    pool.give(a, b)
    assert pool.nbytes == a.nbytes + b.nbytes
    assert pool.take((4, 5), np.float32) is a
    assert pool.take((3,), np.int16) is b
    assert pool.take((4, 5), np.float32) is not a  # taken: never handed out twice
    assert pool.nbytes == 0


def test_pool_drops_what_it_holds_when_a_take_finds_nothing_to_reuse() -> None:
    """Views of another size (or a new level) take other shapes: the old arrays are freed, not kept."""
    pool = BufferPool()
    a = pool.take((4, 5), np.float32)
    pool.give(a)
    assert pool.take((5, 4), np.float32) is not a
    assert pool.nbytes == 0
    pool.give(a)
    assert pool.take((4, 5), np.float64) is not a and pool.nbytes == 0


def test_pool_refuses_views_and_forgets_on_clear() -> None:
    pool = BufferPool()
    base = np.zeros((6, 6), np.float32)
    pool.give(base[:3], base[:, ::2], None)
    assert pool.nbytes == 0  # a view would alias memory its base still owns
    pool.give(base)
    pool.clear()
    assert pool.nbytes == 0 and pool.take((6, 6), np.float32) is not base
