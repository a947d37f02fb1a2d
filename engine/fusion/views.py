"""Fusion views of a scene: cameras and colours at each depth map's resolution, overlap lists."""

from __future__ import annotations

import numpy as np

from engine.errors import DeepCError
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
    views = []
    for i, sv in enumerate(scene.views):
        depth = np.asarray(depth_maps[i], np.float32)
        h, w = depth.shape
        cam = sv.camera if (sv.camera.width, sv.camera.height) == (w, h) else sv.camera.rescaled(w, h)
        rgb = scene.image(i)
        if rgb.shape[:2] != (h, w):
            rgb = resize_area(rgb, (w, h))
        conf = None if confidence_maps is None else confidence_maps[i]
        views.append(FusionView(cam, depth, np.asarray(normal_maps[i], np.float32), rgb, conf,
                                scene.overlapping_views(i, check_num_images)))
    return views

