"""A mesh within a triangle budget for display: vertex clustering (Rossignac & Borrel 1993, open3d).

What the viewer sends to the browser (``workbench/viewer/mesh.py``): Poisson's 1.27 M triangles of sample small
are 31.6 MB and took about 60 s to show in chromium's software WebGL. Vertex clustering merges every vertex of a
grid cell into their mean and drops the triangles that collapse: one linear pass where quadric error decimation
takes seconds per hundred thousand triangles (docs/decisions.md, bench_viewer_budget_quadric.json), so a mesh
shows within seconds of being asked for. Its surface is the cell size coarser than the mesh; scores are taken on
the whole mesh.
"""

from __future__ import annotations

import numpy as np

from engine.core.errors import DeepCError
from engine.meshing.mesh import TriangleMesh

TRIES = 6  # cell sizes tried: each later one is scaled by the square root of the share it missed by
FILL = 0.9  # a first cell size aims at this share of the budget (a mesh's triangle count goes as 1 / cell²)


AREA_SAMPLE = 100_000  # triangles whose areas estimate a larger mesh's (every k-th: a first cell size needs no more)


def surface_area(mesh: TriangleMesh, sample: int | None = None) -> float:
    """Total area of ``mesh``'s triangles (the vertices' unit squared); with ``sample``, estimated from every k-th
    triangle, k the smallest stride that keeps at most ``sample`` of them."""
    v = np.asarray(mesh.vertices, np.float64)
    t = np.asarray(mesh.triangles, np.int64)
    stride = 1 if sample is None else max(1, -(-len(t) // sample))
    t = t[::stride]
    return stride * float(0.5 * np.linalg.norm(np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]),
                                               axis=1).sum())


def decimate(mesh: TriangleMesh, max_triangles: int) -> TriangleMesh:
    """``mesh`` with at most ``max_triangles`` triangles (itself when it has no more), by vertex clustering on a
    grid whose cell is sized to the budget; colours averaged per cell, normals recomputed. A budget below 1, or
    one no cell size tried reaches, is a :class:`DeepCError`.

    Parameters
    ----------
    mesh : TriangleMesh
        Vertices ``(V, 3)`` in scene units, triangles ``(T, 3)``.
    max_triangles : int
        Most triangles of the result.
    """
    if max_triangles < 1:
        raise DeepCError(f"a triangle budget must be at least 1, not {max_triangles}")
    if len(mesh) <= max_triangles:
        return mesh
    import open3d as o3d  # lazy: open3d

    source = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(mesh.vertices, np.float64)),
                                       o3d.utility.Vector3iVector(np.asarray(mesh.triangles, np.int32)))
    source.vertex_colors = o3d.utility.Vector3dVector(np.asarray(mesh.vertex_colors, np.float64) / 255.0)
    # a surface of area A on a grid of cell c has about A / c² cells, each giving about two triangles
    cell = np.sqrt(2.0 * max(surface_area(mesh, AREA_SAMPLE), 1e-30) / (FILL * max_triangles))
    count = 0
    for _ in range(TRIES):
        out = source.simplify_vertex_clustering(voxel_size=float(cell),
                                                contraction=o3d.geometry.SimplificationContraction.Average)
        count = len(out.triangles)
        if 0 < count <= max_triangles:
            out.remove_unreferenced_vertices()
            out.compute_vertex_normals()
            return TriangleMesh.from_open3d(out)
        # too many: larger cells; none (a budget below the mesh's coarsest grid): smaller ones
        cell *= np.sqrt(count / (FILL * max_triangles)) if count else 0.5
    raise DeepCError(f"vertex clustering did not reach {max_triangles:,} triangles ({count:,} after {TRIES} tries)")
