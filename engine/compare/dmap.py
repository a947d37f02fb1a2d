"""OpenMVS depth-data files (``depthNNNN.dmap``, written by DensifyPointCloud), read-only.

The layout, from OpenMVS's published format (``HeaderDepthDataRaw``, ``ExportDepthDataRaw`` in ``libs/MVS``), all
little-endian:

    header     "DR" (2 bytes), uint8 flags (1 depth, 2 normal, 4 confidence, 8 views), one byte (0, padding),
               uint32 image width, height, uint32 depth-map width, height, float32 depth min, max   (28 bytes)
    name       uint16 length, then the image file name (relative to the .dmap's folder, or absolute)
    views      uint32 count, then the uint32 ids of the reference view and its neighbours
    camera     float64 K[3][3], R[3][3] (row-major), C[3]
    maps       float32 depth[h][w]; float32 normal[h][w][3] (camera frame) if flag 2; float32 confidence[h][w]
               if flag 4; uint8 views[h][w][4] if flag 8

OpenMVS v2.3.0's DensifyPointCloud writes this layout (checked on its files; it writes no views map by default).
The reader also takes a quantized variant: a 32-byte header whose padding byte is a power-of-two depth exponent
and which ends with a float32 confidence scale, then half-float depth (times 2^exponent), two int16 per normal
(octahedral), uint8 confidence (times scale / 255) and the same views map. Which of the two a file holds follows
from its size; the quantized normals are not decoded (``normal`` is None), depth and confidence are.
Depth is camera-frame z in the scene's units, 0 = none.
"""

from __future__ import annotations

import dataclasses
import struct
from pathlib import Path

import numpy as np

from engine.core.errors import DeepCError
from engine.io.binary import ByteReader

MAGIC = b"DR"
HAS_DEPTH, HAS_NORMAL, HAS_CONF, HAS_VIEWS = 1, 2, 4, 8
HEADER = struct.Struct("<2sBB4I2f")  # 28 bytes
HEADER_QUANTIZED = struct.Struct("<2sBb4I3f")  # 40 bytes
CAMERA_BYTES = 8 * (9 + 9 + 3)
_MAX_DIM = 1 << 16


@dataclasses.dataclass
class DepthData:
    """One view's .dmap.

    Attributes:
        image_name: the image file name as stored (relative to the .dmap's folder, or absolute).
        image_size, depth_size: (width, height) of the image and of the maps, pixels.
        depth_range: (min, max) depth of the view, scene units.
        view_ids: OpenMVS ids of the reference view, then its neighbours.
        K, R, C: (3, 3) intrinsics at ``image_size``, (3, 3) world-to-camera rotation, (3,) camera centre.
        depth: (H, W) float32, 0 = none; normal: (H, W, 3) float32 camera-frame or None; confidence: (H, W)
            float32 or None; views: (H, W, 4) uint8 or None.
    """

    image_name: str
    image_size: tuple[int, int]
    depth_size: tuple[int, int]
    depth_range: tuple[float, float]
    view_ids: list[int]
    K: np.ndarray
    R: np.ndarray
    C: np.ndarray
    depth: np.ndarray
    normal: np.ndarray | None = None
    confidence: np.ndarray | None = None
    views: np.ndarray | None = None


def _map_bytes(flags: int, width: int, height: int, quantized: bool) -> int:
    per_pixel = (2 if quantized else 4) + ((4 if quantized else 12) if flags & HAS_NORMAL else 0)
    per_pixel += ((1 if quantized else 4) if flags & HAS_CONF else 0) + (4 if flags & HAS_VIEWS else 0)
    return per_pixel * width * height


