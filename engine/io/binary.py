"""A bounds-checked reader of little-endian binary files: COLMAP's model files (``engine.io.colmap_files``) and
OpenMVS's depth maps (``engine.compare.dmap``).

Every read is checked against the bytes that remain, and every count against what could still follow, so that a
truncated or corrupt file is a one-line :class:`DeepCError` naming it and the field it ends inside, never a read
past the end or an allocation sized by garbage.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from engine.core.errors import DeepCError


class ByteReader:
    """Reads fields of ``data`` from ``pos`` on.

    Args:
        data: the file's bytes.
        path: the file, named in every error.
        label: what the file is, for errors ("COLMAP binary model", "OpenMVS depth map").
        pos: the offset to start at, bytes.
    """

    def __init__(self, data: bytes, path: str | Path, label: str, pos: int = 0):
        self.data, self.path, self.label, self.pos = data, Path(path), label, pos

    @classmethod
    def from_file(cls, path: str | Path, label: str) -> ByteReader:
        """A reader of the whole file at ``path``; an unreadable file is a :class:`DeepCError`."""
        try:
            data = Path(path).read_bytes()
        except OSError as exc:  # missing, a folder, unreadable
            raise DeepCError(f"cannot read: {exc.strerror or exc}", path) from exc
        return cls(data, path, label)

    @property
    def left(self) -> int:
        """Bytes after the current position."""
        return len(self.data) - self.pos

    def error(self, problem: str) -> DeepCError:
        """``corrupt <label>: <problem>``, naming the file."""
        return DeepCError(f"corrupt {self.label}: {problem}", self.path)

    def need(self, size: int, what: str) -> None:
        """Fail unless ``size`` bytes of ``what`` remain."""
        if size < 0 or size > self.left:
            raise DeepCError(f"truncated {self.label}: the file ends inside the {what} ({size} bytes needed at "
                             f"offset {self.pos}, {self.left} left)", self.path)

    def take(self, size: int, what: str) -> bytes:
        """The next ``size`` bytes (``what`` names them in an error)."""
        self.need(size, what)
        chunk = self.data[self.pos:self.pos + size]
        self.pos += size
        return chunk

    def skip(self, size: int, what: str) -> None:
        self.need(size, what)
        self.pos += size

    def unpack(self, fmt: str, what: str) -> tuple:
        """The values of the little-endian :mod:`struct` format ``fmt`` (without byte-order prefix)."""
        size = struct.calcsize("<" + fmt)
        self.need(size, what)
        values = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return values

    def array(self, dtype: str, shape: tuple[int, ...], what: str) -> np.ndarray:
        """A read-only array of ``shape`` and ``dtype`` viewing the next bytes (copy it to keep or change it)."""
        count = int(np.prod(shape))
        size = count * np.dtype(dtype).itemsize
        self.need(size, what)
        values = np.frombuffer(self.data, dtype, count, self.pos).reshape(shape)
        self.pos += size
        return values

    def count(self, fmt: str, item_size: int, what: str) -> int:
        """A count, checked against the bytes left at ``item_size`` bytes (at least) per item."""
        (n,) = self.unpack(fmt, what)
        if n < 0 or n * item_size > self.left:
            raise self.error(f"{what} is {n}, but only {self.left} bytes follow")
        return n

    def floats(self, n: int, what: str) -> np.ndarray:
        """``n`` finite float64 values (a copy)."""
        values = self.array("<f8", (n,), what).copy()
        if not np.isfinite(values).all():
            raise self.error(f"non-finite {what}")
        return values

    def c_string(self, what: str, max_length: int) -> str:
        """A NUL-terminated UTF-8 string of at most ``max_length`` bytes."""
        end = self.data.find(b"\0", self.pos, self.pos + max_length)
        if end < 0:
            raise self.error(f"{what} at offset {self.pos} is not terminated")
        raw = self.data[self.pos:end]
        self.pos = end + 1
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise self.error(f"{what} {raw[:40]!r} is not UTF-8") from None

    def done(self) -> None:
        """Fail unless every byte was read."""
        if self.left:
            raise self.error(f"{self.left} unexpected bytes at the end")
