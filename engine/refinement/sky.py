"""Sky filtering of refined depth maps (Kuhn et al. 2020, §5.5).

The paper removes sky with PCF-MVS's method (Kuhn et al., GCPR 2019), which is not published as code; this is
our substitute.

Refinement fills every pixel, so textureless sky receives plausible-looking depths that the
geometric checks of fusion do not remove. Without a semantic-segmentation model (no weights can be
downloaded here) the sky is found by a heuristic:

    a pixel is sky iff it was unreliable in the *vanilla* PatchMatch output (no depth, or confidence
    below ``unreliable_below``), has low texture (grey std in a ``texture_window`` box below ``max_texture_std``),
    is bright (grey > ``min_brightness``) or blue-dominant (B > R and B > G), and its 4-connected
    component of such pixels touches the top image border;

and refined depths at or beyond ``far_factor`` · z_99 (z_99 = 99th percentile of the
view's sparse-point depths) are dropped: the refinement clamps to the far end of the depth range,
which with the default range (1.25 · 1.2 · z_99) is exactly 1.5 · z_99.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import ndimage

from engine.core.options import Options, option


@dataclasses.dataclass
class SkyOptions(Options):
    """Heuristic sky mask and far-plane cut (module doc); whether ``full`` applies it is
    ``RefinementOptions.sky_filter``."""

    unreliable_below: float = option(0.05, "a pixel whose vanilla confidence is below this counts as unreliable",
                                     source="ours", low=0, high=1, aliases=("conf_tau",), metavar="C")
    texture_window: int = option(7, "box side of the grey-level standard deviation (odd)", unit="px", source="ours",
                                 odd=True, low=3, metavar="PX")
    max_texture_std: float = option(0.02, "largest grey std of a sky pixel", unit="grey on [0, 1]", source="ours",
                                    low=0, metavar="STD")
    min_brightness: float = option(0.5, "grey level above which a low-texture pixel may be sky",
                                   unit="grey on [0, 1]", source="ours", low=0, high=1, metavar="G")
    far_factor: float = option(1.5, "drop refined depths at or beyond this multiple of z_99", source="ours", above=0,
                               metavar="F")


def local_std(gray: np.ndarray, window: int) -> np.ndarray:
    """(H, W) standard deviation of the grey level in a window x window box (replicate border)."""
    g = np.asarray(gray, np.float64)
    mean = ndimage.uniform_filter(g, window, mode="nearest")
    mean_sq = ndimage.uniform_filter(g * g, window, mode="nearest")
    return np.sqrt(np.maximum(mean_sq - mean * mean, 0.0))


def sky_mask(rgb: np.ndarray, vanilla_depth: np.ndarray, vanilla_confidence: np.ndarray | None = None,
             options: SkyOptions | None = None) -> np.ndarray:
    """(H, W) bool: pixels the heuristic (module doc) calls sky.

    Args:
        rgb: (H, W, 3) float image in [0, 1].
        vanilla_depth: (H, W) vanilla PatchMatch depth, 0 = none.
        vanilla_confidence: (H, W) confidence of the vanilla maps in [0, 1]; None = only pixels
            without depth count as unreliable.
    """
    options = (options or SkyOptions()).validate()
    rgb = np.asarray(rgb, np.float64)
    depth = np.asarray(vanilla_depth)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.shape[:2] != depth.shape:
        raise ValueError(f"rgb {rgb.shape} and depth {depth.shape} must be (H, W, 3) and (H, W)")
    unreliable = ~(np.isfinite(depth) & (depth > 0))
    if vanilla_confidence is not None:
        conf = np.asarray(vanilla_confidence, np.float64)
        if conf.shape != depth.shape:
            raise ValueError(f"confidence {conf.shape} and depth {depth.shape} differ in shape")
        unreliable |= ~(conf >= options.unreliable_below)
    gray = rgb @ np.array([0.299, 0.587, 0.114])
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    looks_like_sky = (gray > options.min_brightness) | ((b > r) & (b > g))
    candidate = unreliable & looks_like_sky & (local_std(gray, options.texture_window) < options.max_texture_std)
    labels, _ = ndimage.label(candidate)  # default structure = 4-connectivity
    touching = np.unique(labels[0][labels[0] > 0])
    return np.isin(labels, touching) & candidate


def far_mask(depth: np.ndarray, z99: float, far_factor: float = 1.5) -> np.ndarray:
    """(H, W) bool: depths at or beyond far_factor · z99 (a relative 1e-4 margin catches depths clamped
    to the far plane)."""
    return np.asarray(depth) >= far_factor * z99 * (1.0 - 1e-4)


def filter_sky(depth: np.ndarray, normal: np.ndarray, sky: np.ndarray, far: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """New (depth, normal) with the pixels of ``sky | far`` set to 0."""
    drop = np.asarray(sky, bool) | np.asarray(far, bool)
    return (np.where(drop, 0.0, depth).astype(np.float32),
            np.where(drop[..., None], 0.0, normal).astype(np.float32))
