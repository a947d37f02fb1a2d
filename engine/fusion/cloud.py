"""What fusion reads and writes: one view's maps (``FusionView``) and the fused points (``FusedCloud``)."""

from __future__ import annotations

import dataclasses
import os

import numpy as np

from engine.core.camera import Camera


@dataclasses.dataclass(eq=False)
class FusionView:
    """One view's maps for fusion, all at the depth-map resolution H x W.

    Attributes:
        camera: camera at the depth-map resolution (``camera.width == W``, ``camera.height == H``).
        depth: (H, W) float32 camera-frame z, 0 = none.
        normal: (H, W, 3) float32 unit normals in the camera frame (facing the camera).
        rgb: (H, W, 3) float32 in [0, 1] or uint8.
        confidence: (H, W) float32 in [0, 1], or None.
        overlap: indices (into the view list) of the views to search, best first (no self).
    """

    camera: Camera
    depth: np.ndarray
    normal: np.ndarray
    rgb: np.ndarray
    confidence: np.ndarray | None = None
    overlap: list[int] = dataclasses.field(default_factory=list)


@dataclasses.dataclass(eq=False)
class FusedCloud:
    """Fused points and the per-point attributes the viewer shows.

    Attributes:
        xyz: (N, 3) float64 (or float32 when read from a PLY) world positions.
        normal: (N, 3) float32 unit world normals.
        rgb: (N, 3) uint8 colours.
        num_views: (N,) int32 number of distinct views that contributed pixels (seed view included).
        mean_confidence: (N,) float32 mean confidence of the fused pixels; NaN without confidence maps.
        source_view: (N,) int32 index of the seed pixel's view (with ``point_per_pixel``: of the point's
            own pixel). ``num_views``, ``mean_confidence`` and ``num_pixels`` are always the cluster's.
        num_pixels: (N,) int32 number of fused pixels (seed included): the quantity ``min_num_pixels``
            thresholds, so masking a cloud fused with ``min_num_pixels=1`` by ``num_pixels >= m`` gives
            exactly the cloud fused with ``min_num_pixels=m``.
    """

    xyz: np.ndarray
    normal: np.ndarray
    rgb: np.ndarray
    num_views: np.ndarray
    mean_confidence: np.ndarray
    source_view: np.ndarray
    num_pixels: np.ndarray

    def __len__(self) -> int:
        return len(self.xyz)

    def subset(self, mask: np.ndarray) -> FusedCloud:
        """The points selected by a boolean mask or an index array."""
        return FusedCloud(*(np.asarray(getattr(self, f.name))[mask] for f in dataclasses.fields(self)))

    @classmethod
    def empty(cls) -> FusedCloud:
        return cls(np.zeros((0, 3)), np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8),
                   np.zeros(0, np.int32), np.zeros(0, np.float32), np.zeros(0, np.int32), np.zeros(0, np.int32))


@dataclasses.dataclass(eq=False)
class DiskCloud(FusedCloud):
    """A fused cloud that lives on disk (``engine.fusion.stream``): its attributes are read-only memory maps, ``xyz``
    (float64, as the kernel made it) of a temporary file without a name, the others of ``fused.ply``'s records. Equal,
    attribute by attribute, to the in-memory cloud of the same points; reading an attribute whole brings it into
    memory (page by page, as the file's pages), :meth:`read_xyz` reads some positions without the map.

    Attributes (besides the cloud's):
        xyz_file: the open binary file of the (N, 3) float64 positions (``engine.fusion.stream``).
        path: the PLY file (its folder also holds the positions' nameless file).
    """

    # not fields: ``subset`` and the loops over the fields see the cloud's seven arrays only
    xyz_file = None
    path = None

    def read_xyz(self, start: int, count: int) -> np.ndarray:
        """(count, 3) float64 positions of points ``start`` .. ``start + count - 1``, read from the file (not through
        the map, whose pages would stay resident)."""
        count = max(0, min(count, len(self) - start))
        data = os.pread(self.xyz_file.fileno(), count * 24, start * 24) if count else b""
        if len(data) != count * 24:
            raise OSError(f"the cloud's positions file ends at point {start + len(data) // 24} of {len(self)}")
        return np.frombuffer(data, np.float64).reshape(count, 3)
