"""A run's depth and normal maps fused by our fusion (``engine.fusion``), whichever system made them: so that two
runs' maps are scored through one fusion, and a foreign system's maps apart from its own fusion.

Each view is fused at its own map's size (its camera rescaled to it); a view the run has no map of takes part with
an empty map. COLMAP's normal maps and OpenMVS's float32 normals are camera-frame and face the camera, as ours do.
"""

from __future__ import annotations

import numpy as np

from engine.compare.sources import SourceRun, match_names
from engine.fusion import DEFAULT_PRESET, FUSION_PRESETS, FusedCloud, FusionOptions, fuse, views_from_scene
from engine.scene import Scene


def fuse_run(run: SourceRun, scene: Scene, options: FusionOptions | None = None) -> FusedCloud:
    """``run``'s maps of ``scene``'s views fused with ``options`` (default: what every pipeline of ours fuses with,
    ``FUSION_PRESETS[DEFAULT_PRESET]``: our own vanilla maps give the run's own cloud)."""
    options = options or FUSION_PRESETS[DEFAULT_PRESET]
    keys = match_names(list(run.keys), [v.name for v in scene.views])
    depths, normals = [], []
    for v in scene.views:
        if v.name in keys:
            depths.append(run.depth(keys[v.name]))
            normals.append(run.normal(keys[v.name]))
        else:
            width, height = v.camera.size
            depths.append(np.zeros((height, width), np.float32))
            normals.append(np.zeros((height, width, 3), np.float32))
    return fuse(views_from_scene(scene, depths, normals, None, options.check_num_images), options)
