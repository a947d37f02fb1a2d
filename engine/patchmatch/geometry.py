"""Per-hypothesis geometry as small numba functions: plane-induced homographies and plane propagation (Xu & Tao
2019 ACMM; Kuhn et al. 2020 DeepC-MVS), random and perturbed normals (Schönberger et al. 2016 COLMAP) and the
forward-backward reprojection error of the geometric consistency term (ACMM).

Conventions: index-space intrinsics (pixel (col, row) centre at (col, row)); a hypothesis at pixel p
is (z, n): camera-frame depth z and unit normal n facing the camera (n · r_p < 0), with
r_p = K⁻¹ [x, y, 1]ᵀ. The plane is nᵀX + d = 0 with d = -z n·r_p > 0.

Relative geometry ref -> source j (precomputed once per reference view and level, float64):
    A_j = K_j R_rel K_r⁻¹ (9,), b_j = K_j t_rel (3,)  so that  x̃_j ~ z A_j p̃ + b_j,
    B_j = K_r R_relᵀ K_j⁻¹ (9,), c_j = -K_r R_relᵀ t_rel (3,)  so that  p̃' ~ z_j B_j x̃_j + c_j,
and the plane-induced homography is H_j = A_j - b_j mᵀ with m = K_r⁻ᵀ n / d.
The kernels take them packed per source as one (N, GEO_COLS) float64 array (:func:`pack_geometry`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from engine.core.camera import Camera
from engine.patchmatch.rng import uniform

# columns of the packed geometry: A_j, b_j, B_j, c_j, then the source's width and height (px)
GEO_A, GEO_B, GEO_BB, GEO_C, GEO_W, GEO_H = 0, 9, 12, 21, 24, 25
GEO_COLS = 26


def pack_geometry(rel: dict[str, np.ndarray], sizes: np.ndarray) -> np.ndarray:
    """(N, GEO_COLS) float64: ``rel``'s A, b, B, c (:func:`relative_geometry`) and ``sizes`` (N, 2) (W, H)
    of each source, one row per source (one array argument instead of five)."""
    return np.ascontiguousarray(np.concatenate([rel["A"], rel["b"], rel["B"], rel["c"],
                                                np.asarray(sizes, np.float64).reshape(-1, 2)], axis=1))


def relative_geometry(ref: Camera, sources: list[Camera]) -> dict[str, np.ndarray]:
    """Precomputed ref -> source matrices (see module doc), all float64.

    Returns a dict with ``kinv`` (9,), ``kref`` (9,), ``A`` (N, 9), ``b`` (N, 3), ``B`` (N, 9),
    ``c`` (N, 3) and ``centers`` (N, 3): source camera centres in the reference camera frame.
    """
    Kr = ref.K_idx
    Kri = np.linalg.inv(Kr)
    n = len(sources)
    A = np.zeros((n, 9))
    b = np.zeros((n, 3))
    B = np.zeros((n, 9))
    c = np.zeros((n, 3))
    centers = np.zeros((n, 3))
    for j, src in enumerate(sources):
        R_rel = src.R @ ref.R.T
        t_rel = src.t - R_rel @ ref.t
        Kj = src.K_idx
        A[j] = (Kj @ R_rel @ Kri).ravel()
        b[j] = Kj @ t_rel
        B[j] = (Kr @ R_rel.T @ np.linalg.inv(Kj)).ravel()
        c[j] = -Kr @ R_rel.T @ t_rel
        centers[j] = -R_rel.T @ t_rel
    return {"kinv": Kri.ravel().copy(), "kref": Kr.ravel().copy(), "A": A, "b": b, "B": B, "c": c,
            "centers": centers}


@njit(cache=True, inline="always")
def ray(kinv: np.ndarray, x: float, y: float) -> tuple[float, float, float]:
    """Viewing ray K⁻¹ [x, y, 1]ᵀ (z component 1 for a zero-skew K)."""
    return (kinv[0] * x + kinv[1] * y + kinv[2],
            kinv[3] * x + kinv[4] * y + kinv[5],
            kinv[6] * x + kinv[7] * y + kinv[8])


@njit(cache=True, inline="always")
def propagate_depth(zq: float, nx: float, ny: float, nz: float, rq: tuple, rp: tuple, plane: bool) -> float:
    """Depth at p of the plane through q's hypothesis (plane-based depth propagation, Kuhn et al. 2020
    DeepC-MVS); raw z_q when ``plane`` is False or when the ray of p is (nearly) parallel to the plane."""
    if not plane:
        return zq
    den = nx * rp[0] + ny * rp[1] + nz * rp[2]
    if abs(den) < 1e-5:
        return zq
    return zq * (nx * rq[0] + ny * rq[1] + nz * rq[2]) / den


@njit(cache=True, inline="always")
def plane_vector(kinv: np.ndarray, rp: tuple, z: float, nx: float, ny: float, nz: float) -> tuple:
    """m = K⁻ᵀ n / d for the homography H = A - b mᵀ; d = -z n·r_p. Returns (m0, m1, m2, ok)."""
    d = -z * (nx * rp[0] + ny * rp[1] + nz * rp[2])
    if d <= 1e-12:
        return 0.0, 0.0, 0.0, False
    inv = 1.0 / d
    m0 = (kinv[0] * nx + kinv[3] * ny + kinv[6] * nz) * inv
    m1 = (kinv[1] * nx + kinv[4] * ny + kinv[7] * nz) * inv
    m2 = (kinv[2] * nx + kinv[5] * ny + kinv[8] * nz) * inv
    return m0, m1, m2, True


@njit(cache=True)
def random_normal(key: np.uint64, draw: int, rp: tuple) -> tuple:
    """Marsaglia sphere sample turned to face the camera (the random normals of ACMM and COLMAP).

    Uses draws ``draw, draw+1, ...`` of the stream; returns (nx, ny, nz, next_draw)."""
    q1 = 0.0
    q2 = 0.0
    s = 2.0
    while s >= 1.0:
        q1 = 2.0 * uniform(key, draw) - 1.0
        q2 = 2.0 * uniform(key, draw + 1) - 1.0
        draw += 2
        s = q1 * q1 + q2 * q2
    f = 2.0 * math.sqrt(1.0 - s)
    nx = q1 * f
    ny = q2 * f
    nz = 1.0 - 2.0 * s
    if nx * rp[0] + ny * rp[1] + nz * rp[2] > 0.0:
        nx, ny, nz = -nx, -ny, -nz
    return nx, ny, nz, draw


@njit(cache=True)
def perturb_normal(key: np.uint64, draw: int, rp: tuple, nx: float, ny: float, nz: float,
                   eps: float, retries: int) -> tuple:
    """COLMAP PerturbNormal (Schönberger et al. 2016): random rotation with angles in ±eps·π/2; halve the range
    and retry while the result faces away, then fall back to n. Returns (nx, ny, nz, next_draw)."""
    scale = eps * math.pi
    for _ in range(retries + 1):
        a1 = (uniform(key, draw) - 0.5) * scale
        a2 = (uniform(key, draw + 1) - 0.5) * scale
        a3 = (uniform(key, draw + 2) - 0.5) * scale
        draw += 3
        c1, s1 = math.cos(a1), math.sin(a1)
        c2, s2 = math.cos(a2), math.sin(a2)
        c3, s3 = math.cos(a3), math.sin(a3)
        # R = Rx(a1) Ry(a2) Rz(a3), applied to n
        x1 = c3 * nx - s3 * ny
        y1 = s3 * nx + c3 * ny
        z1 = nz
        x2 = c2 * x1 + s2 * z1
        y2 = y1
        z2 = -s2 * x1 + c2 * z1
        x3 = x2
        y3 = c1 * y2 - s1 * z2
        z3 = s1 * y2 + c1 * z2
        if x3 * rp[0] + y3 * rp[1] + z3 * rp[2] < 0.0:
            inv = 1.0 / math.sqrt(x3 * x3 + y3 * y3 + z3 * z3)
            return x3 * inv, y3 * inv, z3 * inv, draw
        scale *= 0.5
    return nx, ny, nz, draw


@njit(cache=True, inline="always")
def reprojection(geo: np.ndarray, j: int, depth: np.ndarray, x: float, y: float, z: float) -> tuple[float, float]:
    """Forward-backward reprojection of depth z at ref pixel (x, y) via source j (ACMM's geometric
    consistency; the counter map of Kuhn et al. 2020): (error px, depth of the point reprojected from source j
    in the reference camera).

    ``geo`` is the packed geometry (:func:`pack_geometry`), ``depth`` (N, Hm, Wm) the source depth maps.
    The source depth is read at the nearest pixel of the projection; the error is -1 when the point
    projects behind or outside source j or the source has no depth there."""
    X0 = z * (geo[j, GEO_A] * x + geo[j, GEO_A + 1] * y + geo[j, GEO_A + 2]) + geo[j, GEO_B]
    X1 = z * (geo[j, GEO_A + 3] * x + geo[j, GEO_A + 4] * y + geo[j, GEO_A + 5]) + geo[j, GEO_B + 1]
    X2 = z * (geo[j, GEO_A + 6] * x + geo[j, GEO_A + 7] * y + geo[j, GEO_A + 8]) + geo[j, GEO_B + 2]
    if X2 <= 0.0:
        return -1.0, 0.0
    u = X0 / X2
    v = X1 / X2
    iu = int(math.floor(u + 0.5))
    iv = int(math.floor(v + 0.5))
    if iu < 0 or iv < 0 or iu >= int(geo[j, GEO_W]) or iv >= int(geo[j, GEO_H]):
        return -1.0, 0.0
    zs = depth[j, iv, iu]
    if zs <= 0.0:
        return -1.0, 0.0
    Y0 = zs * (geo[j, GEO_BB] * u + geo[j, GEO_BB + 1] * v + geo[j, GEO_BB + 2]) + geo[j, GEO_C]
    Y1 = zs * (geo[j, GEO_BB + 3] * u + geo[j, GEO_BB + 4] * v + geo[j, GEO_BB + 5]) + geo[j, GEO_C + 1]
    Y2 = zs * (geo[j, GEO_BB + 6] * u + geo[j, GEO_BB + 7] * v + geo[j, GEO_BB + 8]) + geo[j, GEO_C + 2]
    if Y2 <= 0.0:
        return -1.0, 0.0
    dx = Y0 / Y2 - x
    dy = Y1 / Y2 - y
    return math.sqrt(dx * dx + dy * dy), Y2


@njit(cache=True, inline="always")
def reprojection_error(geo: np.ndarray, j: int, depth: np.ndarray, x: float, y: float, z: float) -> float:
    """The error (px) of :func:`reprojection` (-1 where unavailable)."""
    return reprojection(geo, j, depth, x, y, z)[0]
