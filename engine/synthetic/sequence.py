"""Long synthetic sequences for scaling measurements: a street walked past with a side-looking camera, one view
every ``spacing`` metres (like a mapping vehicle's side camera).

The street runs along world x: a ground plane, a textured facade 4 m to the camera's left (y = 4) with pillars and
balconies every 3 m (boxes; depth structure), a low kerb. Each facade point is seen by about five consecutive views
(a 60 degree field of view at 4 m covers 4.6 m), so the source views of a view are its neighbours in the sequence
and the work per view does not depend on the sequence's length: what ``benchmarks/performance/bench_dask.py``
measures against N.
"""

from __future__ import annotations

import math

import numpy as np

from engine.core.camera import Camera
from engine.synthetic.layout import look_at
from engine.synthetic.raycast import Box, Quad
from engine.synthetic.scene import RenderSettings, SceneRecipe, SparseSettings
from engine.synthetic.texture import Texture

FACADE_Y = 4.0  # metres from the camera path to the facade
BAY = 3.0  # metres between pillars


def street_scene(n_views: int, width: int = 320, height: int = 240, spacing: float = 1.0, seed: int = 0
                 ) -> SceneRecipe:
    """``n_views`` views ``spacing`` metres apart along a street (see the module docstring); same arguments, same
    scene. Shadows off and one colour sample per pixel keep rendering linear in ``n_views`` and fast."""
    if n_views < 2:
        raise ValueError("a sequence needs at least 2 views")
    rng = np.random.Generator(np.random.PCG64(seed))
    length = (n_views - 1) * spacing
    half = length / 2 + 8.0
    mid = length / 2
    prims: list = [Quad((mid, 0.0, 0.0), (1, 0, 0), (0, 1, 0), half, 6.0),                 # ground
                   Quad((mid, FACADE_Y, 4.0), (1, 0, 0), (0, 0, 1), half, 4.0),           # facade
                   Box((mid, FACADE_Y - 1.2, 0.08), (half, 0.15, 0.08), np.eye(3))]       # kerb
    textures = [Texture("noise", (0.12, 0.11, 0.10), (0.70, 0.68, 0.62), 0.20, 2.0, 4, seed * 100 + 1, 0.65),
                Texture("noise", (0.35, 0.18, 0.12), (0.92, 0.85, 0.70), 0.15, 2.2, 4, seed * 100 + 2, 0.65),
                Texture("stripes", (0.25, 0.25, 0.28), (0.80, 0.80, 0.78), 0.25, 1.5, 3, seed * 100 + 3)]
    for k, x in enumerate(np.arange(-8.0, length + 8.0, BAY)):
        depth = float(rng.uniform(0.2, 0.5))
        prims.append(Box((x, FACADE_Y - depth, 3.0), (0.25, depth, 3.0), np.eye(3)))     # pillar
        textures.append(Texture("noise", (0.10, 0.10, 0.25), (0.85, 0.85, 0.95), 0.12, 2.0, 4,
                                seed * 100 + 10 + 2 * k, 0.65))
        prims.append(Box((x + BAY / 2, FACADE_Y - 0.6, float(rng.uniform(1.8, 2.6))), (0.8, 0.6, 0.08),
                         np.eye(3)))                                                       # balcony
        textures.append(Texture("noise", (0.30, 0.05, 0.05), (0.95, 0.80, 0.40), 0.10, 2.0, 4,
                                seed * 100 + 11 + 2 * k, 0.65))
    focal = 0.5 * width / math.tan(math.radians(30.0))  # 60 degrees across
    cx, cy = width / 2 + 0.013 * width, height / 2 - 0.011 * height
    cams = []
    for i in range(n_views):
        center = np.array([i * spacing, 0.0, 1.6]) + rng.normal(0.0, 0.02, 3)
        aim = center + np.array([float(rng.normal(0.0, 0.15)), FACADE_Y, 0.3])
        R, t = look_at(center, aim, float(rng.normal(0.0, 0.5)))
        cams.append(Camera.from_params(width, height, focal, focal * 1.008, cx, cy, R, t))
    return SceneRecipe(
        name=f"street_{n_views}", seed=seed, primitives=prims, textures=textures,
        light_dir=np.array([0.3, -0.6, 0.75]), sky_horizon=(0.78, 0.84, 0.92), sky_zenith=(0.30, 0.45, 0.85),
        cameras=cams, image_names=[f"view_{i:05d}.png" for i in range(n_views)],
        render=RenderSettings(supersample=1, shadows=False, noise_sigma=1.0),
        sparse=SparseSettings(cell_size=12, neighbours=6), gt_voxel=0.05,
        description=(f"A street seen by a side-looking camera, {n_views} views {spacing:g} m apart, "
                     f"{width}x{height} pixels: ground, a facade 4 m away with pillars and balconies every 3 m."),
        recipe=f"engine.synthetic.sequence.street_scene({n_views}, {width}, {height}, {spacing}, {seed})",
    )
