"""COLMAP workspaces of the kinds users bring, generated from a shipped pinhole sample scene for tests: distorted
camera models (SIMPLE_RADIAL, OPENCV), one shared camera or one per image, text or binary models, portrait views
among landscape ones, unregistered images left in ``images/``, larger images, and a camera whose size disagrees
with its images.

The poses, sparse points and tracks are the sample's; a portrait view is its landscape image turned a quarter
counter-clockwise with the pose turned to match, so the geometry stays consistent. The distortion parameters are
written into the model only (the pixels are the sample's), which is all that loading and undistortion look at.
"""

from __future__ import annotations

import shutil
from collections.abc import Collection
from pathlib import Path

import numpy as np
import pycolmap
from PIL import Image

from engine.io.colmap_model import find_model_dir

#: a quarter turn counter-clockwise of the image (PIL's ROTATE_90) in camera coordinates: (X, Y, Z) -> (Y, -X, Z)
_QUARTER = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def _params(model: str, fx: float, fy: float, cx: float, cy: float) -> list[float]:
    if model == "PINHOLE":
        return [fx, fy, cx, cy]
    if model == "SIMPLE_RADIAL":
        return [(fx + fy) / 2, cx, cy, 0.05]
    if model == "OPENCV":
        return [fx, fy, cx, cy, 0.04, -0.01, 0.001, -0.0005]
    raise ValueError(f"no parameters for camera model {model}")


def write_workspace(source: Path, dst: Path, *, camera_model: str = "SIMPLE_RADIAL", per_image: bool = False,
                    binary: bool = False, scale: int = 1, portrait: Collection[int] = (), unregistered: int = 0,
                    camera_factor: float = 1.0) -> Path:
    """Write a workspace at ``dst`` from the pinhole scene ``source``; returns ``dst``.

    Args:
        camera_model: PINHOLE, SIMPLE_RADIAL or OPENCV for every camera.
        per_image: one camera per image (else one per orientation).
        binary: a binary model (else text).
        scale: images (and cameras) ``scale`` times the source's size.
        portrait: indices (in image-id order) of the views turned to portrait.
        unregistered: images put in ``images/`` that the model does not list.
        camera_factor: cameras this many times the images' size (a model that disagrees with its images).
    """
    rec = pycolmap.Reconstruction(str(find_model_dir(source)))
    out = pycolmap.Reconstruction()
    (dst / "images").mkdir(parents=True)
    shared: dict[bool, int] = {}
    for index, image_id in enumerate(sorted(rec.images)):
        image = rec.images[image_id]
        cam = rec.cameras[image.camera_id]
        fx, fy, cx, cy = (float(v) * scale for v in np.array(cam.params)[[0, 1, 2, 3]]) if cam.model.name == \
            "PINHOLE" else (float(v) * scale for v in np.array(cam.params)[[0, 0, 1, 2]])
        width, height = cam.width * scale, cam.height * scale
        pose = image.cam_from_world()
        R, t = np.array(pose.rotation.matrix()), np.array(pose.translation)
        xy = np.array([p.xy for p in image.points2D]).reshape(-1, 2) * scale
        pixels = Image.open(source / "images" / image.name).convert("RGB").resize((width, height), Image.BICUBIC)
        turned = index in portrait
        if turned:
            pixels = pixels.transpose(Image.ROTATE_90)
            fx, fy, cx, cy = fy, fx, cy, width - cx
            width, height = height, width
            R, t = _QUARTER @ R, _QUARTER @ t
            xy = np.stack([xy[:, 1], height - xy[:, 0]], axis=1) if len(xy) else xy
        pixels.save(dst / "images" / image.name, format="PNG", compress_level=1)
        if per_image or turned not in shared:
            camera_id = len(out.cameras) + 1
            f = camera_factor
            out.add_camera_with_trivial_rig(pycolmap.Camera(
                model=camera_model, width=round(width * f), height=round(height * f),
                params=_params(camera_model, fx * f, fy * f, cx * f, cy * f), camera_id=camera_id))
            if not per_image:
                shared[turned] = camera_id
        camera_id = len(out.cameras) if per_image else shared[turned]
        new = pycolmap.Image(name=image.name, camera_id=camera_id, image_id=image_id)
        new.points2D = pycolmap.Point2DList([pycolmap.Point2D(p) for p in xy])
        out.add_image_with_trivial_frame(new, pycolmap.Rigid3d(pycolmap.Rotation3d(R), t))
    for point in rec.points3D.values():
        track = pycolmap.Track([pycolmap.TrackElement(e.image_id, e.point2D_idx) for e in point.track.elements])
        out.add_point3D(point.xyz, track, point.color)
    for k in range(unregistered):
        first = sorted(rec.images)[0]
        shutil.copyfile(dst / "images" / rec.images[first].name, dst / "images" / f"unregistered_{k:03d}.png")
    (dst / "sparse").mkdir()
    if binary:
        out.write_binary(str(dst / "sparse"))
    else:
        out.write_text(str(dst / "sparse"))
    return dst