def _quantized(data: bytes, path: Path) -> bool:
    """Whether the file is the quantized variant: the size of the float32 layout does not fit, the other does."""
    fits = []
    for quantized, header in ((False, HEADER), (True, HEADER_QUANTIZED)):
        if len(data) < header.size + 2:
            fits.append(False)
            continue
        _, flags, _, _, _, width, height, *_ = header.unpack_from(data)
        name_len = struct.unpack_from("<H", data, header.size)[0]
        ids_at = header.size + 2 + name_len
        if len(data) < ids_at + 4:
            fits.append(False)
            continue
        n_ids = struct.unpack_from("<I", data, ids_at)[0]
        size = ids_at + 4 + 4 * n_ids + CAMERA_BYTES + _map_bytes(flags, width, height, quantized)
        fits.append(size == len(data))
    if fits[0] or not fits[1]:
        return False  # the float32 layout, or neither: the reader names what is wrong
    return True


def decode_dmap(data: bytes, path: str | Path = "<bytes>") -> DepthData:
    """Parse the bytes of a .dmap; any defect is a one-line :class:`DeepCError` naming ``path``."""
    path = Path(path)
    if data[:2] != MAGIC:
        raise DeepCError("not an OpenMVS depth map: no 'DR' header", path)
    if len(data) < HEADER.size:
        raise DeepCError(f"truncated OpenMVS depth map: {len(data)} bytes, shorter than its header", path)
    quantized = _quantized(data, path)
    header = HEADER_QUANTIZED if quantized else HEADER
    _, flags, exponent, image_w, image_h, width, height, d_min, d_max, *rest = header.unpack_from(data)
    if not flags & HAS_DEPTH:
        raise DeepCError("OpenMVS depth map without depth (flags say no depth map)", path)
    for label, value in (("image width", image_w), ("image height", image_h), ("depth width", width),
                         ("depth height", height)):
        if not 0 < value <= _MAX_DIM:
            raise DeepCError(f"malformed OpenMVS depth map header: {label} = {value}", path)
    cur = ByteReader(data, path, "OpenMVS depth map", header.size)
    (name_len,) = cur.unpack("H", "image name length")
    try:
        image_name = cur.take(name_len, "image name").decode("utf-8")
    except UnicodeDecodeError:
        raise DeepCError("malformed OpenMVS depth map: the image name is not UTF-8", path) from None
    (n_ids,) = cur.unpack("I", "view count")
    view_ids = [int(v) for v in cur.array("<u4", (n_ids,), "view ids")]
    K = cur.array("<f8", (3, 3), "camera").copy()
    R = cur.array("<f8", (3, 3), "camera").copy()
    C = cur.array("<f8", (3,), "camera").copy()
    if quantized:
        depth = cur.array("<f2", (height, width), "depth map").astype(np.float32) * np.float32(2.0 ** exponent)
        normal = None
        if flags & HAS_NORMAL:
            cur.take(4 * width * height, "normal map")
        confidence = (cur.array("u1", (height, width), "confidence map").astype(np.float32) * np.float32(rest[0] / 255)
                      if flags & HAS_CONF else None)
    else:
        depth = cur.array("<f4", (height, width), "depth map").astype(np.float32)
        normal = cur.array("<f4", (height, width, 3), "normal map").astype(np.float32) if flags & HAS_NORMAL else None
        confidence = cur.array("<f4", (height, width), "confidence map").astype(np.float32) \
            if flags & HAS_CONF else None
    views = cur.array("u1", (height, width, 4), "views map").copy() if flags & HAS_VIEWS else None
    if cur.pos != len(data):
        raise DeepCError(f"malformed OpenMVS depth map: {len(data) - cur.pos} bytes after the maps", path)
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, np.float32(0)).astype(np.float32)
    return DepthData(image_name, (image_w, image_h), (width, height), (float(d_min), float(d_max)), view_ids, K, R, C,
                     depth, normal, confidence, views)


def read_dmap(path: str | Path) -> DepthData:
    """Read a ``.dmap`` file (:func:`decode_dmap`)."""
    try:
        return decode_dmap(Path(path).read_bytes(), path)
    except OSError as exc:  # missing, a folder, unreadable
        raise DeepCError(f"cannot read: {exc.strerror or exc}", path) from exc
