"""COLMAP sparse model files read with numpy: ``cameras``, ``images`` and ``points3D`` as ``.bin`` or ``.txt``.

The byte layouts are COLMAP's documented output format (https://colmap.github.io/format.html). Reading them here
instead of through pycolmap keeps pycolmap's ~55 MiB out of every ``deepc run`` process. COLMAP's own binary
reader trusts every count it reads: a corrupt count makes it loop over a truncated stream for hours or allocate
without bound (found by fuzzing), so every count is checked here against the bytes that remain and every defect
is a :class:`DeepCError` naming the file.

Models written since COLMAP 3.12 may describe rigs (``rigs.bin|txt``) and frames. A model whose rigs all have one
sensor (every model from a single-camera mapper) stores each image's own pose in ``images``; a model with a
multi-sensor rig is left to pycolmap (:func:`read_model_files` returns None).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from engine.core.errors import DeepCError
from engine.io.binary import ByteReader

# COLMAP camera model id -> (name, number of parameters) (src/colmap/sensor/models.h)
CAMERA_MODELS = {0: ("SIMPLE_PINHOLE", 3), 1: ("PINHOLE", 4), 2: ("SIMPLE_RADIAL", 4), 3: ("RADIAL", 5),
                 4: ("OPENCV", 8), 5: ("OPENCV_FISHEYE", 8), 6: ("FULL_OPENCV", 12), 7: ("FOV", 5),
                 8: ("SIMPLE_RADIAL_FISHEYE", 4), 9: ("RADIAL_FISHEYE", 5), 10: ("THIN_PRISM_FISHEYE", 12),
                 11: ("RAD_TAN_THIN_PRISM_FISHEYE", 16), 12: ("SIMPLE_DIVISION", 4), 13: ("DIVISION", 5),
                 14: ("SIMPLE_FISHEYE", 3), 15: ("FISHEYE", 4), 16: ("EUCM", 6), 17: ("EQUIRECTANGULAR", 2)}
PARAMS_BY_NAME = {name: n for name, n in CAMERA_MODELS.values()}
MAX_IMAGE_SIDE = 1 << 20
_MAX_NAME = 4096


@dataclasses.dataclass
class ModelFiles:
    """What the files hold, unchecked beyond their layout.

    cameras: (camera_id, model name, width, height, params (n,) f64); images: (image_id, name, camera_id,
    qvec (4,) f64 w x y z (or pycolmap's (3, 3) rotation), tvec (3,) f64) world -> camera; point_ids (P,) i64,
    xyz (P, 3) f64; track_point (M,) i64 index into the points and track_image (M,) i64 image id of each
    observation."""

    cameras: list[tuple[int, str, int, int, np.ndarray]]
    images: list[tuple[int, str, int, np.ndarray, np.ndarray]]
    point_ids: np.ndarray
    xyz: np.ndarray
    track_point: np.ndarray
    track_image: np.ndarray


def read_model_files(model_dir: Path) -> ModelFiles | None:
    """The model in ``model_dir`` (``.bin`` preferred where both exist); None for a model with a multi-sensor rig."""
    binary = all((model_dir / f"{name}.bin").is_file() for name in ("cameras", "images", "points3D"))
    if binary:
        rigs = model_dir / "rigs.bin"
        if rigs.is_file() and not _single_sensor_rigs_bin(_model_reader(rigs)):
            return None
        frames = model_dir / "frames.bin"
        if frames.is_file():
            _check_frames_bin(_model_reader(frames))
        cameras = _cameras_bin(_model_reader(model_dir / "cameras.bin"))
        images = _images_bin(_model_reader(model_dir / "images.bin"))
        points = _points_bin(_model_reader(model_dir / "points3D.bin"))
    else:
        rigs = model_dir / "rigs.txt"
        if rigs.is_file() and not _single_sensor_rigs_txt(rigs):
            return None
        cameras = _cameras_txt(model_dir / "cameras.txt")
        images = _images_txt(model_dir / "images.txt")
        points = _points_txt(model_dir / "points3D.txt")
    return ModelFiles(cameras, images, *points)


# ---- binary --------------------------------------------------------------------------------------

def _model_reader(path: Path) -> ByteReader:
    return ByteReader.from_file(path, "COLMAP binary model")


def _cameras_bin(cur: ByteReader) -> list:
    cameras = []
    for _ in range(cur.count("Q", 24, "number of cameras")):
        camera_id, model_id, width, height = cur.unpack("IiQQ", "camera")
        if model_id not in CAMERA_MODELS:
            raise cur.error(f"camera {camera_id} has unknown model id {model_id}")
        if not (0 < width <= MAX_IMAGE_SIDE and 0 < height <= MAX_IMAGE_SIDE):
            raise cur.error(f"camera {camera_id} is {width}x{height}")
        name, n_params = CAMERA_MODELS[model_id]
        cameras.append((camera_id, name, width, height, cur.floats(n_params, f"parameters of camera {camera_id}")))
    cur.done()
    return cameras


def _images_bin(cur: ByteReader) -> list:
    images = []
    for _ in range(cur.count("Q", 69, "number of images")):
        (image_id,) = cur.unpack("I", "image id")
        pose = cur.floats(7, f"pose of image {image_id}")
        (camera_id,) = cur.unpack("I", f"camera id of image {image_id}")
        name = cur.c_string("image name", _MAX_NAME)
        n_points = cur.count("Q", 24, f"number of 2-D points of image {image_id}")
        cur.skip(24 * n_points, f"2-D points of image {image_id}")
        images.append((image_id, name, camera_id, pose[:4], pose[4:]))
    cur.done()
    return images


def _points_bin(cur: ByteReader) -> tuple[np.ndarray, ...]:
    n = cur.count("Q", 51, "number of 3-D points")
    ids = np.empty(n, np.int64)
    xyz = np.empty((n, 3))
    tracks = []
    for i in range(n):
        (ids[i],) = cur.unpack("Q", "3-D point id")
        xyz[i] = cur.floats(3, f"position of 3-D point {ids[i]}")
        cur.skip(3 + 8, f"colour and error of 3-D point {ids[i]}")
        length = cur.count("Q", 8, f"track length of 3-D point {ids[i]}")
        tracks.append(cur.array("<u4", (2 * length,), f"track of 3-D point {ids[i]}")[0::2])  # (image id, 2-D index)
    cur.done()
    lengths = np.array([len(t) for t in tracks], np.int64)
    track_image = np.concatenate(tracks).astype(np.int64) if tracks else np.zeros(0, np.int64)
    return ids, xyz, np.repeat(np.arange(n, dtype=np.int64), lengths), track_image


def _single_sensor_rigs_bin(cur: ByteReader) -> bool:
    single = True
    for _ in range(cur.count("Q", 8, "number of rigs")):
        rig_id, n_sensors = cur.unpack("Ii", "rig")
        if n_sensors < 0 or n_sensors * 8 > cur.left:
            raise cur.error(f"rig {rig_id} has {n_sensors} sensors")
        single &= n_sensors <= 1
        if n_sensors > 0:
            cur.skip(8, f"reference sensor of rig {rig_id}")
        for _ in range(max(n_sensors - 1, 0)):
            cur.skip(8, f"sensor of rig {rig_id}")
            (has_pose,) = cur.unpack("B", f"sensor pose flag of rig {rig_id}")
            if has_pose:
                cur.floats(7, f"sensor pose of rig {rig_id}")
    cur.done()
    return single


def _check_frames_bin(cur: ByteReader) -> None:
    for _ in range(cur.count("Q", 68, "number of frames")):
        frame_id, _rig_id = cur.unpack("II", "frame")
        cur.floats(7, f"pose of frame {frame_id}")
        n_data = cur.count("I", 16, f"number of data ids of frame {frame_id}")
        cur.skip(16 * n_data, f"data ids of frame {frame_id}")
    cur.done()


# ---- text ----------------------------------------------------------------------------------------

def _lines(path: Path) -> list[str]:
    try:
        return path.read_text(encoding="utf-8").splitlines()
    except OSError as exc:
        raise DeepCError(f"cannot read: {exc.strerror or exc}", path) from exc
    except UnicodeDecodeError:
        raise DeepCError("malformed COLMAP model: not UTF-8 text", path) from None


def _malformed(path: Path, number: int, what: str) -> DeepCError:
    return DeepCError(f"malformed COLMAP model: line {number + 1}: {what}", path)


def _numbers(path: Path, number: int, words: list[str], what: str) -> np.ndarray:
    try:
        values = np.array([float(w) for w in words], np.float64)
    except ValueError:
        raise _malformed(path, number, f"{what} is not a list of numbers") from None
    if not np.isfinite(values).all():
        raise _malformed(path, number, f"non-finite {what}")
    return values


def _cameras_txt(path: Path) -> list:
    cameras = []
    for number, line in enumerate(_lines(path)):
        words = line.split()
        if not words or words[0].startswith("#"):
            continue
        if len(words) < 4 or words[1] not in PARAMS_BY_NAME:
            raise _malformed(path, number, "expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[] with a COLMAP model name")
        try:
            camera_id, width, height = int(words[0]), int(words[2]), int(words[3])
        except ValueError:
            raise _malformed(path, number, "camera id, width and height must be integers") from None
        params = _numbers(path, number, words[4:], f"parameters of camera {camera_id}")
        if len(params) != PARAMS_BY_NAME[words[1]]:
            raise _malformed(path, number, f"{words[1]} takes {PARAMS_BY_NAME[words[1]]} parameters, not {len(params)}")
        cameras.append((camera_id, words[1], width, height, params))
    return cameras


def _images_txt(path: Path) -> list:
    images = []
    lines = _lines(path)
    number = 0
    while number < len(lines):
        words = lines[number].split()
        if not words or words[0].startswith("#"):
            number += 1
            continue
        if len(words) < 10:
            raise _malformed(path, number, "expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME")
        try:
            image_id, camera_id = int(words[0]), int(words[8])
        except ValueError:
            raise _malformed(path, number, "image and camera ids must be integers") from None
        pose = _numbers(path, number, words[1:8], f"pose of image {image_id}")
        # the name is the rest of the line (it may hold spaces); the next line holds its 2-D points
        name = lines[number].strip().split(None, 9)[9]
        images.append((image_id, name, camera_id, pose[:4], pose[4:]))
        number += 2
    return images


def _points_txt(path: Path) -> tuple[np.ndarray, ...]:
    ids, xyz, lengths, track_image = [], [], [], []
    for number, line in enumerate(_lines(path)):
        words = line.split()
        if not words or words[0].startswith("#"):
            continue
        if len(words) < 8 or (len(words) - 8) % 2:
            raise _malformed(path, number, "expected POINT3D_ID X Y Z R G B ERROR TRACK[] as (IMAGE_ID, POINT2D_IDX)")
        try:
            ids.append(int(words[0]))
            track = [int(w) for w in words[8::2]]
        except ValueError:
            raise _malformed(path, number, "point and image ids must be integers") from None
        xyz.append(_numbers(path, number, words[1:4], f"position of 3-D point {words[0]}"))
        lengths.append(len(track))
        track_image.extend(track)
    n = len(ids)
    return (np.array(ids, np.int64), np.array(xyz, np.float64).reshape(n, 3),
            np.repeat(np.arange(n, dtype=np.int64), np.array(lengths, np.int64)), np.array(track_image, np.int64))


def _single_sensor_rigs_txt(path: Path) -> bool:
    for number, line in enumerate(_lines(path)):
        words = line.split()
        if not words or words[0].startswith("#"):
            continue
        if len(words) < 2 or not words[1].lstrip("-").isdigit():
            raise _malformed(path, number, "expected RIG_ID NUM_SENSORS ...")
        if int(words[1]) > 1:
            return False
    return True
