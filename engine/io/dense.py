"""COLMAP dense maps (``.bin``): depth, normal, cost, counter and confidence maps.

Layout (COLMAP ``src/colmap/mvs/mat.cc``, ``scripts/python/read_write_dense.py``): an ASCII header
``"{width}&{height}&{channels}&"`` with no newline, then ``width*height*channels`` little-endian
float32 values, channel-planar and row-major within a plane: element (row, col, ch) is at index
``ch*width*height + row*width + col``. Our files are byte-identical to what COLMAP writes.

Arrays on the Python side are (H, W) for one channel and (H, W, C) for several, float32.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from engine.core.errors import DeepCError
from engine.io.atomic import atomic_write

_MAX_HEADER = 64  # "&"-separated decimal header; far more than any real size needs
_MAX_DIM = 1 << 20


def encode_dense_map(array: np.ndarray) -> bytes:
    """Bytes of ``array`` ((H, W) or (H, W, C)) in COLMAP's dense layout."""
    array = np.asarray(array)
    if array.ndim == 2:
        array = array[:, :, None]
    if array.ndim != 3 or 0 in array.shape:
        raise ValueError(f"dense map must be (H, W) or (H, W, C) and non-empty, got shape {array.shape}")
    height, width, channels = array.shape
    header = f"{width}&{height}&{channels}&".encode("ascii")
    planar = np.ascontiguousarray(np.moveaxis(array, 2, 0), dtype="<f4")
    return header + planar.tobytes()


def write_dense_map(path: str | Path, array: np.ndarray) -> None:
    """Write ``array`` as a COLMAP ``.bin`` map, atomically (no half-written file on failure)."""
    data = encode_dense_map(array)
    with atomic_write(path) as handle:
        handle.write(data)


def _parse_header(head: bytes, path: str | Path) -> tuple[int, int, int, int]:
    """(width, height, channels, data offset) from the first bytes of a COLMAP dense map."""
    parts = head[:_MAX_HEADER].split(b"&", 3)
    if len(parts) < 4:
        raise DeepCError("not a COLMAP dense map: header 'width&height&channels&' not found", path)
    dims = []
    for label, raw in zip(("width", "height", "channels"), parts[:3], strict=True):
        text = raw.strip()
        if not text.isdigit():
            raise DeepCError(f"malformed COLMAP dense-map header: {label} is {raw[:16]!r}", path)
        value = int(text)
        if not 0 < value <= _MAX_DIM:
            raise DeepCError(f"malformed COLMAP dense-map header: {label} = {value}", path)
        dims.append(value)
    return dims[0], dims[1], dims[2], len(parts[0]) + len(parts[1]) + len(parts[2]) + 3


def _check_size(width: int, height: int, nchan: int, available: int, path: str | Path) -> None:
    expected = width * height * nchan * 4
    if available < expected:
        raise DeepCError(
            f"truncated COLMAP dense map: header says {width}x{height}x{nchan} "
            f"({expected} bytes of data), the file has {available}", path)
    if available > expected:
        raise DeepCError(
            f"malformed COLMAP dense map: {available - expected} bytes after the "
            f"{width}x{height}x{nchan} data", path)


def decode_dense_map(data: bytes, path: str | Path = "<bytes>", channels: int | None = None) -> np.ndarray:
    """Parse COLMAP dense-map bytes; raises :class:`DeepCError` naming ``path`` on any defect."""
    width, height, nchan, offset = _parse_header(data, path)
    if channels is not None and nchan != channels:
        raise DeepCError(f"expected a {channels}-channel map, the file has {nchan} channels", path)
    _check_size(width, height, nchan, len(data) - offset, path)
    planar = np.frombuffer(data, dtype="<f4", count=width * height * nchan, offset=offset)
    array = planar.reshape(nchan, height, width).transpose(1, 2, 0).astype(np.float32)
    return array[:, :, 0].copy() if nchan == 1 else np.ascontiguousarray(array)


def read_dense_map(path: str | Path, channels: int | None = None) -> np.ndarray:
    """Read a COLMAP ``.bin`` map: (H, W) float32 for one channel, (H, W, C) otherwise."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise DeepCError("file not found", path) from None
    except IsADirectoryError:
        raise DeepCError("is a folder, expected a COLMAP dense map", path) from None
    except OSError as exc:
        raise DeepCError(f"cannot read: {exc.strerror or exc}", path) from exc
    return decode_dense_map(data, path, channels)


def read_depth_map(path: str | Path, *, allow_nonfinite: bool = False) -> np.ndarray:
    """(H, W) float32 depth, 0 = none. Non-finite values are an error unless allowed (then 0)."""
    depth = read_dense_map(path, channels=1)
    bad = ~np.isfinite(depth)
    if bad.any():
        if not allow_nonfinite:
            raise DeepCError(f"{int(bad.sum())} non-finite depth values (NaN or inf); 0 marks a missing depth", path)
        depth[bad] = 0.0
    if (depth < 0).any():
        depth[depth < 0] = 0.0  # COLMAP treats depth <= 0 as invalid
    return depth


def read_normal_map(path: str | Path) -> np.ndarray:
    """(H, W, 3) float32 camera-frame normals (0 vector = none)."""
    normal = read_dense_map(path, channels=3)
    if not np.isfinite(normal).all():
        raise DeepCError("non-finite normal values (NaN or inf)", path)
    return normal


def read_dense_map_header(path: str | Path) -> tuple[int, int, int]:
    """(width, height, channels) of a COLMAP ``.bin`` map, checking that the file size matches."""
    path = Path(path)
    try:
        with open(path, "rb") as handle:
            head = handle.read(_MAX_HEADER)
            size = os.fstat(handle.fileno()).st_size
    except FileNotFoundError:
        raise DeepCError("file not found", path) from None
    except OSError as exc:
        raise DeepCError(f"cannot read: {exc.strerror or exc}", path) from exc
    width, height, channels, offset = _parse_header(head, path)
    _check_size(width, height, channels, size - offset, path)
    return width, height, channels
