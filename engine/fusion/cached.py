"""Fusion through a bounded cache of views, as COLMAP's StereoFusion reads its workspace through a cache that evicts
the least recently used images (Schönberger et al. 2016; COLMAP ``src/colmap/mvs/workspace.h``, ``CachedWorkspace``).

The kernel is :func:`engine.fusion.kernel.fuse_kernel`, the one the in-memory :func:`engine.fusion.fuse` runs: the
maps of at most ``cache_views`` views sit in slots; when the traversal pops a pixel of a view that is not resident,
the kernel stores its state and returns; this module loads that view (``load(i)``, e.g. from a run folder) into a
slot, evicting the least recently used view other than the seed view, and calls the kernel again. The cloud is the
one :func:`engine.fusion.fuse` makes of the same views, byte for byte (same traversal, same points).

The cache's size: a seed's traversal goes through the views that see its point, about the seed view's overlap
list; a cache smaller than that list reloads views over and over (thrashes; correct but slow). The default is 1 +
the longest overlap list (at most ``check_num_images`` + 1 = 51 views): bounded whatever the number of views.

Memory: ``cache_views`` x (largest view's pixels) x 23 bytes (depth 4, normal 12, colour 3, confidence 4) for the
slots; what stays for every view is small: its camera, its overlap list, and, for a view evicted before it was
fused, which of its pixels are consumed (1 bit a pixel, as COLMAP's ``fused_pixel_masks_`` keep 1 byte).
The cloud is written into chunks of ``CHUNK_POINTS`` points. Without a ``sink`` they are joined at the end one
attribute at a time (peak about 1.4 x the cloud, as COLMAP holds its fused points). With one, each chunk is handed to
it as it fills and its arrays are filled again: :mod:`engine.fusion.stream` writes it into ``fused.ply`` (records,
and the float64 positions into a temporary file) and returns the cloud as memory maps of the files, so that the
memory of fusion is the cache's and one chunk's whatever the number of views and points (every ``deepc run``:
``engine.run.distributed.streamed`` with an executor, ``engine.fusion.stream.fuse_views_to_ply`` in process).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from engine.core.camera import Camera
from engine.core.interrupt import check_interrupt
from engine.fusion.cloud import FusedCloud, FusionView
from engine.fusion.kernel import (
    FUSED,
    IMG,
    N_OUT,
    NEED_ROOM,
    SP,
    ST_IMG,
    cloud_of,
    fuse_kernel,
    kernel_options,
    output_arrays,
    sanitize_depth,
    work_arrays,
)
from engine.fusion.options import FusionOptions
from engine.fusion.packing import check_view, fill_rgb, pack_geometry

# points a chunk of the output holds (3.5 MiB); joined at the end, or handed to a sink. The kernel returns when a chunk
# is full, and a stop request is honoured there: 1 << 18 points took up to 7 s a call at 768 px on the loaded 2-core
# machine (benchmarks/reliability/bench_stop_latency.py), past the 2 s a Ctrl-C may take
CHUNK_POINTS = 1 << 16


@dataclasses.dataclass
class CacheStats:
    """What a cached fusion did: views loaded (a view evicted and needed again counts again), evictions, the most
    views resident at once (never more than the cache), and calls of the kernel."""

    loads: int = 0
    evictions: int = 0
    peak_resident: int = 0
    calls: int = 0


class _Slots:
    """The resident views' maps, ``size`` slots of ``slot_px`` pixels each, in the arrays the kernel reads."""

    def __init__(self, n_views: int, size: int, slot_px: int, confidence: bool):
        self.dep = np.zeros(size * slot_px, np.float32)
        self.nrm = np.zeros((size * slot_px, 3), np.float32)
        self.rgb = np.zeros((size * slot_px, 3), np.uint8)
        self.conf = np.full(size * slot_px if confidence else 1, np.nan, np.float32)
        self.base = np.full(n_views, -1, np.int64)  # view -> first pixel of its slot, -1: not resident
        self.used = np.zeros(n_views, np.int64)  # view -> when the traversal last popped one of its pixels
        self.view = [-1] * size  # slot -> view
        self.slot_px = slot_px
        self.consumed: dict[int, np.ndarray] = {}  # evicted, not yet fused view -> its consumed pixels, packed bits

    def maps(self) -> tuple:
        return self.dep, self.nrm, self.rgb, self.conf, self.base, self.used

    def evict(self, s: int, fused: np.ndarray, n_px: int) -> None:
        v = self.view[s]
        a = s * self.slot_px
        if not fused[v]:  # a fused view is never visited again
            consumed = self.dep[a:a + n_px] < 0
            if consumed.any():
                self.consumed[v] = np.packbits(consumed)
        self.base[v] = -1
        self.view[s] = -1

    def load(self, s: int, i: int, view: FusionView, n_px: int) -> None:
        a = s * self.slot_px
        depth = self.dep[a:a + n_px]
        depth[:] = np.asarray(view.depth, np.float32).ravel()
        sanitize_depth(depth)
        bits = self.consumed.pop(i, None)
        if bits is not None:  # consumed before the view was evicted: negative again (the kernel's mark)
            consumed = np.unpackbits(bits, count=n_px).view(bool)
            depth[consumed] = -depth[consumed]
        self.nrm[a:a + n_px] = np.asarray(view.normal, np.float32).reshape(-1, 3)
        fill_rgb(view.rgb, self.rgb[a:a + n_px])
        if self.conf.shape[0] > 1:
            self.conf[a:a + n_px] = np.nan if view.confidence is None else np.asarray(view.confidence,
                                                                                       np.float32).ravel()
        self.base[i] = a
        self.view[s] = i


