"""Synthetic ETH3D-format ground truth (laser scans of two boxes) and noisy reconstructions of it.

For tests, benchmarks and checking a build of the official evaluator.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

SYNTHETIC_BOXES = np.array([[[-1.0, -1.0, -0.02], [1.0, 1.0, 0.0]],
                            [[-0.3, -0.3, 0.0], [0.3, 0.3, 0.6]]])



def _rotation(axis_angle: np.ndarray) -> np.ndarray:
    theta = float(np.linalg.norm(axis_angle))
    if theta == 0:
        return np.eye(3)
    k = axis_angle / theta
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(theta) * Kx + (1 - math.cos(theta)) * Kx @ Kx



def _raycast_boxes(origin: np.ndarray, dirs: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """(N,) distance along unit ``dirs`` from ``origin`` to the first box hit (inf = miss)."""
    best = np.full(len(dirs), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / dirs
        for lo, hi in boxes:
            t1 = (lo - origin) * inv
            t2 = (hi - origin) * inv
            tmin = np.nanmax(np.minimum(t1, t2), axis=1)
            tmax = np.nanmin(np.maximum(t1, t2), axis=1)
            hit = (tmax >= tmin) & (tmin > 0)
            best = np.where(hit & (tmin < best), tmin, best)
    return best



def make_synthetic_eth3d(folder: str | Path, step_mrad: float = 0.8, noise: float = 0.0005, seed: int = 0,
                         scanners: tuple = ((2.2, 1.0, 1.0), (-1.9, 1.5, 1.2))) -> Path:
    """Write ETH3D-format GT for :data:`SYNTHETIC_BOXES`: one float32 scan PLY per scanner, in its own
    frame (scanner at the origin, arbitrary rotation), rays on an azimuth/inclination grid with
    ``step_mrad`` spacing (0.8 mrad = 2-3 mm at the 2.5-3.5 m ranges here) and Gaussian range
    noise, plus ``scan_alignment.mlp`` with the scan-to-global poses. Returns the .mlp path."""
    from engine.io.ply import write_ply

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    meshes = []
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-0.02, 0.6)])
    for k, centre in enumerate(np.asarray(scanners, np.float64)):
        R_gs = _rotation(rng.normal(size=3))  # scan frame -> global rotation
        local_corners = (corners - centre) @ R_gs  # R^T (c - C)
        az = np.arctan2(local_corners[:, 1], local_corners[:, 0])
        inc = np.arccos(local_corners[:, 2] / np.linalg.norm(local_corners, axis=1))
        az0 = float(np.angle(np.exp(1j * az).mean()))
        daz = float(np.max(np.abs(np.angle(np.exp(1j * (az - az0)))))) + 0.02
        step = step_mrad * 1e-3
        a = az0 + np.arange(-daz, daz, step)
        i = np.arange(max(inc.min() - 0.02, 1e-3), min(inc.max() + 0.02, np.pi - 1e-3), step)
        A, I = np.meshgrid(a, i)
        d_local = np.stack([np.sin(I) * np.cos(A), np.sin(I) * np.sin(A), np.cos(I)], axis=-1).reshape(-1, 3)
        t = _raycast_boxes(centre, d_local @ R_gs.T, SYNTHETIC_BOXES)
        hit = np.isfinite(t)
        rng_t = t[hit] + rng.normal(0.0, noise, int(hit.sum()))
        pts = (d_local[hit] * rng_t[:, None]).astype(np.float32)
        name = f"scan{k + 1}.ply"
        write_ply(folder / name, pts)
        T = np.eye(4)
        T[:3, :3] = R_gs
        T[:3, 3] = centre
        meshes.append((name, T))
    lines = ['<!DOCTYPE MeshLabDocument>', '<MeshLabProject>', ' <MeshGroup>']
    for name, T in meshes:
        lines.append(f'  <MLMesh label="{name}" filename="{name}">')
        lines.append('   <MLMatrix44>')
        lines += ["" + " ".join(f"{v:.17g}" for v in row) + " " for row in T]
        lines.append('</MLMatrix44>')
        lines.append('  </MLMesh>')
    lines += [' </MeshGroup>', ' <RasterGroup/>', '</MeshLabProject>']
    mlp = folder / "scan_alignment.mlp"
    mlp.write_text("\n".join(lines) + "\n")
    return mlp



def sample_synthetic_reconstruction(n: int, noise: float = 0.004, outlier_fraction: float = 0.03,
                                    seed: int = 0) -> np.ndarray:
    """(N, 3) float32 points for :data:`SYNTHETIC_BOXES`: the box's faces except +x (incomplete), the
    plate's top, Gaussian noise, uniform outliers in a 2.4 m cube (some in free space, some below
    the ground where no scanner looks)."""
    rng = np.random.default_rng(seed)
    n_out = int(n * outlier_fraction)
    n_surf = n - n_out
    # Faces: plate top (area 4 minus the box footprint), box -x, +y, -y (0.36 each), top (0.36).
    faces = [("z", 0.0, (-1, 1), (-1, 1)), ("x", -0.3, (-0.3, 0.3), (0, 0.6)), ("y", 0.3, (-0.3, 0.3), (0, 0.6)),
             ("y", -0.3, (-0.3, 0.3), (0, 0.6)), ("z", 0.6, (-0.3, 0.3), (-0.3, 0.3))]
    areas = np.array([4.0 - 0.36, 0.36, 0.36, 0.36, 0.36])
    counts = rng.multinomial(n_surf, areas / areas.sum())
    parts = []
    for (axis, value, (a0, a1), (b0, b1)), m in zip(faces, counts, strict=True):
        u = rng.uniform(a0, a1, m)
        v = rng.uniform(b0, b1, m)
        w = np.full(m, value)
        if axis == "z":
            p = np.stack([u, v, w], 1)
            if value == 0.0:  # plate top: drop the part under the box
                p = p[~((np.abs(u) < 0.3) & (np.abs(v) < 0.3))]
        elif axis == "x":
            p = np.stack([w, u, v], 1)
        else:
            p = np.stack([u, w, v], 1)
        parts.append(p)
    surf = np.concatenate(parts)
    surf = surf + rng.normal(0.0, noise, surf.shape)
    outliers = rng.uniform([-1.2, -1.2, -0.6], [1.2, 1.2, 1.2], (n_out, 3))
    return np.concatenate([surf, outliers]).astype(np.float32)

