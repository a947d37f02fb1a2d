"""Maps as pictures: the colour scales that the rerun stream, the viewer and the regression report share.

Every function returns uint8 RGB (or subsamples without blending), so a map looks the same in a recording,
in the viewer's side panel and in a report thumbnail.
"""

from __future__ import annotations

import numpy as np

from engine.run.fused_maps import RunViewMaps
from engine.scene import Scene


def colorize(values: np.ndarray, vmin: float, vmax: float, cmap: str = "viridis",
             invalid: np.ndarray | None = None) -> np.ndarray:
    """(H, W) scalars -> (H, W, 3) uint8 through a matplotlib colormap; ``invalid`` pixels black."""
    from matplotlib import colormaps  # lazy: matplotlib

    scaled = np.clip((np.nan_to_num(values, nan=vmin) - vmin) / max(vmax - vmin, 1e-12), 0.0, 1.0)
    lut = (colormaps[cmap](np.linspace(0.0, 1.0, 256))[:, :3] * 255).astype(np.uint8)
    rgb = lut[(scaled * 255).astype(np.uint8)]
    if invalid is not None:
        rgb[invalid] = 0
    return rgb


def normal_to_rgb(normal: np.ndarray) -> np.ndarray:
    """(H, W, 3) unit normals -> uint8 RGB (n + 1) / 2; missing normals black."""
    rgb = ((np.clip(normal, -1.0, 1.0) + 1.0) * 127.5).astype(np.uint8)
    rgb[~normal.any(axis=2)] = 0
    return rgb


def subsample(array: np.ndarray, max_size: int) -> np.ndarray:
    """Nearest-neighbour subsampling by an integer step so the longer side is at most ``max_size``
    (0 = unchanged); keeps depth values real, never blended."""
    if max_size <= 0:
        return array
    step = int(np.ceil(max(array.shape[:2]) / max_size))
    return np.ascontiguousarray(array[::step, ::step]) if step > 1 else array


def view_images(scene: Scene, i: int, data: RunViewMaps | None) -> dict[str, np.ndarray]:
    """uint8 RGB images of view ``i``: its image and, from ``data``, its depth, normal, counter and
    confidence maps (those the run wrote)."""
    images = {"image": (np.asarray(scene.image(i)) * 255 + 0.5).astype(np.uint8)}
    if data is None:
        return images
    lo, hi = scene.views[i].depth_range
    images["depth"] = colorize(data.depth, lo, hi, "turbo", data.depth <= 0)
    images["normal"] = normal_to_rgb(data.normal)
    if data.counter is not None:
        images["counter"] = colorize(data.counter, 0, 5, "coolwarm", data.depth <= 0)
    if data.confidence is not None:
        images["confidence"] = colorize(data.confidence, 0.0, 1.0, "viridis", data.depth <= 0)
    return images


def colormap_lut(cmap: str, n: int) -> np.ndarray:
    """(n, 3) uint8 colours sampled evenly along a matplotlib colormap (for class-coded maps and legends)."""
    from matplotlib import colormaps  # lazy: matplotlib

    return (colormaps[cmap](np.linspace(0.0, 1.0, max(n, 2)))[:n, :3] * 255).astype(np.uint8)
