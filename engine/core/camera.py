"""Pinhole cameras in one pixel-centre convention (Schönberger et al. 2016).

``Camera.K`` is COLMAP's *continuous* calibration: the centre of pixel (col, row) lies at image
coordinate (col + 0.5, row + 0.5). All per-pixel geometry of the engine uses the *index-space*
matrix ``Camera.K_idx`` (cx - 0.5, cy - 0.5), so that integer (col, row) plug straight in. The
conversion happens here, once; nothing else adds or subtracts half pixels.

Poses follow COLMAP: ``X_cam = R @ X_world + t``; the camera centre is ``-R.T @ t``. Depth is the
camera-frame z coordinate, not the ray length.
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated, posed pinhole camera.

    Attributes:
        width, height: image size in pixels.
        K: (3, 3) float64 continuous intrinsics (pixel centres at +0.5).
        R: (3, 3) float64 world-to-camera rotation.
        t: (3,) float64 world-to-camera translation.
    """

    width: int
    height: int
    K: np.ndarray
    R: np.ndarray
    t: np.ndarray

    def __post_init__(self) -> None:
        for name in ("K", "R", "t"):
            value = np.array(getattr(self, name), dtype=np.float64)
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    @classmethod
    def from_params(cls, width: int, height: int, fx: float, fy: float, cx: float, cy: float,
                    R: np.ndarray | None = None, t: np.ndarray | None = None) -> Camera:
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        return cls(int(width), int(height), K, np.eye(3) if R is None else R, np.zeros(3) if t is None else t)

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def K_idx(self) -> np.ndarray:
        """(3, 3) index-space intrinsics: pixel (col, row) has its centre at (col, row)."""
        K = self.K.copy()
        K[0, 2] -= 0.5
        K[1, 2] -= 0.5
        return K

    @property
    def center(self) -> np.ndarray:
        """(3,) camera centre in world coordinates."""
        return -self.R.T @ self.t

    @property
    def size(self) -> tuple[int, int]:
        """(width, height)."""
        return self.width, self.height

    def rescaled(self, width: int, height: int) -> Camera:
        """The same camera for an image resized to (width, height); exact intrinsics.

        With s_x = width / self.width and s_y = height / self.height, the continuous intrinsics scale
        as fx·s_x, cx·s_x, fy·s_y, cy·s_y (pixel-area-aligned resampling).
        """
        sx, sy = width / self.width, height / self.height
        K = self.K.copy()
        K[0, :] *= sx
        K[1, :] *= sy
        return Camera(int(width), int(height), K, self.R, self.t)

    def world_to_camera(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) world points -> (..., 3) camera-frame points."""
        return np.asarray(points, np.float64) @ self.R.T + self.t

    def camera_to_world(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) camera-frame points -> (..., 3) world points."""
        return (np.asarray(points, np.float64) - self.t) @ self.R

    def project(self, points_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project (N, 3) world points; returns index-space (N, 2) (col, row) and (N,) depth z.

        Points with z <= 0 get NaN coordinates.
        """
        X = self.world_to_camera(points_world)
        z = X[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = (X @ self.K_idx.T)[..., :2] / z[..., None]
        uv[z <= 0] = np.nan
        return uv, z

    def pixel_rays(self) -> np.ndarray:
        """(H, W, 3) float64 camera-frame rays K_idx^-1 [col, row, 1] (z component 1)."""
        cols, rows = np.meshgrid(np.arange(self.width), np.arange(self.height))
        Ki = np.linalg.inv(self.K_idx)
        pix = np.stack([cols, rows, np.ones_like(cols)], axis=-1).astype(np.float64)
        return pix @ Ki.T

    def backproject(self, depth: np.ndarray) -> np.ndarray:
        """(H, W) depth (z, 0 = none) -> (H, W, 3) world points (NaN where depth <= 0)."""
        if depth.shape != (self.height, self.width):
            raise ValueError(f"depth shape {depth.shape} does not match camera {self.height}x{self.width}")
        X = self.pixel_rays() * depth[..., None]
        world = self.camera_to_world(X)
        world[depth <= 0] = np.nan
        return world

    def to_dict(self) -> dict:
        return {"width": self.width, "height": self.height, "K": self.K.tolist(),
                "R": self.R.tolist(), "t": self.t.tolist()}


def rescaled_size(width: int, height: int, max_image_size: int) -> tuple[int, int]:
    """Size after limiting the longer side to ``max_image_size`` (0 = keep); never upscales."""
    longest = max(width, height)
    if max_image_size <= 0 or longest <= max_image_size:
        return width, height
    scale = max_image_size / longest
    return max(1, int(round(width * scale))), max(1, int(round(height * scale)))