def _victim(slots: _Slots, seed: int, stack: np.ndarray) -> int:
    """The slot to free: not the seed view's; of the others, the view the traversal needs last (Belady's choice
    over what is known: the stack is popped from its top, so a view deeper in it, or absent, is needed later; the
    pure LRU order of COLMAP's cache thrashes on the traversal's round trips through the overlapping views), the
    least recently used one among equals."""
    best, key = -1, None
    for s, v in enumerate(slots.view):
        if v == seed:
            continue
        on_stack = np.flatnonzero(stack == v)
        k = (-(len(stack) - on_stack[-1]) if on_stack.size else -(len(stack) + 1), slots.used[v])
        if key is None or k < key:
            best, key = s, k
    return best


def fuse_cached(cameras: list[Camera], overlaps: list[list[int]], load: Callable[[int], FusionView],
                options: FusionOptions | None = None, cache_views: int | None = None,
                confidence: bool = False, stats: CacheStats | None = None,
                sink: Callable[[tuple, int], None] | None = None) -> FusedCloud | None:
    """Fuse views whose maps are loaded on demand (Schönberger et al. 2016), holding at most ``cache_views``.

    Args:
        cameras: every view's camera at its depth map's resolution.
        overlaps: every view's overlap list (indices into ``cameras``), best first.
        load: view index -> its maps as a :class:`FusionView` (depth, normal, rgb, confidence at the camera's
            resolution; its camera and overlap are not read). Called again for a view evicted before it was fused.
        options: thresholds; default ``FusionOptions()``.
        cache_views: views resident at once, at least 2 (the seed view and the one the traversal is in); None: 1 +
            the longest overlap list (see the module docstring).
        confidence: whether ``load`` gives confidence maps (the points' ``mean_confidence``; NaN otherwise), as
            :func:`engine.fusion.fuse` reads them when any view has one.
        stats: filled with what the cache did.
        sink: called with each filled chunk of the output, ``(the kernel's output arrays, points in them)``, in the
            cloud's order, instead of joining them (:mod:`engine.fusion.stream` writes them into ``fused.ply``);
            the arrays are filled again once it returns.
    Returns:
        The cloud :func:`engine.fusion.fuse` makes of the same views; None with a ``sink``.
    """
    options = (options or FusionOptions()).validate()
    if cache_views is not None and cache_views < 2:
        raise ValueError(f"cache_views must be at least 2, got {cache_views}")
    if len(overlaps) != len(cameras):
        raise ValueError(f"{len(cameras)} cameras but {len(overlaps)} overlap lists")
    n = len(cameras)
    if not n:
        return None if sink is not None else FusedCloud.empty()
    stats = stats if stats is not None else CacheStats()
    geometry = pack_geometry(cameras, overlaps, options)
    if cache_views is None:
        cache_views = max(2, 1 + int(np.max(np.diff(geometry[6]))))
    n_px = geometry[0] * geometry[1]
    slots = _Slots(n, min(cache_views, n), int(n_px.max()), confidence)
    work = work_arrays(n, geometry[6], int(options.max_num_pixels))
    fused = work[FUSED]
    room = max(CHUNK_POINTS, int(options.max_num_pixels))  # a cluster of max_num_pixels points fits one chunk
    chunks, out = [], output_arrays(room)
    thresholds = kernel_options(options)
    while True:
        stats.calls += 1
        need = fuse_kernel(slots.maps(), geometry, work, out, *thresholds, confidence)
        if need in (-1, NEED_ROOM):  # done, or the chunk is full
            if sink is not None:
                sink(out, int(work[0][N_OUT]))
            else:
                chunks.append((out, int(work[0][N_OUT])))
            if need == -1:
                return None if sink is not None else cloud_of(chunks)
            if sink is None:
                out = output_arrays(room)
            work[0][N_OUT] = 0
            check_interrupt()  # between two calls (engine/core/interrupt.py): the chunks so far are whole
            continue
        if -1 in slots.view:
            s = slots.view.index(-1)
        else:
            s = _victim(slots, int(work[0][IMG]), work[ST_IMG][:int(work[0][SP])])
            slots.evict(s, fused, int(n_px[slots.view[s]]))
            stats.evictions += 1
        view = load(need)
        check_view(need, dataclasses.replace(view, camera=cameras[need], overlap=[]), n)
        slots.load(s, need, view, int(n_px[need]))
        stats.loads += 1
        stats.peak_resident = max(stats.peak_resident, sum(v >= 0 for v in slots.view))
