"""Uniform samples of a mesh's surface, so that a mesh is scored by the same point evaluation as a cloud."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from engine.meshing.mesh import TriangleMesh

#: meshes are sampled this many times denser (linearly) than the GT points, so that gaps between samples never
#: count as missing surface at a tolerance as small as the GT's own spacing
OVERSAMPLING = 2.0


def point_spacing(points: np.ndarray, sample: int = 20000, seed: int = 0) -> float:
    """Median distance from a point to its nearest neighbour (on up to ``sample`` random points), in model units."""
    points = np.asarray(points, np.float64)
    if len(points) < 2:
        raise ValueError("point spacing needs at least two points")
    rng = np.random.default_rng(seed)
    queries = points[rng.choice(len(points), min(sample, len(points)), replace=False)]
    distance, _ = cKDTree(points).query(queries, k=2)
    return float(np.median(distance[:, 1]))


def sample_surface(mesh: TriangleMesh, spacing: float, seed: int = 0, max_points: int = 20_000_000) -> np.ndarray:
    """(N, 3) float64 points uniform over the surface, about one per ``spacing``² of area (the density of GT
    points ``spacing`` apart), at least one per mesh; triangles chosen by area, positions by uniform barycentric
    coordinates (Turk 1990), so the same seed gives the same points."""
    if spacing <= 0:
        raise ValueError("spacing must be positive")
    areas = mesh.triangle_areas()
    total = float(areas.sum())
    if total <= 0:
        return np.zeros((0, 3))
    n = int(min(max_points, max(1, round(total / spacing**2))))
    rng = np.random.default_rng(seed)
    tri = rng.choice(len(areas), n, p=areas / total)
    r1, r2 = np.sqrt(rng.random(n)), rng.random(n)
    a, b, c = (mesh.vertices[mesh.triangles[tri, k]] for k in range(3))
    return (1 - r1)[:, None] * a + (r1 * (1 - r2))[:, None] * b + (r1 * r2)[:, None] * c
