"""Scene recipes: the two fixed sample scenes and a seeded random-scene generator.

World frame: z up, metres, objects around the origin on a ground plane z = 0. Cameras sit on an
arc around the scene centre and look at it, like a hand-held capture walking around an object:
PINHOLE with fx != fy (slightly) and an off-centre principal point.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from engine.core.camera import Camera
from engine.core.options import Options, option
from engine.synthetic.raycast import Box, Cylinder, Quad, Sphere
from engine.synthetic.scene import RenderSettings, SceneRecipe, SparseSettings
from engine.synthetic.texture import KINDS, Texture


def rot_z(degrees: float) -> np.ndarray:
    """(3, 3) rotation about the world z axis; as a box rotation its columns are the box axes."""
    a = math.radians(degrees)
    return np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])


def look_at(center: np.ndarray, target: np.ndarray, roll_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """COLMAP world-to-camera (R (3, 3), t (3,)) of a camera at ``center`` looking at ``target``.

    Camera axes: x right, y down, z forward; world z is up; ``roll_deg`` turns about the optical axis.
    """
    c = np.asarray(center, np.float64)
    forward = np.asarray(target, np.float64) - c
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    a = math.radians(roll_deg)
    right, down = math.cos(a) * right + math.sin(a) * down, -math.sin(a) * right + math.cos(a) * down
    R = np.stack([right, down, forward])
    return R, -R @ c


def arc_cameras(n: int, width: int, height: int, focal: float, target: np.ndarray, radius: float,
                height_m: float, step_deg: float, azimuth_deg: float = -90.0,
                rng: np.random.Generator | None = None, jitter: float = 0.0) -> list[Camera]:
    """``n`` cameras on a horizontal arc (``step_deg`` apart, centred on ``azimuth_deg``) looking at ``target``.

    Intrinsics are shared, like one physical camera: fy = 1.008 fx, principal point off-centre by a
    few pixels. With ``rng`` and ``jitter`` > 0, positions (metres * jitter), aim points and roll are
    perturbed slightly, as in a hand-held capture.
    """
    target = np.asarray(target, np.float64)
    fx, fy = focal, focal * 1.008
    cx, cy = width / 2 + 0.013 * width, height / 2 - 0.011 * height
    cams = []
    for i in range(n):
        az = math.radians(azimuth_deg + (i - (n - 1) / 2) * step_deg)
        center = np.array([target[0] + radius * math.cos(az), target[1] + radius * math.sin(az), height_m])
        aim, roll = target.copy(), 0.0
        if rng is not None and jitter > 0:
            center = center + rng.normal(0.0, 0.08 * jitter, 3)
            aim = aim + rng.normal(0.0, 0.10 * jitter, 3)
            roll = float(rng.normal(0.0, 1.5 * jitter))
        R, t = look_at(center, aim, roll)
        cams.append(Camera.from_params(width, height, fx, fy, cx, cy, R, t))
    return cams


def _names(n: int) -> list[str]:
    return [f"view_{i:03d}.png" for i in range(n)]


def tiny_scene() -> SceneRecipe:
    """5 views, 160 x 120: strongly textured, moderate baseline (6 degrees), little sky, for unit tests."""
    rng = np.random.Generator(np.random.PCG64(1))
    prims = [
        Quad((0.0, 0.5, 0.0), (1, 0, 0), (0, 1, 0), 6.0, 6.0),              # ground
        Quad((0.0, 2.1, 1.2), (1, 0, 0), (0, 0, 1), 6.0, 1.2),              # back wall, sky strip above
        Box((-0.95, 0.35, 0.45), (0.45, 0.4, 0.45), rot_z(25)),
        Box((0.85, 1.2, 0.65), (0.35, 0.5, 0.65), rot_z(-15)),
        Sphere((0.15, -0.45, 0.45), 0.45),
        Quad((1.95, 0.6, 0.7), (0.94, -0.34, 0.0), (0.2, 0.55, 0.81), 0.45, 0.75),  # slanted panel
    ]
    textures = [  # fine, high-contrast noise everywhere: easy to match
        Texture("noise", (0.10, 0.08, 0.05), (0.85, 0.75, 0.55), 0.22, 2.0, 4, 11, 0.65),
        Texture("noise", (0.10, 0.16, 0.32), (0.85, 0.88, 0.92), 0.25, 2.0, 4, 12, 0.65),
        Texture("noise", (0.55, 0.08, 0.05), (0.95, 0.85, 0.30), 0.15, 2.0, 4, 13, 0.65),
        Texture("noise", (0.05, 0.25, 0.08), (0.70, 0.95, 0.60), 0.18, 2.0, 4, 14, 0.65),
        Texture("noise", (0.10, 0.10, 0.40), (0.95, 0.90, 0.95), 0.12, 2.0, 4, 15, 0.65),
        Texture("noise", (0.35, 0.05, 0.35), (0.95, 0.80, 0.50), 0.15, 2.0, 4, 16, 0.65),
    ]
    cams = arc_cameras(5, 160, 120, 150.0, np.array([0.0, 0.5, 0.75]), 4.6, 2.3, 6.0,
                       rng=rng, jitter=0.2)
    return SceneRecipe(
        name="tiny", seed=1, primitives=prims, textures=textures, light_dir=np.array([-0.4, -0.5, 0.75]),
        sky_horizon=(0.75, 0.82, 0.92), sky_zenith=(0.35, 0.50, 0.85), cameras=cams, image_names=_names(5),
        render=RenderSettings(noise_sigma=1.0, shadow_strength=0.5),
        sparse=SparseSettings(cell_size=8),
        gt_voxel=0.025,
        description=("Tiny synthetic scene for unit tests: a ground plane, a back wall, two rotated boxes, a "
                     "sphere and a slanted panel, all strongly textured, seen by 5 cameras on a 24-degree arc "
                     "(6 degrees apart), 160x120 pixels, a thin strip of sky."),
        recipe="engine.synthetic.layout.tiny_scene()",
    )


def small_scene() -> SceneRecipe:
    """8 views, 320 x 240: varied geometry and textures, occlusions, thin poles, sky, one weak texture."""
    rng = np.random.Generator(np.random.PCG64(2))
    prims = [
        Quad((0.0, 0.5, 0.0), (1, 0, 0), (0, 1, 0), 7.0, 7.0),                  # 0 ground
        Quad((-0.3, 3.0, 1.1), (1, 0, 0), (0, 0, 1), 3.6, 1.1),                 # 1 back wall (sky above)
        Quad((3.1, 1.2, 0.9), (0.3, 1, 0), (0, 0, 1), 1.6, 0.9),                # 2 side wall, weak texture
        Box((-1.2, 0.6, 0.5), (0.5, 0.45, 0.5), rot_z(30)),                     # 3 box
        Box((0.9, 1.6, 0.75), (0.4, 0.6, 0.75), rot_z(-12)),                    # 4 tall box
        Box((0.2, 0.1, 0.2), (0.3, 0.25, 0.2), rot_z(55)),                      # 5 low box, in front
        Sphere((-0.15, -0.75, 0.4), 0.4),                                       # 6 sphere, occludes
        Sphere((-0.5, 2.2, 0.3), 0.3),                                          # 7 sphere behind boxes
        Quad((2.0, 0.1, 0.55), (0.95, -0.3, 0.0), (0.15, 0.5, 0.85), 0.5, 0.65),  # 8 slanted plane
        Cylinder((-2.1, -0.2, 0.0), 0.035, 2.4),                                # 9 thin pole
        Cylinder((1.6, -0.9, 0.0), 0.03, 1.9),                                  # 10 thin pole
        Cylinder((0.35, 2.4, 0.0), 0.05, 2.6),                                  # 11 pole near the wall
        Box((-2.4, 1.4, 0.6), (0.6, 0.012, 0.6), rot_z(-35)),                   # 12 thin plate
    ]
    textures = [
        Texture("noise", (0.12, 0.10, 0.07), (0.80, 0.72, 0.55), 0.25, 2.2, 4, 21),
        Texture("blobs", (0.15, 0.20, 0.28), (0.85, 0.85, 0.80), 0.35, 1.3, 4, 22),
        Texture("weak", (0.62, 0.60, 0.55), (0.70, 0.68, 0.62), 1.0, 1.0, 2, 23),
        Texture("checker", (0.60, 0.10, 0.08), (0.95, 0.85, 0.40), 0.12, 1.0, 3, 24),
        Texture("stripes", (0.06, 0.22, 0.10), (0.70, 0.92, 0.62), 0.20, 1.3, 3, 25),
        Texture("noise", (0.30, 0.10, 0.35), (0.95, 0.75, 0.90), 0.10, 2.4, 4, 26),
        Texture("noise", (0.08, 0.10, 0.40), (0.90, 0.92, 0.95), 0.12, 2.4, 4, 27),
        Texture("blobs", (0.45, 0.25, 0.05), (0.95, 0.90, 0.70), 0.10, 1.4, 4, 28),
        Texture("noise", (0.20, 0.05, 0.05), (0.95, 0.60, 0.40), 0.15, 2.4, 4, 29),
        Texture("stripes", (0.10, 0.10, 0.10), (0.90, 0.90, 0.90), 0.10, 1.2, 2, 30),
        Texture("noise", (0.25, 0.15, 0.05), (0.90, 0.80, 0.30), 0.08, 2.0, 3, 31),
        Texture("noise", (0.05, 0.15, 0.20), (0.70, 0.90, 0.95), 0.08, 2.0, 3, 32),
        Texture("blobs", (0.05, 0.05, 0.05), (0.85, 0.80, 0.70), 0.12, 1.4, 4, 33),
    ]
    cams = arc_cameras(8, 320, 240, 290.0, np.array([0.0, 0.6, 0.7]), 5.4, 1.9, 7.0,
                       rng=rng, jitter=1.0)
    return SceneRecipe(
        name="small", seed=2, primitives=prims, textures=textures, light_dir=np.array([0.5, -0.35, 0.8]),
        sky_horizon=(0.78, 0.84, 0.92), sky_zenith=(0.30, 0.45, 0.85), cameras=cams, image_names=_names(8),
        render=RenderSettings(noise_sigma=2.0, blur_sigma=0.3),
        sparse=SparseSettings(cell_size=12),
        gt_voxel=0.02,
        description=("Small synthetic scene for the demo and regression runs: ground, back wall with sky above, "
                     "a weakly textured side wall, three boxes, two spheres, a slanted plane, three thin poles "
                     "and a thin plate, with occlusions and cast shadows, seen by 8 hand-held-like cameras on a "
                     "49-degree arc (7 degrees apart), 320x240 pixels, sensor noise and slight blur."),
        recipe="engine.synthetic.layout.small_scene()",
    )


Range = tuple[float, float]  # (lo, hi), drawn uniformly


@dataclasses.dataclass
class RandomSceneKnobs(Options):
    """Knobs of :func:`random_scene` (all ours). A (lo, hi) pair is drawn uniformly (integers inclusive);
    give lo == hi to fix a value."""

    # --- cameras
    n_views: Range = option((6, 10), "number of views", source="ours", low=2, ordered="<=")
    width: int = option(320, "image width", unit="px", source="ours", low=8)
    height: int = option(240, "image height", unit="px", source="ours", low=8)
    focal: Range = option((0.75, 1.3), "fx as a multiple of the image width", source="ours", ordered="<=")
    arc_step_deg: Range = option((4.0, 12.0), "angle between neighbouring cameras", unit="degrees", source="ours",
                                 ordered="<=")
    radius: Range = option((4.5, 7.0), "camera distance from the scene centre", unit="m", source="ours", ordered="<=")
    cam_height: Range = option((1.2, 3.0), "camera height above the ground", unit="m", source="ours", ordered="<=")
    jitter: Range = option((0.0, 1.0), "hand-held pose jitter (0 = perfect arc)", source="ours", ordered="<=")
    # --- geometry
    n_boxes: Range = option((1, 4), "number of boxes", source="ours", ordered="<=")
    n_spheres: Range = option((0, 3), "number of spheres", source="ours", ordered="<=")
    sphere_radius: Range = option((0.2, 0.6), "sphere radius", unit="m", source="ours", ordered="<=")
    n_poles: Range = option((0, 4), "number of thin vertical poles", source="ours", ordered="<=")
    n_slanted: Range = option((0, 2), "number of slanted rectangles", source="ours", ordered="<=")
    wall_prob: float = option(0.8, "probability of a back wall", source="ours", low=0, high=1)
    wall_height: Range = option((1.0, 3.5), "back wall height; lower walls show more sky", unit="m", source="ours",
                                ordered="<=")
    # --- appearance
    texture_kinds: tuple = option(KINDS, "texture kinds to draw from", source="ours", choices=KINDS, nonempty=True)
    weak_prob: float = option(0.15, "probability that a surface gets the weak texture", source="ours", low=0, high=1)
    texture_scale: Range = option((0.06, 0.5), "texture feature size", unit="m", source="ours", ordered="<=")
    contrast: Range = option((0.8, 2.8), "texture contrast", source="ours", ordered="<=")
    sun: Range = option((0.3, 1.0), "directional light intensity", source="ours", ordered="<=")
    ambient: Range = option((0.15, 0.5), "ambient light", source="ours", ordered="<=")
    sun_elevation_deg: Range = option((25.0, 80.0), "elevation of the light", unit="degrees", source="ours",
                                      ordered="<=")
    shadows_prob: float = option(0.7, "probability of cast shadows", source="ours", low=0, high=1)
    # --- camera model and image degradations
    exposure: Range = option((0.8, 1.3), "linear exposure gain", source="ours", ordered="<=")
    noise_sigma: Range = option((0.5, 4.0), "sensor noise", unit="8-bit grey levels", source="ours", ordered="<=")
    blur_sigma: Range = option((0.0, 1.0), "optical blur", unit="px", source="ours", ordered="<=")
    jpeg_prob: float = option(0.4, "probability of a JPEG round trip", source="ours", low=0, high=1)
    jpeg_quality: Range = option((60, 95), "JPEG quality when it happens", source="ours", ordered="<=")
    supersample: int = option(3, "anti-aliasing samples per pixel side", source="ours")


def _draw(rng: np.random.Generator, pair: tuple) -> float | int:
    lo, hi = pair
    if isinstance(lo, int) and isinstance(hi, int):
        return int(rng.integers(lo, hi + 1))
    return float(rng.uniform(lo, hi))


def _random_texture(rng: np.random.Generator, knobs: RandomSceneKnobs, seed: int) -> Texture:
    if rng.random() < knobs.weak_prob:
        base = rng.uniform(0.3, 0.8, 3)
        return Texture("weak", tuple(base), tuple(np.clip(base + rng.uniform(0.02, 0.08), 0, 1)),
                       float(rng.uniform(0.5, 2.0)), 1.0, 2, seed)
    kinds = [k for k in knobs.texture_kinds if k != "weak"] or ["weak"]
    kind = kinds[int(rng.integers(len(kinds)))]
    dark = rng.uniform(0.02, 0.4, 3)
    light = rng.uniform(0.5, 0.98, 3)
    if rng.random() < 0.5:
        dark, light = light, dark
    return Texture(kind, tuple(dark), tuple(light), _draw(rng, knobs.texture_scale), _draw(rng, knobs.contrast),
                   int(rng.integers(2, 5)), seed)


def random_scene(seed: int, **knobs) -> SceneRecipe:
    """A random scene drawn from ``numpy.random.Generator(PCG64(seed))``; same seed, same scene.

    Keyword arguments are :class:`RandomSceneKnobs` fields (ranges as (lo, hi) tuples).
    """
    k = RandomSceneKnobs(**knobs).validate()
    rng = np.random.Generator(np.random.PCG64(seed))
    prims: list = [Quad((0.0, 0.0, 0.0), (1, 0, 0), (0, 1, 0), 12.0, 12.0)]
    azimuth = float(rng.uniform(0.0, 360.0))  # arc centre direction, seen from the scene centre
    away = np.array([-math.cos(math.radians(azimuth)), -math.sin(math.radians(azimuth)), 0.0])
    side = np.array([-away[1], away[0], 0.0])

    def spot(spread: float = 2.0) -> np.ndarray:
        r, a = spread * math.sqrt(rng.random()), rng.uniform(0, 2 * math.pi)
        return np.array([r * math.cos(a), r * math.sin(a)])

    if rng.random() < k.wall_prob:
        hw = _draw(rng, k.wall_height) / 2
        c = away * rng.uniform(2.5, 4.0)
        prims.append(Quad((c[0], c[1], hw), tuple(side), (0, 0, 1), float(rng.uniform(4.0, 8.0)), hw))
    for _ in range(_draw(rng, k.n_boxes)):
        xy, half = spot(), rng.uniform(0.15, 0.7, 3)
        prims.append(Box((xy[0], xy[1], half[2]), tuple(half), rot_z(rng.uniform(0, 90))))
    for _ in range(_draw(rng, k.n_spheres)):
        xy, r = spot(), float(_draw(rng, k.sphere_radius))
        prims.append(Sphere((xy[0], xy[1], r * rng.uniform(0.7, 1.5)), r))
    for _ in range(_draw(rng, k.n_poles)):
        xy = spot(2.5)
        prims.append(Cylinder((xy[0], xy[1], 0.0), float(rng.uniform(0.02, 0.07)), float(rng.uniform(1.0, 3.0))))
    for _ in range(_draw(rng, k.n_slanted)):
        xy, yaw, tilt = spot(), rng.uniform(0, 2 * math.pi), math.radians(rng.uniform(20, 70))
        u = np.array([math.cos(yaw), math.sin(yaw), 0.0])
        v = np.array([-math.sin(yaw) * math.cos(tilt), math.cos(yaw) * math.cos(tilt), math.sin(tilt)])
        hu, hv = rng.uniform(0.3, 0.8, 2)
        prims.append(Quad((xy[0], xy[1], hv * math.sin(tilt) + 0.02), tuple(u), tuple(v), float(hu), float(hv)))
    textures = [_random_texture(rng, k, seed * 1000 + i) for i in range(len(prims))]

    n_views = _draw(rng, k.n_views)
    target = np.array([0.0, 0.0, rng.uniform(0.3, 1.0)])
    focal = _draw(rng, k.focal) * k.width
    cams = arc_cameras(n_views, k.width, k.height, focal, target, _draw(rng, k.radius), _draw(rng, k.cam_height),
                       _draw(rng, k.arc_step_deg), azimuth, rng=rng, jitter=_draw(rng, k.jitter))
    elev, sun_az = math.radians(_draw(rng, k.sun_elevation_deg)), rng.uniform(0, 2 * math.pi)
    light = np.array([math.cos(elev) * math.cos(sun_az), math.cos(elev) * math.sin(sun_az), math.sin(elev)])
    zenith = rng.uniform([0.2, 0.3, 0.6], [0.5, 0.6, 0.95])
    horizon = np.clip(zenith + rng.uniform(0.2, 0.4), 0, 1)
    render = RenderSettings(
        supersample=k.supersample, ambient=_draw(rng, k.ambient), sun=_draw(rng, k.sun),
        shadows=bool(rng.random() < k.shadows_prob), exposure=_draw(rng, k.exposure),
        noise_sigma=_draw(rng, k.noise_sigma), blur_sigma=_draw(rng, k.blur_sigma),
        jpeg_quality=int(_draw(rng, k.jpeg_quality)) if rng.random() < k.jpeg_prob else 0)
    return SceneRecipe(
        name=f"random_{seed}", seed=seed, primitives=prims, textures=textures, light_dir=light,
        sky_horizon=tuple(horizon), sky_zenith=tuple(zenith), cameras=cams, image_names=_names(n_views),
        render=render, sparse=SparseSettings(cell_size=max(8, k.width // 24)), gt_voxel=0.02,
        description=f"Random synthetic scene, seed {seed}.",
        recipe=f"engine.synthetic.layout.random_scene({seed}, **{knobs!r})",
    )
