"""The size rule of a view's candidate row cache (``ViewState.prepare_caches``), apart from the state so that the
memory estimate (``engine/run/memory.py``, ``deepc info``) reads it without the kernels."""

from __future__ import annotations

# the candidate row cache takes K_up · (4 N + 1) + 8 bytes per pixel (129 MB at 768x512 with 5 sources,
# 255 MB with 10); above this it is left out (results are the same either way, only slower)
ROW_CACHE_MAX_BYTES = 2 << 30


def row_cache_bytes(h: int, w: int, k_up: int, n_sources: int) -> int:
    """Bytes of the candidate row cache of an (h, w) view with ``k_up`` candidates and ``n_sources`` sources."""
    return h * w * (k_up * (4 * n_sources + 1) + 4 + 4)
