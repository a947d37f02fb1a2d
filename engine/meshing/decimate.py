"""A mesh within a triangle budget: quadric error decimation (Garland & Heckbert 1997, open3d).

What the viewer sends to the browser (``workbench/viewer/mesh.py``): Poisson's 1.19 M triangles of sample small
are 31.6 MB and took about 60 s to show in chromium's software WebGL. Quadric decimation merges vertices where
the surface is flat first, so the shape keeps its edges; scores are taken on the whole mesh.
"""

from __future__ import annotations

import numpy as np

from engine.core.errors import DeepCError
from engine.meshing.mesh import TriangleMesh

TRIES = 6  # open3d may stop above its target: each retry aims lower by the share it overshot


def decimate(mesh: TriangleMesh, max_triangles: int) -> TriangleMesh:
    """``mesh`` with at most ``max_triangles`` triangles (itself when it has no more), colours carried per vertex
    and normals recomputed; a budget below 1, or one open3d cannot reach, is a :class:`DeepCError`."""
    if max_triangles < 1:
        raise DeepCError(f"a triangle budget must be at least 1, not {max_triangles}")
    if len(mesh) <= max_triangles:
        return mesh
    import open3d as o3d  # lazy: open3d

    source = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(mesh.vertices, np.float64)),
                                       o3d.utility.Vector3iVector(np.asarray(mesh.triangles, np.int32)))
    source.vertex_colors = o3d.utility.Vector3dVector(np.asarray(mesh.vertex_colors, np.float64) / 255.0)
    target = max_triangles
    for _ in range(TRIES):
        out = source.simplify_quadric_decimation(target_number_of_triangles=int(target))
        if len(out.triangles) <= max_triangles:
            out.remove_unreferenced_vertices()
            out.compute_vertex_normals()
            return TriangleMesh.from_open3d(out)
        target = max(1, int(target * max_triangles / len(out.triangles) * 0.95))
    raise DeepCError(f"quadric decimation did not reach {max_triangles:,} triangles "
                     f"({len(out.triangles):,} after {TRIES} tries)")
