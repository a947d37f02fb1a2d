"""A fused cloud streamed to ``fused.ply`` as fusion makes it, so that no whole cloud is ever held in memory.

The kernel's output chunks (:mod:`engine.fusion.cached`) are turned into the PLY's records and written as they fill:
the file is the one :func:`engine.fusion.write_fused_ply` writes of the same cloud, byte for byte, written under a
temporary name and renamed once complete (:func:`engine.io.atomic.atomic_write`). The header holds the vertex count,
known only at the end, so the body starts after room for the header of an upper bound of the count (every point
consumes at least one pixel: the views' pixels); when the count has fewer digits, the body is moved down by those
bytes before the header is written (a copy through a bounded buffer, rare: the bound and the count usually have
as many digits).

The positions also go, as the kernel computed them (float64; the PLY holds float32), into a temporary file without
a name in the same folder (deleted by the system when closed, even after a crash). The result is a
:class:`engine.fusion.cloud.DiskCloud` mapping both files: equal to the in-memory cloud, so that evaluation
(:func:`engine.evaluation.evaluate_point_chunks`) scores exactly the positions an in-process run scores.
Memory: one chunk's records (43 bytes a point) besides the kernel's chunk.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO

import numpy as np
from numpy.lib.stride_tricks import as_strided

from engine.fusion.cached import fuse_cached
from engine.fusion.cloud import DiskCloud, FusedCloud, FusionView
from engine.fusion.options import FusionOptions
from engine.fusion.ply import FUSED_FIELDS, FUSED_RECORD, fill_records
from engine.io.atomic import atomic_write
from engine.io.ply import ply_header

Sink = Callable[[tuple, int], None]  # (the kernel's output arrays, points in them) -> None
MOVE_BLOCK = 1 << 24  # bytes moved at once when the body must move down


class _PlySink:
    """Writes each chunk of the kernel's output: its records into the PLY's body, its positions into ``xyz_file``."""

    def __init__(self, handle: IO[bytes], xyz_file: IO[bytes], body_start: int):
        self.handle, self.xyz_file, self.body_start = handle, xyz_file, body_start
        self.count = 0
        self.table = np.empty(0, FUSED_RECORD)
        handle.seek(body_start)

    def __call__(self, out: tuple, n: int) -> None:
        if n == 0:
            return
        if len(self.table) < n:
            self.table = np.empty(len(out[0]), FUSED_RECORD)  # the kernel's chunk size: made once
        xyz, nrm, rgb, nv, npx, conf, src = (a[:n] for a in out)
        self.handle.write(memoryview(fill_records(self.table, xyz, nrm, rgb, nv, conf, src, npx).view(np.uint8)))
        self.xyz_file.write(memoryview(np.ascontiguousarray(xyz, np.float64)).cast("B"))
        self.count += n

    def finish(self) -> int:
        """Write the header (moving the body next to it when it is shorter than the room left); its length."""
        header = ply_header(self.count, FUSED_FIELDS)
        self.handle.flush()
        self.xyz_file.flush()
        fd = self.handle.fileno()
        body = self.count * FUSED_RECORD.itemsize
        if len(header) != self.body_start:
            _move(fd, self.body_start, len(header), body)
            os.ftruncate(fd, len(header) + body)
        os.pwrite(fd, header, 0)
        return len(header)


def _move(fd: int, src: int, dst: int, length: int) -> None:
    """Move ``length`` bytes of a file from offset ``src`` to ``dst`` (the ranges may overlap), a block at a time."""
    starts = range(0, length, MOVE_BLOCK)
    for start in (starts if dst < src else reversed(starts)):
        size = min(MOVE_BLOCK, length - start)
        data = os.pread(fd, size, src + start)
        if len(data) != size:
            raise OSError(f"short read moving the PLY body ({len(data)} of {size} bytes)")
        os.pwrite(fd, data, dst + start)


def write_fused_stream(path: str | Path, produce: Callable[[Sink], object], max_points: int) -> FusedCloud:
    """Write ``fused.ply`` from the chunks ``produce(sink)`` passes to ``sink`` (in the cloud's order), atomically,
    and return the cloud as a :class:`DiskCloud` of the written file.

    Args:
        path: the PLY to write (its folder also gets the positions' temporary file).
        produce: called once with the sink, e.g. ``lambda sink: fuse_cached(..., sink=sink)``.
        max_points: an upper bound of the points (the header's room; a wrong bound costs a move, not the file).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    xyz_file = tempfile.TemporaryFile(dir=path.parent)  # noqa: SIM115 -- the cloud keeps it open
    try:
        with atomic_write(path, "w+b") as handle:
            sink = _PlySink(handle, xyz_file, len(ply_header(max(int(max_points), 0), FUSED_FIELDS)))
            produce(sink)
            header_len = sink.finish()
        return disk_cloud(path, header_len, sink.count, xyz_file)
    except BaseException:
        xyz_file.close()
        raise


def fuse_views_to_ply(path: str | Path, views: list[FusionView], options: FusionOptions | None = None) -> FusedCloud:
    """:func:`engine.fusion.fuse` of views held in memory, written into the PLY ``path`` as fusion makes the points
    (``write_fused_ply``'s bytes) and returned as the :class:`DiskCloud` of that file: the same cloud, without
    the whole cloud in memory besides the views (every view resident: the cached kernel never evicts one)."""
    views = list(views)
    cameras = [v.camera for v in views]
    confidence = any(v.confidence is not None for v in views)
    return write_fused_stream(path, lambda sink: fuse_cached(
        cameras, [list(v.overlap) for v in views], views.__getitem__, options, cache_views=max(2, len(views)),
        confidence=confidence, sink=sink), max_points=sum(c.width * c.height for c in cameras))


def disk_cloud(path: Path, header_len: int, n: int, xyz_file: IO[bytes]) -> FusedCloud:
    """The :class:`DiskCloud` of ``n`` records of a fused PLY from ``header_len`` on and their float64 positions in
    ``xyz_file`` (kept open by the cloud)."""
    if n == 0:
        empty = FusedCloud.empty()
        cloud = DiskCloud(*(getattr(empty, f) for f in ("xyz", "normal", "rgb", "num_views", "mean_confidence",
                                                         "source_view", "num_pixels")))
    else:
        records = np.memmap(path, FUSED_RECORD, mode="r", offset=header_len, shape=(n,))
        step = FUSED_RECORD.itemsize

        def triple(first: str) -> np.ndarray:  # three consecutive fields as an (n, 3) view
            return as_strided(records[first], (n, 3), (step, records[first].dtype.itemsize), writeable=False)

        cloud = DiskCloud(np.memmap(xyz_file, np.float64, mode="r", shape=(n, 3)), triple("nx"), triple("red"),
                          records["num_views"], records["confidence"], records["source_view"], records["num_pixels"])
    cloud.xyz_file, cloud.path = xyz_file, path
    return cloud
