"""A triangle mesh (``TriangleMesh``), written as a binary PLY and read back from any format open3d reads."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from engine.core.errors import DeepCError
from engine.io.atomic import atomic_write


@dataclasses.dataclass(eq=False)
class TriangleMesh:
    """Vertices and triangles in world coordinates.

    Attributes:
        vertices: (V, 3) float64 positions.
        triangles: (F, 3) int32 vertex indices, counter-clockwise seen from outside.
        vertex_normals: (V, 3) float32 unit normals, or zeros where unknown.
        vertex_colors: (V, 3) uint8 colours.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    vertex_normals: np.ndarray
    vertex_colors: np.ndarray

    def __len__(self) -> int:
        return len(self.triangles)

    def triangle_areas(self) -> np.ndarray:
        """(F,) float64 area of every triangle."""
        a, b, c = (self.vertices[self.triangles[:, k]] for k in range(3))
        return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)

    @classmethod
    def from_open3d(cls, mesh) -> TriangleMesh:
        vertices = np.asarray(mesh.vertices, np.float64)
        normals = np.asarray(mesh.vertex_normals, np.float32) if mesh.has_vertex_normals() else \
            np.zeros_like(vertices, np.float32)
        colors = np.asarray(mesh.vertex_colors) if mesh.has_vertex_colors() else np.full_like(vertices, 0.7)
        return cls(vertices, np.asarray(mesh.triangles, np.int32).reshape(-1, 3), normals,
                   np.clip(np.rint(colors * 255), 0, 255).astype(np.uint8))


def write_mesh_ply(path: str | Path, mesh: TriangleMesh) -> Path:
    """Binary little-endian PLY (float32 positions and normals, uchar colours, int32 faces), written atomically."""
    path = Path(path)
    v = np.zeros(len(mesh.vertices), [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("nx", "<f4"), ("ny", "<f4"),
                                      ("nz", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    for k, name in enumerate("xyz"):
        v[name] = mesh.vertices[:, k]
        v["n" + name] = mesh.vertex_normals[:, k]
    for k, name in enumerate(("red", "green", "blue")):
        v[name] = mesh.vertex_colors[:, k]
    f = np.zeros(len(mesh.triangles), [("n", "u1"), ("i", "<i4", (3,))])
    f["n"], f["i"] = 3, mesh.triangles
    header = (f"ply\nformat binary_little_endian 1.0\ncomment deepc mesh\nelement vertex {len(v)}\n"
              + "".join(f"property {'float' if t[1] == '<f4' else 'uchar'} {t[0]}\n" for t in v.dtype.descr)
              + f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n")
    with atomic_write(path) as handle:
        handle.write(header.encode("ascii"))
        handle.write(v.tobytes())
        handle.write(f.tobytes())
    return path


def read_mesh(path: str | Path) -> TriangleMesh:
    """A mesh file (PLY, OBJ, OFF, ... as open3d reads them); a missing file or one without triangles is a
    :class:`DeepCError` naming it."""
    import open3d as o3d  # lazy: open3d

    path = Path(path)
    if not path.is_file():
        raise DeepCError("mesh file not found", path)
    mesh = o3d.io.read_triangle_mesh(str(path), print_progress=False)
    if len(mesh.triangles) == 0:
        raise DeepCError("no triangles in this file (not a mesh, or an empty one)", path)
    return TriangleMesh.from_open3d(mesh)
