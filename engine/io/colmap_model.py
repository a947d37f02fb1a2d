"""COLMAP sparse models, read through pycolmap (binary or text, in ``sparse/`` or ``sparse/0/``).

The model is flattened into :class:`SparseModel`: plain numpy arrays for cameras, poses, 3-D
points and their tracks, so that the rest of the engine never touches pycolmap objects.
Cameras that are not PINHOLE / SIMPLE_PINHOLE can be undistorted into a cache with
:func:`undistort_workspace`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from engine.errors import DeepCError

PINHOLE_MODELS = ("PINHOLE", "SIMPLE_PINHOLE")
_MODEL_FILES = ("cameras", "images", "points3D")


@dataclasses.dataclass(eq=False)
class SparseImage:
    """One registered image of the model."""

    image_id: int
    name: str
    camera_id: int
    R: np.ndarray  # (3, 3) world -> camera
    t: np.ndarray  # (3,)


@dataclasses.dataclass(eq=False)
class SparseCamera:
    camera_id: int
    model: str
    width: int
    height: int
    params: np.ndarray

    def pinhole(self) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy) in COLMAP's continuous convention."""
        if self.model == "PINHOLE":
            fx, fy, cx, cy = self.params[:4]
        elif self.model == "SIMPLE_PINHOLE":
            f, cx, cy = self.params[:3]
            fx = fy = f
        else:
            raise ValueError(f"camera model {self.model} is not a pinhole model")
        return float(fx), float(fy), float(cx), float(cy)


@dataclasses.dataclass(eq=False)
class SparseModel:
    """A COLMAP sparse model as arrays.

    Attributes:
        path: the folder the model was read from.
        cameras: camera_id -> :class:`SparseCamera`.
        images: registered images in model order (sorted by image_id).
        points: (P, 3) float64 world positions of the 3-D points.
        track_point: (M,) int index into ``points`` for each observation.
        track_image: (M,) int index into ``images`` for each observation.
    """

    path: Path
    cameras: dict[int, SparseCamera]
    images: list[SparseImage]
    points: np.ndarray
    track_point: np.ndarray
    track_image: np.ndarray


def find_model_dir(scene_root: str | Path) -> Path:
    """The folder holding the model: ``sparse/`` or, failing that, ``sparse/0/``."""
    scene_root = Path(scene_root)
    for candidate in (scene_root / "sparse", scene_root / "sparse" / "0"):
        if all(_model_file(candidate, name) is not None for name in _MODEL_FILES):
            return candidate
    sparse = scene_root / "sparse"
    if not sparse.is_dir():
        raise DeepCError("no sparse/ folder: a scene is a COLMAP workspace with images/ and sparse/", scene_root)
    missing = [n for n in _MODEL_FILES if _model_file(sparse, n) is None]
    raise DeepCError(f"incomplete COLMAP model: no {', '.join(n + '.bin|.txt' for n in missing)} "
                     "in sparse/ or sparse/0/", sparse)


def _model_file(folder: Path, name: str) -> Path | None:
    for ext in (".bin", ".txt"):
        if (folder / f"{name}{ext}").is_file():
            return folder / f"{name}{ext}"
    return None


def read_sparse_model(model_dir: str | Path) -> SparseModel:
    """Read a COLMAP model folder through pycolmap; errors name the folder and the problem."""
    import pycolmap

    model_dir = Path(model_dir)
    try:
        rec = pycolmap.Reconstruction(str(model_dir))
    except Exception as exc:  # pycolmap maps C++ failures to assorted Python exception types
        reason = " ".join(str(exc).split()) or type(exc).__name__
        if "]" in reason[:60]:
            reason = reason.split("]", 1)[1].strip()
        raise DeepCError(f"malformed COLMAP model ({reason[:200]})", model_dir) from None

    cameras = {}
    for camera_id, cam in rec.cameras.items():
        cameras[camera_id] = SparseCamera(camera_id, cam.model.name, int(cam.width), int(cam.height),
                                          np.array(cam.params, np.float64))
    images = []
    for image_id in sorted(rec.images):
        im = rec.images[image_id]
        if not im.has_pose:
            continue
        pose = im.cam_from_world()
        images.append(SparseImage(image_id, im.name, im.camera_id, np.array(pose.rotation.matrix()),
                                  np.array(pose.translation)))
    if not images:
        raise DeepCError("the COLMAP model has no registered images", model_dir)
    image_index = {im.image_id: i for i, im in enumerate(images)}

    point_ids = sorted(rec.points3D)
    points = np.zeros((len(point_ids), 3))
    track_point, track_image = [], []
    for index, point_id in enumerate(point_ids):
        point = rec.points3D[point_id]
        points[index] = point.xyz
        for element in point.track.elements:
            if element.image_id in image_index:
                track_point.append(index)
                track_image.append(image_index[element.image_id])
    return SparseModel(model_dir, cameras, images, points,
                       np.array(track_point, np.int64), np.array(track_image, np.int64))


def undistort_workspace(scene_root: Path, model_dir: Path, cache_root: Path) -> Path:
    """Undistort a workspace with non-pinhole cameras into ``cache_root``; returns the new root.

    The result is cached under a key of the model's contents, so a second load is free. It is
    written to a temporary folder first and renamed, so an interrupted run leaves no partial cache.
    """
    import pycolmap

    digest = hashlib.sha1()
    for name in sorted(os.listdir(model_dir)):
        digest.update(name.encode())
        digest.update((model_dir / name).read_bytes() if (model_dir / name).is_file() else b"")
    target = Path(cache_root) / f"{scene_root.resolve().name}-{digest.hexdigest()[:12]}"
    if (target / "sparse").is_dir():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".undistort-", dir=target.parent))
    try:
        pycolmap.undistort_images(str(tmp), str(model_dir), str(scene_root / "images"))
        shutil.rmtree(tmp / "stereo", ignore_errors=True)
        for script in tmp.glob("run-colmap-*.sh"):
            script.unlink()
        os.replace(tmp, target)
    except (ValueError, RuntimeError, OSError) as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        raise DeepCError(f"undistortion with pycolmap failed ({' '.join(str(exc).split())[:200]})",
                         scene_root) from None
    return target
