"""Where a pixel's matching window lands in its source images: the thumbnails of the pixel inspector.

PatchMatch compares the reference window with its image in each source view under the homography of the
pixel's plane (depth and normal; Schönberger et al. 2016, §4; Xu & Tao 2019). Drawing that footprint on a
crop of every source image shows at a glance what the cost saw: an occluder, a texture-less wall, a window
that falls off the image. Geometry in the engine's pixel-centre convention (``engine/core/camera.py``).
"""

from __future__ import annotations

import numpy as np

from engine.core.camera import Camera

THUMB = 96  # side of one thumbnail in pixels


def window_corners(camera: Camera, x: int, y: int, depth: float, normal, half: int) -> np.ndarray:
    """(4, 3) world points where the window corners (x ± half, y ± half) meet the pixel's plane.

    The plane passes through the pixel's 3-D point at ``depth`` with ``normal`` (camera frame); a normal
    seen edge-on (or missing) falls back to the fronto-parallel plane."""
    k_inv = np.linalg.inv(camera.K_idx)
    point = k_inv @ np.array([x, y, 1.0]) * depth
    n = np.asarray(normal if normal is not None else (0.0, 0.0, -1.0), np.float64)
    corners = []
    for u, v in ((x - half, y - half), (x + half, y - half), (x + half, y + half), (x - half, y + half)):
        ray = k_inv @ np.array([u, v, 1.0])
        along = float(n @ ray)
        scale = float(n @ point) / along if abs(along) > 1e-9 else depth
        if not np.isfinite(scale) or scale <= 0 or scale > 10 * depth:
            scale = depth  # edge-on plane: the fronto-parallel window
        corners.append(ray * scale)
    return camera.camera_to_world(np.array(corners))


def ray_points(camera: Camera, x: int, y: int, depths) -> np.ndarray:
    """(N, 3) world points on pixel (x, y)'s ray at camera-frame ``depths`` (N,)."""
    ray = np.linalg.inv(camera.K_idx) @ np.array([x, y, 1.0])
    return camera.camera_to_world(np.asarray(depths, np.float64).reshape(-1)[:, None] * ray[None, :])


def _crop(image: np.ndarray, centre: np.ndarray, radius: int) -> tuple[np.ndarray, np.ndarray]:
    """A (2r+1)² crop of ``image`` around ``centre`` (black outside the image) and its top-left corner."""
    h, w = image.shape[:2]
    cx, cy = int(round(centre[0])), int(round(centre[1]))
    out = np.zeros((2 * radius + 1, 2 * radius + 1, 3), np.uint8)
    x0, y0 = cx - radius, cy - radius
    xs, ys = slice(max(x0, 0), min(x0 + 2 * radius + 1, w)), slice(max(y0, 0), min(y0 + 2 * radius + 1, h))
    if xs.start < xs.stop and ys.start < ys.stop:
        out[ys.start - y0:ys.stop - y0, xs.start - x0:xs.stop - x0] = image[ys, xs]
    return out, np.array([x0, y0], np.float64)


def window_thumbnails(images: list[np.ndarray], cameras: list[Camera], names: list[str], x: int, y: int,
                      depth: float, normal, half: int, selected: set[str] | frozenset = frozenset(),
                      costs: list | None = None, columns: int = 4) -> np.ndarray:
    """(H, W, 3) uint8 grid, ``columns`` wide: the reference window (first) and its footprint in each source image.

    Args:
        images: uint8 (H_i, W_i, 3) images, reference first, then the sources in ``names[1:]`` order.
        cameras: their cameras at the same resolution.
        names: view names, reference first.
        x, y: the pixel (column, row) of the reference view; ``depth``/``normal`` its plane (camera frame).
        half: half the matching window side (``PatchMatchOptions.window // 2``).
        selected: source names the view selection kept (outlined green; others red).
        costs: per source view the cost of the plane (None: not evaluated), printed under the thumbnail.
    """
    from PIL import Image, ImageDraw  # lazy: pillow

    world = window_corners(cameras[0], x, y, depth, normal, half) if depth and depth > 0 else None
    tiles = []
    for k, (image, camera, name) in enumerate(zip(images, cameras, names, strict=True)):
        if k == 0:
            quad = np.array([[x - half, y - half], [x + half, y - half], [x + half, y + half], [x - half, y + half]],
                            np.float64)
        elif world is None:
            quad = None
        else:
            quad, z = camera.project(world)
            if not (z > 0).all() or not np.isfinite(quad).all():
                quad = None
        centre = np.array([x, y], np.float64) if quad is None and k == 0 else (
            quad.mean(axis=0) if quad is not None else None)
        extent = 0.0 if quad is None else float(np.ptp(quad, axis=0).max())
        radius = int(max(3 * half, 0.9 * extent, 8))
        tile = Image.new("RGB", (THUMB, THUMB + 14), (255, 255, 255))
        draw = ImageDraw.Draw(tile)
        visible = quad is not None and centre is not None
        if visible:
            crop, origin = _crop(image, centre, radius)
            scale = THUMB / crop.shape[0]
            tile.paste(Image.fromarray(crop).resize((THUMB, THUMB), Image.NEAREST), (0, 0))
            points = [tuple(((p - origin + 0.5) * scale).tolist()) for p in quad]
            colour = (240, 160, 0) if k == 0 else ((40, 200, 80) if name in selected else (230, 50, 50))
            draw.polygon(points, outline=colour, width=2)
            h, w = image.shape[:2]
            if k > 0 and not ((quad >= -0.5) & (quad <= np.array([w - 0.5, h - 0.5]))).all():
                draw.text((2, 2), "off image", fill=(255, 255, 0))
        else:
            draw.rectangle((0, 0, THUMB - 1, THUMB - 1), fill=(40, 40, 40))
            draw.text((6, THUMB // 2 - 6), "behind camera", fill=(255, 255, 255))
        caption = "ref " if k == 0 else ""
        caption += str(name).rsplit("/", 1)[-1][-10:]
        if k > 0 and costs is not None and k - 1 < len(costs) and costs[k - 1] is not None:
            caption += f" {float(costs[k - 1]):.2f}"
        draw.text((2, THUMB + 1), caption, fill=(0, 0, 0))
        tiles.append(np.asarray(tile))
    if not tiles:
        return np.zeros((THUMB + 14, THUMB, 3), np.uint8)
    blank = np.full_like(tiles[0], 255)
    width = min(columns, len(tiles))
    tiles += [blank] * (-len(tiles) % width)
    return np.concatenate([np.concatenate(tiles[r:r + width], axis=1) for r in range(0, len(tiles), width)], axis=0)
