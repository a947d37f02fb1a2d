"""Rendering of a :class:`~engine.synthetic.scene.SceneRecipe`: images and exact GT per view.

Per view: colour is the mean of s x s sub-pixel ray casts (anti-aliasing) with Lambertian shading
(directional light, optional cast shadows, ambient) of solid textures and a smooth sky gradient
where nothing is hit; then optical blur, gamma, Gaussian sensor noise, 8-bit quantisation and an
optional JPEG round trip. GT depth, normal and primitive id come from the pixel-centre ray alone,
so the depth is exact for the index-space pixel centre (``Camera.K_idx``).
"""

from __future__ import annotations

import io

import numpy as np
from PIL import Image
from scipy import ndimage

import engine.synthetic.raycast as raycast
from engine.core.camera import Camera
from engine.synthetic.scene import SceneData, SceneRecipe
from engine.synthetic.sparse import make_sparse_model


def view_rng(scene: SceneRecipe, view: int, stream: int) -> np.random.Generator:
    """Independent deterministic random stream per (scene seed, stream, view)."""
    return np.random.Generator(np.random.PCG64([scene.seed, stream, view]))


def subpixel_rays(camera: Camera, offset: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """(H*W, 3) camera-frame rays (z = 1) through index-space points (col + dx, row + dy)."""
    cols, rows = np.meshgrid(np.arange(camera.width, dtype=np.float64) + offset[0],
                             np.arange(camera.height, dtype=np.float64) + offset[1])
    K = camera.K_idx
    x = (cols - K[0, 2] - K[0, 1] * (rows - K[1, 2]) / K[1, 1]) / K[0, 0]
    y = (rows - K[1, 2]) / K[1, 1]
    return np.stack([x.ravel(), y.ravel(), np.ones(x.size)], axis=1)


def cast_camera_rays(scene: SceneRecipe, camera: Camera, offset: tuple[float, float] = (0.0, 0.0)) -> raycast.Hits:
    """Cast one ray per pixel through (col + dx, row + dy); ``Hits.s`` is the camera z-depth."""
    dirs = subpixel_rays(camera, offset) @ camera.R  # camera -> world: R^T d, row-vector form
    return raycast.cast(scene.primitives, camera.center, dirs)


def shade(scene: SceneRecipe, hits: raycast.Hits, directions: np.ndarray) -> np.ndarray:
    """(N, 3) linear radiance of N rays: Lambertian surfaces, sky where nothing is hit."""
    rs = scene.render
    out = np.empty((len(hits.s), 3))
    hit = hits.hit
    # Sky: smooth gradient over the elevation of the (world) viewing direction; nearly textureless.
    d = directions[~hit]
    elevation = np.clip(d[:, 2] / np.linalg.norm(d, axis=1), -1.0, 1.0)
    w = np.clip(elevation * 2.0 + 0.3, 0.0, 1.0)[:, None] ** 0.8
    out[~hit] = (1 - w) * np.asarray(scene.sky_horizon) + w * np.asarray(scene.sky_zenith)
    if not hit.any():
        return out
    points, normals, prim = hits.point[hit], hits.normal[hit], hits.prim[hit]
    albedo = np.empty((len(points), 3))
    for index in np.unique(prim):
        sel = prim == index
        albedo[sel] = scene.textures[index].albedo(points[sel])
    lambert = np.clip(normals @ scene.light_dir, 0.0, None)
    if rs.shadows:
        lit = lambert > 0
        origins = points[lit] + normals[lit] * 1e-6 * (1.0 + np.abs(points[lit]).max(axis=1, keepdims=True))
        blocked = raycast.occluded(scene.primitives, origins, scene.light_dir)
        factor = np.ones(len(points))
        factor[np.flatnonzero(lit)[blocked]] = 1.0 - rs.shadow_strength
        lambert = lambert * factor
    out[hit] = albedo * (rs.ambient + rs.sun * lambert)[:, None]
    return out


def render_view(scene: SceneRecipe, view: int) -> dict[str, np.ndarray]:
    """Render view ``view``.

    Returns:
        ``image`` (H, W, 3) uint8 RGB; ``depth`` (H, W) float32 camera z (0 = sky);
        ``normal`` (H, W, 3) float32 camera-frame unit normals facing the camera (0 = sky);
        ``prim`` (H, W) int32 primitive ids (-1 = sky); ``point`` (H, W, 3) float64 world hit points
        of the pixel centres (NaN = sky).
    """
    camera = scene.cameras[view]
    rs = scene.render
    h, w = camera.height, camera.width
    centre = cast_camera_rays(scene, camera)
    s = rs.supersample
    offsets = [((i + 0.5) / s - 0.5, (j + 0.5) / s - 0.5) for j in range(s) for i in range(s)]
    radiance = np.zeros((h * w, 3))
    for offset in offsets:
        hits = centre if offset == (0.0, 0.0) else cast_camera_rays(scene, camera, offset)
        radiance += shade(scene, hits, subpixel_rays(camera, offset) @ camera.R)
    radiance = radiance.reshape(h, w, 3) / len(offsets)
    image = finish_image(radiance * rs.exposure, scene, view_rng(scene, view, 1))
    hit = centre.hit.reshape(h, w)
    depth = np.where(hit, centre.s.reshape(h, w), 0.0).astype(np.float32)
    normal = (centre.normal @ camera.R.T).reshape(h, w, 3).astype(np.float32)
    return {"image": image, "depth": depth, "normal": normal, "prim": centre.prim.reshape(h, w),
            "point": centre.point.reshape(h, w, 3)}


def finish_image(radiance: np.ndarray, scene: SceneRecipe, rng: np.random.Generator) -> np.ndarray:
    """Linear (H, W, 3) radiance -> uint8 RGB: blur, gamma, sensor noise, quantisation, JPEG."""
    rs = scene.render
    img = np.clip(radiance, 0.0, 1.0)
    if rs.blur_sigma > 0:
        img = ndimage.gaussian_filter(img, sigma=(rs.blur_sigma, rs.blur_sigma, 0), mode="nearest")
    img = 255.0 * img ** (1.0 / rs.gamma)
    if rs.noise_sigma > 0:
        img = img + rng.normal(0.0, rs.noise_sigma, img.shape)
    img = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    if rs.jpeg_quality > 0:
        buf = io.BytesIO()
        Image.fromarray(img).save(buf, format="JPEG", quality=int(rs.jpeg_quality))
        img = np.asarray(Image.open(io.BytesIO(buf.getvalue())).convert("RGB")).copy()
    return img


def voxel_thin(points: np.ndarray, voxel: float) -> np.ndarray:
    """Keep the first point of every occupied voxel of size ``voxel``; (N, 3) -> (G, 3), order kept."""
    keys = np.floor(points / voxel).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return points[np.sort(first)]


def render_scene(scene: SceneRecipe) -> SceneData:
    """Render all views, draw the sparse model and collect GT points."""
    views = [render_view(scene, v) for v in range(len(scene.cameras))]
    points = np.concatenate([v["point"][v["prim"] >= 0] for v in views])
    data = SceneData(
        scene=scene,
        images=[v["image"] for v in views],
        depths=[v["depth"] for v in views],
        normals=[v["normal"] for v in views],
        prim_ids=[v["prim"] for v in views],
        sparse=None,  # type: ignore[arg-type]  # filled right below
        gt_points=voxel_thin(points, scene.gt_voxel),
    )
    data.sparse = make_sparse_model(data, np.random.Generator(np.random.PCG64([scene.seed, 2])))
    return data
