"""Fusion views of a scene: cameras and colours at each depth map's resolution, overlap lists."""

from __future__ import annotations

import numpy as np

from engine.core.errors import DeepCError
from engine.fusion.cloud import FusionView
from engine.io.images import resize_area


def views_from_scene(scene, depth_maps: list[np.ndarray], normal_maps: list[np.ndarray],
                     confidence_maps: list[np.ndarray | None] | None = None,
                     check_num_images: int = 50) -> list[FusionView]:
    """Fusion views for every view of ``scene`` (an ``engine.scene.Scene``).

    Cameras and colours are brought to each depth map's resolution; the overlap lists are the
    views sharing most sparse points (COLMAP's ``GetMaxOverlappingImages``).
    """

    if len(depth_maps) != len(scene.views) or len(normal_maps) != len(scene.views):
        raise DeepCError(f"scene has {len(scene.views)} views but {len(depth_maps)} depth and "
                         f"{len(normal_maps)} normal maps were given", scene.root)
    return [scene_view(scene, i, depth_maps[i], normal_maps[i],
                       None if confidence_maps is None else confidence_maps[i],
                       scene.overlapping_views(i, check_num_images))
            for i in range(len(scene.views))]


def scene_view(scene, i: int, depth: np.ndarray, normal: np.ndarray, confidence: np.ndarray | None,
               overlap: list[int]) -> FusionView:
    """The fusion view of view ``i`` of ``scene`` with these (H, W) depth, (H, W, 3) normal and (H, W) confidence
    maps (or None) and this overlap list: its camera and colours at the depth's resolution."""
    depth = np.asarray(depth, np.float32)
    h, w = depth.shape
    cam = scene_camera(scene, i, (h, w))
    rgb = scene.image(i)
    if rgb.shape[:2] != (h, w):
        rgb = resize_area(rgb, (w, h))
    return FusionView(cam, depth, np.asarray(normal, np.float32), rgb, confidence, overlap)


def scene_camera(scene, i: int, shape: tuple[int, int]):
    """View ``i``'s camera at resolution ``shape`` (H, W)."""
    cam = scene.views[i].camera
    return cam if (cam.height, cam.width) == tuple(shape) else cam.rescaled(shape[1], shape[0])
