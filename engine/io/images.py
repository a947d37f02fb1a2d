"""Image reading and area-averaged resizing.

Images are float32 in [0, 1], (H, W, 3) RGB, C-contiguous. Grey images are (H, W) float32.
``read_image`` = ``image_to_float(decode_image(path))``: a cache may keep the decoded 8-bit pixels (a quarter of the
bytes) and convert them when asked, to the same floats.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from engine.core.errors import DeepCError

Image.MAX_IMAGE_PIXELS = None  # large aerial/ETH3D photographs are legitimate input

_LUMA = np.array([0.299, 0.587, 0.114], np.float32)  # ITU-R BT.601, as OpenCV's RGB2GRAY


def image_size(path: str | Path) -> tuple[int, int]:
    """(width, height) from the file header; raises :class:`DeepCError` if it is not an image."""
    path = Path(path)
    if not path.is_file():
        raise DeepCError("image listed in the model is missing", path)
    try:
        with Image.open(path) as image:
            return image.size
    except (UnidentifiedImageError, OSError, ValueError) as exc:
        raise DeepCError(f"unreadable image ({type(exc).__name__}: {exc})", path) from exc


def read_image(path: str | Path) -> np.ndarray:
    """(H, W, 3) float32 RGB in [0, 1]. Grey and RGBA images are converted to RGB."""
    return image_to_float(decode_image(path))


def decode_image(path: str | Path) -> np.ndarray:
    """The file's pixels as stored, before :func:`image_to_float`: (H, W, 3) uint8 RGB (grey and RGBA converted),
    or (H, W) uint16 / int32 for 16-bit and 32-bit grey images (a quarter of the float image's bytes for 8-bit
    files: what a cache holds)."""
    path = Path(path)
    if not path.is_file():
        raise DeepCError("image listed in the model is missing", path)
    try:
        with Image.open(path) as image:
            image.load()
            if image.mode in ("I;16", "I;16B", "I"):
                return np.asarray(image)
            return np.asarray(image.convert("RGB"))
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError) as exc:
        raise DeepCError(f"unreadable image ({type(exc).__name__}: {exc})", path) from exc


def image_to_float(pixels: np.ndarray) -> np.ndarray:
    """:func:`decode_image`'s pixels -> (H, W, 3) float32 RGB in [0, 1] (8-bit / 255, 16-bit grey / 65535)."""
    if pixels.ndim == 2:
        array = np.asarray(pixels, dtype=np.float32) / 65535.0
        array = np.repeat(array[:, :, None], 3, axis=2)
    else:
        array = np.asarray(pixels, dtype=np.float32) / 255.0
    return np.ascontiguousarray(np.clip(array, 0.0, 1.0))


def resize_area(array: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Area-averaged resize of (H, W) or (H, W, C) float32 to ``size`` = (width, height).

    Each output pixel is the mean over the input area it covers (Pillow's BOX filter on float
    planes), the pixel-area-aligned resampling that ``Camera.rescaled`` assumes.
    """
    width, height = size
    if array.shape[1] == width and array.shape[0] == height:
        return np.ascontiguousarray(array, dtype=np.float32)
    planes = array[:, :, None] if array.ndim == 2 else array
    out = np.empty((height, width, planes.shape[2]), np.float32)
    for c in range(planes.shape[2]):
        plane = Image.fromarray(np.ascontiguousarray(planes[:, :, c], dtype=np.float32), mode="F")
        out[:, :, c] = np.asarray(plane.resize((width, height), Image.BOX), dtype=np.float32)
    return out[:, :, 0] if array.ndim == 2 else out


def to_gray(rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) RGB -> (H, W) float32 luma."""
    return np.ascontiguousarray(rgb @ _LUMA, dtype=np.float32)


def to_uint8(rgb: np.ndarray) -> np.ndarray:
    """[0, 1] float image -> uint8."""
    return (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
