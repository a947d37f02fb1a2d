"""Network inputs per reference view (Kuhn et al. 2020, §3.2): RGB, normals in polar coordinates, counter map.

Channel order of the 6-channel input: 0-2 RGB in [0, 1]; 3 θ/π with θ ∈ [0, π] the angle between the
normal and the direction facing the camera; 4 (φ + π)/(2π) with φ = atan2(n_y, n_x);
5 min(K, N)/N with N the number of source views of the reference. Invalid pixels (zero normal) encode as
(0, 0). The depth itself is not an input.

θ scaling: Kuhn et al. 2020, §3.2 recommends θ/(π/2) clipped to [0, 1], which maps every back-facing normal
(θ > 90°) to the same value as a grazing one. On fountain_p11, 63 % of the outliers of our PatchMatch
face away from the camera (in the synthetic training scenes 2-10 %, and almost no inliers do), so we
keep the whole range: θ/π.

Counter normalisation: Kuhn et al. 2020, §3.2 recommends min(K, 10)/10. We divide by the number of source views
instead, so that the channel means "fraction of consistent source views" whatever N a run used: with
min(K, 10)/10, a network trained on runs with 4 source views never sees values above 0.4, yet runs with
5 (fountain_p11 validation) or 10 views (the CLI default) are mostly above it, and the confidence of such
runs came out erratic (fountain ROC-AUC 46-87 between epochs in a first training).
"""

from __future__ import annotations

import numpy as np

RGB, NORMAL, COUNTER = slice(0, 3), slice(3, 5), slice(5, 6)
NUM_CHANNELS = 6


def encode_normals(normal: np.ndarray) -> np.ndarray:
    """(H, W, 3) camera-frame normals -> (H, W, 2) float32 polar encoding; zero normals -> (0, 0)."""
    n = np.asarray(normal, np.float32)
    valid = np.any(n != 0, axis=-1)
    theta = np.arccos(np.clip(-n[..., 2], -1.0, 1.0)) / np.pi
    phi = (np.arctan2(n[..., 1], n[..., 0]) + np.pi) / (2 * np.pi)
    out = np.stack([theta, phi], axis=-1).astype(np.float32)
    out[~valid] = 0.0
    return out


def network_inputs(rgb: np.ndarray, normal: np.ndarray, counter: np.ndarray, num_sources: int) -> np.ndarray:
    """(6, H, W) float32 network input from (H, W, 3) RGB (uint8 or float in [0, 1]), (H, W, 3)
    normals, the (H, W) counter map and the number of source views the counter was counted over."""
    rgb = np.asarray(rgb)
    rgb = rgb.astype(np.float32) / 255.0 if rgb.dtype == np.uint8 else rgb.astype(np.float32)
    h, w = rgb.shape[:2]
    if normal.shape != (h, w, 3) or counter.shape != (h, w):
        raise ValueError(f"RGB {rgb.shape}, normal {normal.shape} and counter {counter.shape} do not match")
    out = np.empty((NUM_CHANNELS, h, w), np.float32)
    out[RGB] = np.moveaxis(rgb, -1, 0)
    out[NORMAL] = np.moveaxis(encode_normals(normal), -1, 0)
    n = max(1, int(num_sources))
    out[COUNTER] = np.clip(np.asarray(counter, np.float32), 0, n)[None] / n
    return out
