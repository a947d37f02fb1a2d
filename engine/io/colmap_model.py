"""COLMAP sparse models, read through pycolmap (binary or text, in ``sparse/`` or ``sparse/0/``).

The model is flattened into :class:`SparseModel`: plain numpy arrays for cameras, poses, 3-D
points and their tracks, so that the rest of the engine never touches pycolmap objects.
Cameras that are not PINHOLE / SIMPLE_PINHOLE are undistorted into a cache by
``engine.io.undistort``.
"""

from __future__ import annotations

import array
import dataclasses
import os
import struct
from pathlib import Path

import numpy as np

from engine.core.errors import DeepCError

PINHOLE_MODELS = ("PINHOLE", "SIMPLE_PINHOLE")
_MODEL_FILES = ("cameras", "images", "points3D")
_MAX_IMAGE_SIDE = 1 << 20


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
    import pycolmap  # lazy: pycolmap

    model_dir = Path(model_dir)
    for name in _BINARY_CHECKS:  # pycolmap would report an unreadable file as a malformed model
        for path in (model_dir / f"{name}.bin", model_dir / f"{name}.txt"):
            if path.is_file() and not os.access(path, os.R_OK):
                raise DeepCError("cannot read: permission denied", path)
    check_binary_model(model_dir)
    try:
        rec = pycolmap.Reconstruction(str(model_dir))
    except Exception as exc:  # pycolmap maps C++ failures to assorted Python exception types
        reason = " ".join(str(exc).split()) or type(exc).__name__
        if "]" in reason[:60]:
            reason = reason.split("]", 1)[1].strip()
        raise DeepCError(f"malformed COLMAP model ({reason[:200]})", model_dir) from None

    cameras = {}
    for camera_id, cam in rec.cameras.items():
        params = np.array(cam.params, np.float64)
        sized = 0 < cam.width <= _MAX_IMAGE_SIDE and 0 < cam.height <= _MAX_IMAGE_SIDE
        if not (np.isfinite(params).all() and sized):
            raise DeepCError(f"camera {camera_id} has non-finite parameters or size {cam.width}x{cam.height}",
                             model_dir)
        cameras[camera_id] = SparseCamera(camera_id, cam.model.name, int(cam.width), int(cam.height), params)
        if cam.model.name in PINHOLE_MODELS and min(cameras[camera_id].pinhole()[:2]) <= 0:
            raise DeepCError(f"camera {camera_id} has a focal length <= 0", model_dir)
    images = []
    for image_id in sorted(rec.images):
        im = rec.images[image_id]
        if not im.has_pose:
            continue
        pose = im.cam_from_world()
        R, t = np.array(pose.rotation.matrix()), np.array(pose.translation)
        if not (np.isfinite(R).all() and np.isfinite(t).all() and abs(np.linalg.det(R) - 1) < 1e-3):
            raise DeepCError(f"image {im.name} has a non-finite or degenerate pose", model_dir)
        images.append(SparseImage(image_id, im.name, im.camera_id, R, t))
    if not images:
        raise DeepCError("the COLMAP model has no registered images", model_dir)
    image_index = {im.image_id: i for i, im in enumerate(images)}

    point_ids = sorted(rec.points3D)
    points = np.zeros((len(point_ids), 3))
    # 8 bytes an observation (lists of ints: ~70, 50 MB at 400 views of a street sequence)
    track_point, track_image = array.array("q"), array.array("q")
    for index, point_id in enumerate(point_ids):
        point = rec.points3D[point_id]
        points[index] = point.xyz
        for element in point.track.elements:
            if element.image_id in image_index:
                track_point.append(index)
                track_image.append(image_index[element.image_id])
    del rec  # pycolmap's copy of the model (its 2-D points too) goes before the arrays are made
    finite = np.isfinite(points).all(axis=1) & (np.abs(points) < 1e30).all(axis=1)
    if not finite.all():
        raise DeepCError(f"{int((~finite).sum())} 3-D points have non-finite or absurd coordinates", model_dir)
    return SparseModel(model_dir, cameras, images, points,
                       np.frombuffer(track_point, np.int64).copy(), np.frombuffer(track_image, np.int64).copy())


# ---- structural check of binary models -----------------------------------------------------------
# COLMAP's binary reader trusts every count it reads: a corrupt count makes it loop over a
# truncated stream for hours or allocate without bound (found by fuzzing). So the byte layout of
# each .bin file (src/colmap/scene/reconstruction_io_binary.cc) is walked here first, every count
# checked against the bytes that remain, before pycolmap sees the model.

# COLMAP camera model id -> number of parameters (src/colmap/sensor/models.h)
_CAMERA_PARAMS = {0: 3, 1: 4, 2: 4, 3: 5, 4: 8, 5: 8, 6: 12, 7: 5, 8: 4, 9: 5, 10: 12, 11: 16, 12: 4, 13: 5,
                  14: 3, 15: 4, 16: 6, 17: 2}
_MAX_NAME = 4096


