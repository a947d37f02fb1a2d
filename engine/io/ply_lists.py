"""PLY vertex elements whose records hold list properties, read for their scalar properties.

OpenMVS's dense cloud (``scene_dense.ply``) gives every point ``property list uint8 uint32 view_indices`` and
``property list uint8 float32 view_weights`` after x, y, z, colour and normal: its records vary in length, so no
fixed record type covers them. In a binary file one pass over the list counts (numba) finds where each scalar
property of each record lies; the scalars are then gathered from those places and the lists skipped. In an ASCII
file each line is read token by token.
"""

from __future__ import annotations

from pathlib import Path

import numba
import numpy as np

from engine.core.errors import DeepCError

# a property as engine.io.ply's header parser gives it: (name, numpy kind of the value or list item, numpy kind of
# the list count or None for a scalar)
Property = tuple[str, str, "str | None"]


@numba.njit(cache=True, nogil=True)
def _scalar_offsets(buf: np.ndarray, offset: int, count: int, is_list: np.ndarray, size: np.ndarray,
                    count_size: np.ndarray, big_endian: bool, out: np.ndarray) -> int:
    """Fill ``out`` (count, scalars) with the byte offset of each scalar property of each record; return the
    offset after the last record, or -1 when the buffer ends first.

    ``is_list``, ``size`` (bytes of the value or list item) and ``count_size`` (bytes of a list's count) describe
    the properties in order."""
    pos = offset
    n = buf.shape[0]
    for i in range(count):
        k = 0
        for p in range(is_list.shape[0]):
            if is_list[p]:
                width = count_size[p]
                if pos + width > n:
                    return -1
                items = 0
                for b in range(width):  # at most 4 bytes: no overflow
                    byte = buf[pos + (b if big_endian else width - 1 - b)]
                    items = items * 256 + byte
                if items > n:  # a signed count below 0 reads as a huge one
                    return -1
                pos += width + items * size[p]
            else:
                out[i, k] = pos
                k += 1
                pos += size[p]
            if pos > n:
                return -1
    return pos


def read_binary_with_lists(data: bytes, offset: int, count: int, properties: list[Property], order: str,
                           path: Path) -> dict[str, np.ndarray]:
    """``{name: (count,) array}`` of the scalar properties of ``count`` binary records from ``offset``; ``order``
    is "<" or ">"."""
    bad = [name for name, _, kind in properties if kind is not None and kind[0] not in "iu"]
    if bad:
        raise DeepCError(f"malformed PLY: list property {bad[0]!r} has a count that is not an integer", path)
    buf = np.frombuffer(data, np.uint8)
    is_list = np.array([kind is not None for _, _, kind in properties], np.bool_)
    size = np.array([np.dtype(value).itemsize for _, value, _ in properties], np.int64)
    count_size = np.array([np.dtype(kind).itemsize if kind is not None else 0 for _, _, kind in properties],
                          np.int64)
    scalars = [(name, value) for name, value, kind in properties if kind is None]
    out = np.zeros((count, len(scalars)), np.int64)
    if _scalar_offsets(buf, offset, count, is_list, size, count_size, order == ">", out) < 0:
        raise DeepCError(f"truncated PLY: {count} vertices (records with lists) run past the end of the file", path)
    columns = {}
    for k, (name, value) in enumerate(scalars):
        dtype = np.dtype(order + value)
        raw = buf[out[:, k, None] + np.arange(dtype.itemsize)]  # (count, itemsize) bytes, contiguous
        columns[name] = raw.view(dtype).ravel().astype(dtype.newbyteorder("="))
    return columns


def read_ascii_with_lists(rows: list[str], properties: list[Property], path: Path) -> dict[str, np.ndarray]:
    """``{name: (len(rows),) array}`` of the scalar properties of ASCII vertex lines, lists skipped."""
    scalars = [(name, value) for name, value, kind in properties if kind is None]
    values = np.empty((len(rows), len(scalars)), np.float64)
    for i, row in enumerate(rows):
        tokens = row.split()
        at, k = 0, 0
        try:
            for _, _, kind in properties:
                if kind is None:
                    values[i, k] = float(tokens[at])
                    k += 1
                    at += 1
                else:
                    items = int(tokens[at])
                    if items < 0:
                        raise ValueError(items)
                    at += 1 + items
        except (IndexError, ValueError):
            raise DeepCError(f"malformed PLY: vertex line {i + 1} does not hold every property", path) from None
    return {name: values[:, k].astype(value) for k, (name, value) in enumerate(scalars)}
