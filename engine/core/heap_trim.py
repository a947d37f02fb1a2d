"""Handing freed heap memory back to the operating system between the stages of a run.

glibc's malloc serves an allocation below its mmap threshold from the heap, and that threshold grows up to
32 MiB as large arrays are freed: after PatchMatch most arrays of a few MiB (a view's maps, fusion's packed
arrays, the evaluation's keys) live on the heap. Freed, they stay resident until the top of the heap is
free, and the next stage's large arrays (mmap'ed) come on top: on fountain_p11 at 768x512 the peak resident
memory of writing the fused cloud was 66 MiB higher than with the freed pages returned
(``benchmarks/results/bench_memory.json``). ``malloc_trim(0)`` returns every free page of the heap; it costs
a few milliseconds, so it runs only at stage boundaries.

A file read through a memory map (the fused cloud's records) stays in the process's resident set page by page as it
is read, although the pages are the page cache's: :func:`release_mapped_pages` drops them after a pass over the file
(on fountain_p11 at 768x512 counting the points per view held 144 MiB of ``fused.ply`` resident).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import mmap
from typing import Any


@functools.cache
def _trim():
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else None
    except OSError:
        return None
    return getattr(libc, "malloc_trim", None)  # glibc only


def release_free_memory() -> bool:
    """Return the heap's free pages to the OS (glibc ``malloc_trim``); False where that is not available."""
    trim = _trim()
    if trim is None:
        return False
    trim(0)
    return True


def release_mapped_pages(array: Any) -> bool:
    """Drop the pages of the file map under ``array`` (a numpy memmap or a view of one) from the resident set
    (``madvise(MADV_DONTNEED)``: they stay in the page cache and are read again if touched); False when ``array``
    is not file-mapped or the platform cannot."""
    base = array
    while base is not None and not isinstance(base, mmap.mmap):
        base = getattr(base, "base", None)
    if base is None or not hasattr(base, "madvise") or not hasattr(mmap, "MADV_DONTNEED"):
        return False
    base.madvise(mmap.MADV_DONTNEED)
    return True