class _BinaryCursor:
    """Reads little-endian values from a model file; any overrun is a :class:`DeepCError` naming it."""

    def __init__(self, path: Path):
        self.path = path
        try:
            self.data = path.read_bytes()
        except OSError as exc:
            raise DeepCError(f"cannot read: {exc.strerror or exc}", path) from exc
        self.pos = 0

    def need(self, size: int, what: str) -> None:
        if size < 0 or self.pos + size > len(self.data):
            raise DeepCError(f"truncated or corrupt COLMAP binary model: {what} needs {size} bytes at offset "
                             f"{self.pos}, {len(self.data) - self.pos} left", self.path)

    def unpack(self, fmt: str, what: str) -> tuple:
        size = struct.calcsize("<" + fmt)
        self.need(size, what)
        values = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return values

    def count(self, fmt: str, item_size: int, what: str) -> int:
        """A count, checked against the bytes left at ``item_size`` bytes (at least) per item."""
        (n,) = self.unpack(fmt, what)
        left = len(self.data) - self.pos
        if n < 0 or n * item_size > left:
            raise DeepCError(f"corrupt COLMAP binary model: {what} is {n}, but only {left} bytes follow", self.path)
        return n

    def floats(self, n: int, what: str) -> np.ndarray:
        self.need(8 * n, what)
        values = np.frombuffer(self.data, "<f8", n, self.pos)
        self.pos += 8 * n
        if not np.isfinite(values).all():
            raise DeepCError(f"corrupt COLMAP binary model: non-finite {what}", self.path)
        return values

    def skip(self, size: int, what: str) -> None:
        self.need(size, what)
        self.pos += size

    def name(self) -> str:
        end = self.data.find(b"\0", self.pos, self.pos + _MAX_NAME)
        if end < 0:
            raise DeepCError(f"corrupt COLMAP binary model: image name at offset {self.pos} is not terminated",
                             self.path)
        raw = self.data[self.pos:end]
        self.pos = end + 1
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise DeepCError(f"corrupt COLMAP binary model: image name {raw[:40]!r} is not UTF-8", self.path) from None

    def done(self) -> None:
        if self.pos != len(self.data):
            raise DeepCError(f"corrupt COLMAP binary model: {len(self.data) - self.pos} unexpected bytes at the end",
                             self.path)


def _check_cameras_bin(cur: _BinaryCursor) -> None:
    for _ in range(cur.count("Q", 24, "number of cameras")):
        camera_id, model_id, width, height = cur.unpack("IiQQ", "camera")
        if model_id not in _CAMERA_PARAMS:
            raise DeepCError(f"corrupt COLMAP binary model: camera {camera_id} has unknown model id {model_id}",
                             cur.path)
        if not (0 < width <= _MAX_IMAGE_SIDE and 0 < height <= _MAX_IMAGE_SIDE):
            raise DeepCError(f"corrupt COLMAP binary model: camera {camera_id} is {width}x{height}", cur.path)
        cur.floats(_CAMERA_PARAMS[model_id], f"parameters of camera {camera_id}")


def _check_images_bin(cur: _BinaryCursor) -> None:
    for _ in range(cur.count("Q", 69, "number of images")):
        (image_id,) = cur.unpack("I", "image id")
        cur.floats(7, f"pose of image {image_id}")
        cur.unpack("I", f"camera id of image {image_id}")
        cur.name()
        n_points = cur.count("Q", 24, f"number of 2-D points of image {image_id}")
        cur.skip(24 * n_points, f"2-D points of image {image_id}")


def _check_points3d_bin(cur: _BinaryCursor) -> None:
    for _ in range(cur.count("Q", 51, "number of 3-D points")):
        (point_id,) = cur.unpack("Q", "3-D point id")
        cur.floats(3, f"position of 3-D point {point_id}")
        cur.skip(3 + 8, f"colour and error of 3-D point {point_id}")
        track = cur.count("Q", 8, f"track length of 3-D point {point_id}")
        cur.skip(8 * track, f"track of 3-D point {point_id}")


def _check_rigs_bin(cur: _BinaryCursor) -> None:
    for _ in range(cur.count("Q", 8, "number of rigs")):
        rig_id, n_sensors = cur.unpack("Ii", "rig")
        if n_sensors < 0 or n_sensors * 8 > len(cur.data) - cur.pos:
            raise DeepCError(f"corrupt COLMAP binary model: rig {rig_id} has {n_sensors} sensors", cur.path)
        if n_sensors > 0:
            cur.skip(8, f"reference sensor of rig {rig_id}")
        for _ in range(max(n_sensors - 1, 0)):
            cur.skip(8, f"sensor of rig {rig_id}")
            (has_pose,) = cur.unpack("B", f"sensor pose flag of rig {rig_id}")
            if has_pose:
                cur.floats(7, f"sensor pose of rig {rig_id}")


def _check_frames_bin(cur: _BinaryCursor) -> None:
    for _ in range(cur.count("Q", 68, "number of frames")):
        frame_id, _rig_id = cur.unpack("II", "frame")
        cur.floats(7, f"pose of frame {frame_id}")
        n_data = cur.count("I", 16, f"number of data ids of frame {frame_id}")
        cur.skip(16 * n_data, f"data ids of frame {frame_id}")


_BINARY_CHECKS = {"cameras": _check_cameras_bin, "images": _check_images_bin, "points3D": _check_points3d_bin,
                  "rigs": _check_rigs_bin, "frames": _check_frames_bin}


def check_binary_model(model_dir: Path) -> None:
    """Walk the byte layout of every ``.bin`` file of a COLMAP model; raises :class:`DeepCError` on a defect."""
    if not all((model_dir / f"{name}.bin").is_file() for name in _MODEL_FILES):
        return  # pycolmap reads the text model then
    for name, check_file in _BINARY_CHECKS.items():
        path = model_dir / f"{name}.bin"
        if path.is_file():
            cursor = _BinaryCursor(path)
            check_file(cursor)
            cursor.done()
