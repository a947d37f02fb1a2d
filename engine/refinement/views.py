"""Refinement and sky filtering of every view of a scene (the ``full`` pipeline's middle stages).

    refined = refine_views(scene, depths, normals, confidences, options)         # Rossi et al. 2020
    (confidence of the refined maps, filter c >= 0.05)                          # Kuhn et al. 2020, §4.2
    depths, normals = sky_filter_views(scene, depths, normals, vanilla_depths, vanilla_confidences)  # §8
    fuse(..., FUSION_PRESETS[DEFAULT_PRESET])                                    # Schönberger et al. 2016

A view with nothing to refine from (:class:`NoDataError`) is reported through ``warnings`` and comes
back as None; callers write an all-zero map for it, so it contributes nothing to fusion.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np

from engine.io.images import resize_area, to_gray
from engine.refinement.options import RefinementOptions
from engine.refinement.refine import NoDataError, RefinedMap, refine_depth
from engine.refinement.sky import SkyOptions, far_mask, filter_sky, sky_mask


def _camera(scene, i: int, shape: tuple[int, int]):
    cam = scene.views[i].camera
    return cam if (cam.height, cam.width) == shape else cam.rescaled(shape[1], shape[0])


def refine_views(scene, depth_maps: list[np.ndarray], normal_maps: list[np.ndarray | None],
                 confidence_maps: list[np.ndarray], options: RefinementOptions | None = None,
                 progress: Callable[[int, int, RefinedMap | None], None] | None = None) -> list[RefinedMap | None]:
    """Refine the depth map of every view of ``scene`` (an ``engine.scene.Scene``) with its grey image,
    camera and depth range; None for views without data (a warning names them)."""

    options = (options or RefinementOptions()).validate()
    out: list[RefinedMap | None] = []
    for i, view in enumerate(scene.views):
        depth = np.asarray(depth_maps[i])
        cam = _camera(scene, i, depth.shape)
        rgb = scene.image(i)
        if rgb.shape[:2] != depth.shape:
            rgb = resize_area(rgb, (depth.shape[1], depth.shape[0]))
        try:
            res = refine_depth(to_gray(rgb), depth, confidence_maps[i], cam.K_idx, view.depth_range,
                               normal_maps[i], options)
        except NoDataError as exc:
            warnings.warn(f"view {view.name}: {exc}; its refined map is left empty", stacklevel=2)
            res = None
        out.append(res)
        if progress is not None:
            progress(i, len(scene.views), res)
    return out


def z99(scene, i: int) -> float:
    """99th-percentile sparse depth of view i, recovered from its depth range (Schönberger et al. 2016)."""
    opts = scene.options
    z_hi = scene.views[i].depth_range[1]
    if opts.depth_range is not None:  # a fixed range: its far end stands for 1.5 z_99
        return z_hi / 1.5
    return z_hi / (opts.depth_stretch[1] * opts.depth_relax[1])


def sky_filter_views(scene, depth_maps: list[np.ndarray], normal_maps: list[np.ndarray],
                     vanilla_depths: list[np.ndarray], vanilla_confidences: list[np.ndarray | None],
                     options: SkyOptions | None = None) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """The sky filter (Kuhn et al. 2020, §5.5) on refined maps: returns (depths, normals, dropped masks)."""
    out = [sky_filter_view(scene, i, depth_maps[i], normal_maps[i], vanilla_depths[i], vanilla_confidences[i],
                           options) for i in range(len(scene.views))]
    return [o[0] for o in out], [o[1] for o in out], [o[2] for o in out]


def sky_filter_view(scene, i: int, depth: np.ndarray, normal: np.ndarray, vanilla_depth: np.ndarray,
                    vanilla_confidence: np.ndarray | None, options: SkyOptions | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sky filter (Kuhn et al. 2020, §5.5) on view ``i``'s (H, W) refined depth and (H, W, 3) normal, given its
    vanilla PatchMatch depth and confidence (None: only pixels without depth count as unreliable): (depth,
    normal, dropped mask)."""
    options = (options or SkyOptions()).validate()
    depth = np.asarray(depth)
    rgb = scene.image(i)
    if rgb.shape[:2] != depth.shape:
        rgb = resize_area(rgb, (depth.shape[1], depth.shape[0]))
    sky = sky_mask(rgb, vanilla_depth, vanilla_confidence, options)
    far = far_mask(depth, z99(scene, i), options.far_factor)
    d, n = filter_sky(depth, normal, sky, far)
    return d, n, sky | far
