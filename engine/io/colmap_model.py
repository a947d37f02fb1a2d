"""COLMAP sparse models (binary or text, in ``sparse/`` or ``sparse/0/``), checked and flattened.

The files are read with numpy (``engine.io.colmap_files``; pycolmap only for a model with a multi-sensor rig) into
:class:`SparseModel`: plain numpy arrays for cameras, poses, 3-D points and their tracks.
Cameras that are not PINHOLE / SIMPLE_PINHOLE are undistorted into a cache by
``engine.io.undistort``.
"""

from __future__ import annotations

import dataclasses
import os
import signal
from pathlib import Path
from types import ModuleType

import numpy as np

from engine.core.errors import DeepCError
from engine.io.colmap_files import MAX_IMAGE_SIDE, ModelFiles, read_model_files

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
    """Read and check a COLMAP model folder; errors name the file and the problem."""
    model_dir = Path(model_dir)
    for name in ("cameras", "images", "points3D", "rigs", "frames"):
        for path in (model_dir / f"{name}.bin", model_dir / f"{name}.txt"):
            if path.is_file() and not os.access(path, os.R_OK):
                raise DeepCError("cannot read: permission denied", path)
    files = read_model_files(model_dir)
    if files is None:
        files = _read_with_pycolmap(model_dir)

    cameras = {}
    for camera_id, model, width, height, params in files.cameras:
        sized = 0 < width <= MAX_IMAGE_SIDE and 0 < height <= MAX_IMAGE_SIDE
        if not (np.isfinite(params).all() and sized):
            raise DeepCError(f"camera {camera_id} has non-finite parameters or size {width}x{height}", model_dir)
        cameras[camera_id] = SparseCamera(camera_id, model, int(width), int(height), params)
        if model in PINHOLE_MODELS and min(cameras[camera_id].pinhole()[:2]) <= 0:
            raise DeepCError(f"camera {camera_id} has a focal length <= 0", model_dir)
    images = []
    for image_id, name, camera_id, qvec, tvec in sorted(files.images, key=lambda im: im[0]):
        if qvec.shape == (3, 3):  # pycolmap's matrix
            R = qvec
        else:
            # COLMAP uses a unit quaternion from the file as it is (so do we: the same matrix to the last bit)
            with np.errstate(over="ignore"):  # an absurd quaternion fails the pose check below
                norm = float(np.linalg.norm(qvec))
            R = _rotation(qvec if abs(norm - 1) < 1e-9 else qvec / norm) if norm > 0 else np.full((3, 3), np.nan)
        t = np.asarray(tvec, np.float64)
        if not (np.isfinite(R).all() and np.isfinite(t).all() and abs(np.linalg.det(R) - 1) < 1e-3):
            raise DeepCError(f"image {name} has a non-finite or degenerate pose", model_dir)
        if camera_id not in cameras:
            raise DeepCError(f"image {name} refers to camera {camera_id}, which the model does not have", model_dir)
        images.append(SparseImage(image_id, name, camera_id, R, t))
    if not images:
        raise DeepCError("the COLMAP model has no registered images", model_dir)

    order = np.argsort(files.point_ids, kind="stable")
    points = files.xyz[order]
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    # observations of registered images only, in point order (points sorted by id, as pycolmap's map iterates)
    ids = np.array([im.image_id for im in images], np.int64)
    position = np.searchsorted(ids, files.track_image)
    known = position < len(ids)
    known[known] = ids[position[known]] == files.track_image[known]
    track_point = rank[files.track_point[known]]
    track_image = position[known]
    by_point = np.argsort(track_point, kind="stable")
    finite = np.isfinite(points).all(axis=1) & (np.abs(points) < 1e30).all(axis=1)
    if not finite.all():
        raise DeepCError(f"{int((~finite).sum())} 3-D points have non-finite or absurd coordinates", model_dir)
    return SparseModel(model_dir, cameras, images, points, track_point[by_point].astype(np.int64),
                       track_image[by_point].astype(np.int64))


def _rotation(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion (w, x, y, z), COLMAP's order, with Eigen's sums and products (the
    matrix COLMAP and pycolmap make, bit for bit)."""
    w, x, y, z = q
    tx, ty, tz = 2 * x, 2 * y, 2 * z
    twx, twy, twz = tx * w, ty * w, tz * w
    txx, txy, txz = tx * x, ty * x, tz * x
    tyy, tyz, tzz = ty * y, tz * y, tz * z
    return np.array([[1 - (tyy + tzz), txy - twz, txz + twy],
                     [txy + twz, 1 - (txx + tzz), tyz - twx],
                     [txz - twy, tyz + twx, 1 - (txx + tyy)]])


def import_pycolmap() -> ModuleType:
    """pycolmap (55 MiB resident, so imported only where needed), keeping this process's SIGTERM handler: its glog
    installs one that aborts the process."""
    try:
        handler = signal.getsignal(signal.SIGTERM)
    except ValueError:
        handler = None
    import pycolmap  # lazy: pycolmap (55 MiB), only where a command needs it

    if handler is not None:
        try:
            signal.signal(signal.SIGTERM, handler)
        except ValueError:  # not the main thread: nothing of ours to keep
            pass
    return pycolmap


def _read_with_pycolmap(model_dir: Path) -> ModelFiles:
    """A model with a multi-sensor rig: pycolmap composes each image's pose from its frame and rig."""
    pycolmap = import_pycolmap()

    try:
        rec = pycolmap.Reconstruction(str(model_dir))
    except Exception as exc:  # pycolmap maps C++ failures to assorted Python exception types
        reason = " ".join(str(exc).split()) or type(exc).__name__
        if "]" in reason[:60]:
            reason = reason.split("]", 1)[1].strip()
        raise DeepCError(f"malformed COLMAP model ({reason[:200]})", model_dir) from None
    cameras = [(camera_id, cam.model.name, int(cam.width), int(cam.height), np.array(cam.params, np.float64))
               for camera_id, cam in rec.cameras.items()]
    images = []
    for image_id, im in rec.images.items():
        if im.has_pose:
            pose = im.cam_from_world()
            images.append((image_id, im.name, im.camera_id, np.array(pose.rotation.matrix()),
                           np.array(pose.translation)))
    ids = np.array(sorted(rec.points3D), np.int64)
    xyz = np.array([rec.points3D[i].xyz for i in ids], np.float64).reshape(-1, 3)
    track_point, track_image = [], []
    for index, point_id in enumerate(ids):
        for element in rec.points3D[int(point_id)].track.elements:
            track_point.append(index)
            track_image.append(element.image_id)
    return ModelFiles(cameras, images, ids, xyz, np.array(track_point, np.int64), np.array(track_image, np.int64))
