"""ETH3D-style evaluation of a point cloud: accuracy, completeness and F1 per tolerance (SPEC.md §9.1).

Two ground-truth forms:

- ``evaluate_points``: GT surface points (e.g. ``SCENE/ground_truth/points.ply``). A reconstructed
  point is *accurate* at tolerance t if a GT point lies within t. Without GT views every other point
  is *inaccurate*. With GT views (camera, GT depth map) the unobserved-space rule applies: a point
  that is not accurate counts as inaccurate only if some GT view sees it more than t in front of
  the GT surface (observed free space); otherwise it is *unobserved* and ignored, as in ETH3D.
- ``evaluate_eth3d``: ETH3D's own format, a MeshLab project (``scan_alignment.mlp``) listing laser
  scans stored in their scanners' frames. Accuracy follows the official program's beam model
  (``ETH3D/multi-view-evaluation`` ``src/accuracy.cc``): a scan ray "sees" a point if it passes within
  the beam radius ``b0 + r tan(half_angle)``; accurate if that scan point is within t, inaccurate if the
  point lies in front of it, unobserved otherwise; scans combine by "accurate in any, else inaccurate
  in any".

Completeness (both forms): a GT point is complete at t if a reconstructed point lies within t.
Every score is a mean over occupied voxels of two grids (cell ``floor(p / voxel + shift)``, shifts 0
and 0.5 voxel), each voxel weighted equally, which cancels point density. Accuracy skips voxels
without classified points. F1 = 2 A C / (A + C), 0 when both are 0. All scores are percentages.
"""

from __future__ import annotations

import dataclasses
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numba
import numpy as np
from scipy.spatial import cKDTree

from engine.camera import Camera
from engine.errors import DeepCError
from engine.io.ply import read_points
from engine.options import Options, check, option

_GRID_SHIFTS = (0.0, 0.5)


@dataclasses.dataclass
class EvaluationOptions(Options):
    """ETH3D evaluation parameters (SPEC.md §12 ``eval``); lengths in model units (metres for ETH3D)."""

    tolerances: tuple[float, ...] = option((0.01, 0.02, 0.05, 0.1, 0.2, 0.5), "distance tolerances",
                                           metavar="T1,T2,...")
    voxel_size: float = option(0.01, "voxel size of the two density-normalising grids", metavar="LENGTH")
    beam_start_radius: float = option(0.001125, "ETH3D scanner beam radius at the scanner", metavar="LENGTH")
    beam_divergence_halfangle_deg: float = option(0.011, "ETH3D scanner beam divergence half-angle",
                                                  metavar="DEGREES")

    def validate(self) -> EvaluationOptions:
        super().validate()
        tol = tuple(self.tolerances)
        check(len(tol) > 0, "tolerances", tol, "give at least one tolerance")
        check(all(isinstance(t, (int, float)) and math.isfinite(t) and t > 0 for t in tol), "tolerances", tol,
              "every tolerance must be a positive finite number")
        check(math.isfinite(self.voxel_size) and self.voxel_size > 0, "voxel_size", self.voxel_size,
              "must be positive")
        check(self.beam_start_radius >= 0, "beam_start_radius", self.beam_start_radius, "must be >= 0")
        check(0 <= self.beam_divergence_halfangle_deg < 90, "beam_divergence_halfangle_deg",
              self.beam_divergence_halfangle_deg, "must be in [0, 90)")
        return self

    def sorted_tolerances(self) -> np.ndarray:
        return np.array(sorted(set(float(t) for t in self.tolerances)), np.float64)


def parse_tolerances(text: str) -> tuple[float, ...]:
    """'0.01,0.02' -> (0.01, 0.02); a clear error for anything else."""
    from engine.errors import OptionsError

    parts = [p.strip() for p in str(text).split(",") if p.strip()]
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        raise OptionsError(f"option tolerances={text!r}: not a comma-separated list of numbers") from None
    EvaluationOptions(tolerances=values).validate()
    return values


@dataclasses.dataclass
class EvaluationResult:
    """Scores per tolerance (percent, 0-100), tolerances ascending.

    Attributes:
        tolerances, accuracy, completeness, f1: lists of equal length.
        num_reconstruction, num_ground_truth: point counts used.
        unobserved: per tolerance, the percentage of reconstructed points that were neither accurate
            nor inaccurate (ignored by accuracy).
        notes: one-line explanations of degenerate results (empty cloud, no overlap, ...).
    """

    tolerances: list[float]
    accuracy: list[float]
    completeness: list[float]
    f1: list[float]
    num_reconstruction: int = 0
    num_ground_truth: int = 0
    unobserved: list[float] = dataclasses.field(default_factory=list)
    notes: list[str] = dataclasses.field(default_factory=list)

    def to_dict(self) -> dict[str, list[float]]:
        """The CONTRACT.md §5 ``eval`` block."""
        return {"tolerances": list(self.tolerances), "accuracy": list(self.accuracy),
                "completeness": list(self.completeness), "f1": list(self.f1)}

    def at(self, tolerance: float) -> dict[str, float]:
        """Scores at one tolerance (must be one of ``tolerances``)."""
        i = int(np.argmin(np.abs(np.array(self.tolerances) - tolerance)))
        if not math.isclose(self.tolerances[i], tolerance, rel_tol=1e-9):
            raise KeyError(f"tolerance {tolerance} was not evaluated (have {self.tolerances})")
        return {"accuracy": self.accuracy[i], "completeness": self.completeness[i], "f1": self.f1[i]}

    def format_table(self) -> str:
        lines = [f"{'tolerance':>10} {'accuracy %':>11} {'completeness %':>15} {'F1 %':>8}"]
        for t, a, c, f in zip(self.tolerances, self.accuracy, self.completeness, self.f1, strict=True):
            lines.append(f"{t:>10g} {a:>11.2f} {c:>15.2f} {f:>8.2f}")
        lines.append(f"({self.num_reconstruction} reconstructed points, {self.num_ground_truth} ground-truth points)")
        lines += [f"note: {n}" for n in self.notes]
        return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# Shared pieces: voxel averaging, nearest-neighbour tolerance classes.

def _as_points(xyz: np.ndarray, what: str) -> np.ndarray:
    xyz = np.asarray(xyz)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise DeepCError(f"{what} must be an (N, 3) array of points, got shape {xyz.shape}")
    if len(xyz) and not np.isfinite(xyz).all():
        raise DeepCError(f"{what} has non-finite coordinates")
    return xyz


def _cell_ids(points: np.ndarray, voxel_size: float, shift: float) -> np.ndarray:
    """(N,) int64 dense ids (0..cells-1) of each point's voxel; float32 arithmetic as the official code."""
    inv = np.float32(1.0 / float(np.float32(voxel_size)))
    cells = np.floor(points.astype(np.float32) * inv + np.float32(shift)).astype(np.int64)
    lo = cells.min(axis=0)
    span = cells.max(axis=0) - lo + 1
    if float(span[0]) * float(span[1]) * float(span[2]) < 2 ** 62:
        key = ((cells[:, 0] - lo[0]) * span[1] + (cells[:, 1] - lo[1])) * span[2] + (cells[:, 2] - lo[2])
        _, ids = np.unique(key, return_inverse=True)
    else:  # astronomically large extent for the voxel size
        _, ids = np.unique(cells, axis=0, return_inverse=True)
    return ids.ravel()


def _completeness(gt: np.ndarray, first_ok: np.ndarray, n_tol: int, voxel_size: float) -> np.ndarray:
    """Mean over voxels (both grids) of the fraction of GT points complete at each tolerance."""
    sums = np.zeros(n_tol)
    n_cells = 0
    for shift in _GRID_SHIFTS:
        ids = _cell_ids(gt, voxel_size, shift)
        total = np.bincount(ids).astype(np.float64)
        n_cells += len(total)
        for t in range(n_tol):
            ok = np.bincount(ids, weights=(first_ok <= t).astype(np.float64), minlength=len(total))
            sums[t] += float(np.sum(ok / total))
    return sums / max(n_cells, 1)


def _accuracy(recon: np.ndarray, first_ok: np.ndarray, inaccurate: np.ndarray, voxel_size: float) -> np.ndarray:
    """Mean over voxels with classified points of accurate / (accurate + inaccurate).

    Args:
        first_ok: (N,) index of the first tolerance at which each point is accurate (n_tol = never).
        inaccurate: (N, n_tol) bool, point inaccurate at that tolerance (only where not accurate).
    """
    n_tol = inaccurate.shape[1]
    sums = np.zeros(n_tol)
    counts = np.zeros(n_tol)
    for shift in _GRID_SHIFTS:
        ids = _cell_ids(recon, voxel_size, shift)
        m = int(ids.max()) + 1 if len(ids) else 0
        for t in range(n_tol):
            acc = np.bincount(ids, weights=(first_ok <= t).astype(np.float64), minlength=m)
            bad = np.bincount(ids, weights=inaccurate[:, t].astype(np.float64), minlength=m)
            valid = acc + bad > 0
            sums[t] += float(np.sum(acc[valid] / (acc[valid] + bad[valid])))
            counts[t] += int(valid.sum())
    return np.where(counts > 0, sums / np.maximum(counts, 1), 0.0)


@numba.njit(cache=True, nogil=True)
def _spread_bits(x: np.ndarray) -> np.ndarray:
    x = x & 0x1FFFFF
    x = (x | (x << 32)) & 0x1F00000000FFFF
    x = (x | (x << 16)) & 0x1F0000FF0000FF
    x = (x | (x << 8)) & 0x100F00F00F00F00F
    x = (x | (x << 4)) & 0x10C30C30C30C30C3
    x = (x | (x << 2)) & 0x1249249249249249
    return x


def _spatial_order(points: np.ndarray) -> np.ndarray:
    """A Morton (Z-curve) order: kd-tree queries in this order are several times faster (cache)."""
    if len(points) < 2:
        return np.arange(len(points))
    lo = points.min(axis=0)
    extent = float((points.max(axis=0) - lo).max())
    scale = (2 ** 21 - 1) / extent if extent > 0 else 0.0
    c = ((points - lo) * scale).astype(np.int64)
    key = _spread_bits(c[:, 0]) | (_spread_bits(c[:, 1]) << 1) | (_spread_bits(c[:, 2]) << 2)
    return np.argsort(key, kind="stable")


class PointIndex:
    """Points prepared for nearest-neighbour queries, as queries and as data: their Morton order and a k-d
    tree. Building them takes about a second for 1M points; pass one to :func:`evaluate_points` in place of
    the GT array when the same GT scores many clouds (the viewer)."""

    def __init__(self, points: np.ndarray, what: str = "ground truth"):
        self.points = np.asarray(_as_points(points, what), np.float64)
        if len(self.points) == 0:
            raise DeepCError(f"the {what} has no points: nothing to evaluate against")
        self.order = _spatial_order(self.points)
        self.tree = cKDTree(self.points[self.order], balanced_tree=False, compact_nodes=False)

    def __len__(self) -> int:
        return len(self.points)


def _first_within(queries: np.ndarray | PointIndex, data: np.ndarray | PointIndex,
                  tolerances: np.ndarray) -> np.ndarray:
    """(Q,) int: index of the smallest tolerance >= the distance from each query to its nearest data
    point (len(tolerances) if none, including when ``data`` is empty)."""
    n_tol = len(tolerances)
    out = np.full(len(queries), n_tol, np.int64)
    if len(queries) == 0 or len(data) == 0:
        return out
    tree = (data if isinstance(data, PointIndex) else PointIndex(data, "data")).tree
    if isinstance(queries, PointIndex):
        queries, order = queries.points, queries.order
    else:
        order = _spatial_order(queries)
    bound = float(tolerances[-1]) * (1 + 1e-6)
    dist, _ = tree.query(np.asarray(queries, np.float64)[order], k=1, distance_upper_bound=bound, workers=-1)
    first = np.searchsorted(tolerances, dist, side="left")  # first t with dist <= t; inf -> n_tol
    out[order] = first
    return out


def _f1(acc: np.ndarray, comp: np.ndarray) -> np.ndarray:
    s = acc + comp
    return np.where(s > 0, 2 * acc * comp / np.where(s > 0, s, 1), 0.0)


def _result(tol, acc, comp, n_rec, n_gt, unobserved, notes) -> EvaluationResult:
    f1 = _f1(acc, comp)
    return EvaluationResult([float(t) for t in tol], [float(100 * a) for a in acc], [float(100 * c) for c in comp],
                            [float(100 * f) for f in f1], n_rec, n_gt, [float(100 * u) for u in unobserved], notes)


def _overlap_notes(acc: np.ndarray, comp: np.ndarray, n_rec: int, tol: np.ndarray) -> list[str]:
    notes = []
    if n_rec == 0:
        notes.append("the reconstruction is empty: accuracy, completeness and F1 are 0")
    elif comp[-1] == 0:
        notes.append(f"no ground-truth point has a reconstructed point within {tol[-1]:g}: is the ground truth "
                     "from another scene, or in another coordinate frame or unit?")
    return notes


# --------------------------------------------------------------------------------------------
# (a) GT points, optionally with GT views for the unobserved-space rule.

@numba.njit(cache=True, nogil=True, parallel=True)
def _free_space_margin_kernel(points, E, K, depth, offsets, widths, heights):
    """For each point the largest distance (along the viewing ray) by which it lies in front of the
    GT surface in any GT view; -inf if no view has GT depth at its projection.

    E: (V, 3, 4) world-to-camera [R | t]; K: (V, 3, 3) index-space intrinsics. The surface depth at
    the nearest pixel is the minimum of the valid GT depths in its 3x3 neighbourhood (the centre
    must be valid): at depth edges the nearer surface wins, so points on a foreground silhouette
    are not declared to float in free space.
    """
    n = points.shape[0]
    out = np.full(n, -np.inf)
    for i in numba.prange(n):
        x = points[i, 0]
        y = points[i, 1]
        z = points[i, 2]
        best = -np.inf
        for v in range(E.shape[0]):
            cz = E[v, 2, 0] * x + E[v, 2, 1] * y + E[v, 2, 2] * z + E[v, 2, 3]
            if cz <= 0.0:
                continue
            cx = E[v, 0, 0] * x + E[v, 0, 1] * y + E[v, 0, 2] * z + E[v, 0, 3]
            cy = E[v, 1, 0] * x + E[v, 1, 1] * y + E[v, 1, 2] * z + E[v, 1, 3]
            fu = (K[v, 0, 0] * cx + K[v, 0, 1] * cy) / cz + K[v, 0, 2]
            fv = K[v, 1, 1] * cy / cz + K[v, 1, 2]
            W = widths[v]
            H = heights[v]
            if not (fu > -0.5 and fv > -0.5 and fu < W - 0.5 and fv < H - 0.5):
                continue
            c = min(int(math.floor(fu + 0.5)), W - 1)
            r = min(int(math.floor(fv + 0.5)), H - 1)
            base = offsets[v]
            surf = depth[base + r * W + c]
            if surf <= 0.0:
                continue
            for rr in range(max(r - 1, 0), min(r + 2, H)):
                for cc in range(max(c - 1, 0), min(c + 2, W)):
                    dn = depth[base + rr * W + cc]
                    if dn > 0.0 and dn < surf:
                        surf = dn
            # Depth difference -> distance along the ray: times |X_cam| / z.
            margin = (surf - cz) * math.sqrt(cx * cx + cy * cy + cz * cz) / cz
            if margin > best:
                best = margin
        out[i] = best
    return out


def _pack_gt_views(gt_views) -> tuple:
    Es, Ks, depths, offsets, widths, heights = [], [], [], [0], [], []
    for cam, depth in gt_views:
        depth = np.asarray(depth, np.float32)
        if depth.shape != (cam.height, cam.width):
            raise DeepCError(f"GT depth shape {depth.shape} does not match its camera ({cam.height}, {cam.width})")
        Es.append(np.hstack([cam.R, cam.t[:, None]]))
        Ks.append(cam.K_idx)
        depths.append(np.where(np.isfinite(depth), depth, 0).ravel())
        offsets.append(offsets[-1] + depth.size)
        widths.append(cam.width)
        heights.append(cam.height)
    return (np.array(Es), np.array(Ks), np.concatenate(depths).astype(np.float32), np.array(offsets, np.int64),
            np.array(widths, np.int64), np.array(heights, np.int64))


def free_space_margin(points: np.ndarray, gt_views: list[tuple[Camera, np.ndarray]]) -> np.ndarray:
    """(N,) float64: how far each point lies in front of the GT surface, the maximum over GT views
    (negative = behind or on it, -inf = no GT view has depth at its projection)."""
    points = np.asarray(points, np.float64)
    if not gt_views or len(points) == 0:
        return np.full(len(points), -np.inf)
    return _free_space_margin_kernel(points, *_pack_gt_views(gt_views))


def free_space_margin_reference(points: np.ndarray, gt_views: list[tuple[Camera, np.ndarray]]) -> np.ndarray:
    """Plain numpy version of :func:`free_space_margin` (for tests)."""
    points = np.asarray(points, np.float64)
    best = np.full(len(points), -np.inf)
    for cam, depth in gt_views:
        depth = np.asarray(depth, np.float64)
        H, W = depth.shape
        uv, z = cam.project(points)
        with np.errstate(invalid="ignore"):
            inside = (z > 0) & (uv[:, 0] > -0.5) & (uv[:, 1] > -0.5) & (uv[:, 0] < W - 0.5) & (uv[:, 1] < H - 0.5)
        for i in np.flatnonzero(inside):
            c = min(int(math.floor(uv[i, 0] + 0.5)), W - 1)
            r = min(int(math.floor(uv[i, 1] + 0.5)), H - 1)
            if depth[r, c] <= 0:
                continue
            block = depth[max(r - 1, 0):r + 2, max(c - 1, 0):c + 2]
            surf = block[block > 0].min()
            Xc = cam.world_to_camera(points[i])
            margin = (surf - z[i]) * np.linalg.norm(Xc) / z[i]
            best[i] = max(best[i], margin)
    return best


def evaluate_points(recon_xyz: np.ndarray, gt_xyz: np.ndarray | PointIndex,
                    options: EvaluationOptions | None = None,
                    gt_views: list[tuple[Camera, np.ndarray]] | None = None) -> EvaluationResult:
    """Score a reconstruction against GT points (see module docstring).

    Args:
        recon_xyz: (N, 3) reconstructed points, world frame.
        gt_xyz: (M, 3) GT surface points, same frame and unit, or a :class:`PointIndex` of them.
        options: tolerances and voxel size.
        gt_views: optional (camera, (H, W) GT depth, 0 = unknown) pairs enabling the unobserved-space
            rule; cameras at the depth maps' resolution.
    """
    options = (options or EvaluationOptions()).validate()
    tol = options.sorted_tolerances()
    recon = _as_points(recon_xyz, "reconstruction")
    # one index serves both directions (its Morton order as queries, its tree as data)
    gt_index = gt_xyz if isinstance(gt_xyz, PointIndex) else PointIndex(gt_xyz, "ground truth")
    gt = gt_index.points
    n_tol = len(tol)
    comp = _completeness(gt, _first_within(gt_index, recon, tol), n_tol, options.voxel_size)
    if len(recon) == 0:
        zeros = np.zeros(n_tol)
        return _result(tol, zeros, comp, 0, len(gt), zeros, _overlap_notes(zeros, comp, 0, tol))
    first_ok = _first_within(recon, gt_index, tol)
    not_acc = first_ok[:, None] > np.arange(n_tol)[None, :]
    if gt_views:
        margin = free_space_margin(recon, gt_views)
        inaccurate = not_acc & (margin[:, None] > tol[None, :])
    else:
        inaccurate = not_acc
    acc = _accuracy(recon, first_ok, inaccurate, options.voxel_size)
    unobserved = (not_acc & ~inaccurate).mean(axis=0)
    notes = _overlap_notes(acc, comp, len(recon), tol)
    if gt_views and not notes and unobserved[0] > 0.99:
        notes.append("over 99% of the reconstructed points are unobserved by the GT views")
    return _result(tol, acc, comp, len(recon), len(gt), unobserved, notes)


# --------------------------------------------------------------------------------------------
# (b) ETH3D: MeshLab project with scans in scanner frames, beam model.

@dataclasses.dataclass
class Eth3dScan:
    """One GT laser scan: points in the scanner frame (scanner at the origin) and its pose."""

    path: Path
    global_T_scan: np.ndarray  # (4, 4) scan frame -> global frame
    points: np.ndarray  # (N, 3) float32, scan frame


def load_eth3d_mlp(path: str | Path) -> list[Eth3dScan]:
    """Read an ETH3D ``scan_alignment.mlp`` and its scans (first ``MeshGroup``, as the official tool).

    Raises :class:`DeepCError` naming the file for malformed XML, missing poses or scan files.
    """
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except FileNotFoundError:
        raise DeepCError("file not found", path) from None
    except ET.ParseError as exc:
        raise DeepCError(f"not a MeshLab project (XML error: {exc})", path) from None
    except OSError as exc:
        raise DeepCError(f"cannot read: {exc.strerror or exc}", path) from exc
    if root.tag != "MeshLabProject":
        raise DeepCError(f"not a MeshLab project: root element is <{root.tag}>", path)
    group = root.find("MeshGroup")
    if group is None:
        raise DeepCError("MeshLab project has no <MeshGroup>", path)
    scans = []
    for mesh in group.findall("MLMesh"):
        name = mesh.get("filename")
        if not name:
            raise DeepCError("an <MLMesh> has no filename", path)
        mat = mesh.find("MLMatrix44")
        if mat is None or not (mat.text or "").strip():
            raise DeepCError(f"scan {name} has no <MLMatrix44> pose", path)
        try:
            M = np.array([float(v) for v in mat.text.split()], np.float64)
        except ValueError:
            raise DeepCError(f"scan {name}: <MLMatrix44> does not hold 16 numbers", path) from None
        if M.size != 16 or not np.isfinite(M).all():
            raise DeepCError(f"scan {name}: <MLMatrix44> does not hold 16 finite numbers", path)
        M = M.reshape(4, 4)  # row-major: global_T_scan
        if not np.array_equal(M[3], [0, 0, 0, 1]):
            raise DeepCError(f"scan {name}: last row of the pose is not (0, 0, 0, 1)", path)
        scan_path = Path(name) if Path(name).is_absolute() else path.parent / name
        pts = read_points(scan_path).astype(np.float32)
        scans.append(Eth3dScan(scan_path, M, pts))
    if not scans:
        raise DeepCError("MeshLab project lists no scans (<MLMesh> elements)", path)
    return scans


_N_AZ = 2048
_N_INC = 1024


@numba.njit(cache=True, nogil=True)
def _build_spherical_grid(pts):
    """Scan points (float32, scan frame) -> (directions, radii, cell_start) sorted by cell.

    Cells: 2048 azimuth x 1024 inclination as the official program (azimuth = atan2(y, x),
    inclination = acos(z / r)). Returns (order, cell_start) with cell_start of size cells + 1.
    """
    n = pts.shape[0]
    ext_az = np.float32(2 * np.pi / _N_AZ)
    ext_inc = np.float32(np.pi / _N_INC)
    cell = np.empty(n, np.int64)
    for i in range(n):
        x = np.float32(pts[i, 0])
        y = np.float32(pts[i, 1])
        z = np.float32(pts[i, 2])
        r = np.float32(math.sqrt(x * x + y * y + z * z))
        az = np.float32(math.atan2(y, x))
        inc = np.float32(math.acos(min(max(z / r, -1.0), 1.0))) if r > 0 else np.float32(0.0)
        ia = int(math.floor(az / ext_az)) % _N_AZ
        ii = min(max(int(math.floor(inc / ext_inc)), 0), _N_INC - 1)
        cell[i] = ia + _N_AZ * ii
    order = np.argsort(cell, kind="mergesort")
    counts = np.zeros(_N_AZ * _N_INC + 1, np.int64)
    for i in range(n):
        counts[cell[i] + 1] += 1
    for c in range(_N_AZ * _N_INC):
        counts[c + 1] += counts[c]
    return order, counts


@numba.njit(cache=True, nogil=True, parallel=True)
def _classify_beam_kernel(points, scan_pts, scan_dir, scan_r, cell_start, tol_sq, beam0, tan_half):
    """Per reconstruction point (scan frame): first accurate tolerance index and the free-space flag.

    Mirrors ``ClassifyPoint`` of the official ``accuracy.cc``: candidate scan points come from the
    spherical cells covering the point's beam-relevancy box; a candidate's ray sees the point if
    the point lies on its positive side within the beam radius.
    """
    n = points.shape[0]
    n_tol = tol_sq.shape[0]
    first = np.full(n, n_tol, np.int64)
    flag = np.zeros(n, np.bool_)
    ext_az = 2 * np.pi / _N_AZ
    ext_inc = np.pi / _N_INC
    for i in numba.prange(n):
        px = points[i, 0]
        py = points[i, 1]
        pz = points[i, 2]
        r = math.sqrt(px * px + py * py + pz * pz)
        if r <= 0.0:
            continue
        rh = math.sqrt(px * px + py * py)
        az = math.atan2(py, px)
        inc = math.acos(min(max(pz / r, -1.0), 1.0))
        beam = beam0 + r * tan_half
        beam_sq = beam * beam
        if beam >= r:
            ang_v = np.pi
            ang_h = np.pi
        else:
            ang_v = math.asin(beam / r)
            ang_h = np.pi if beam >= rh else math.asin(beam / rh)
        a0 = int(math.floor((az - ang_h) / ext_az))
        a1 = int(math.floor((az + ang_h) / ext_az))
        if a1 - a0 >= _N_AZ:
            a0 = 0
            a1 = _N_AZ - 1
        i0 = min(max(int(math.floor((inc - ang_v) / ext_inc)), 0), _N_INC - 1)
        i1 = min(max(int(math.floor((inc + ang_v) / ext_inc)), 0), _N_INC - 1)
        best = n_tol
        free = False
        for ii in range(i0, i1 + 1):
            for aa in range(a0, a1 + 1):
                c = (aa % _N_AZ) + _N_AZ * ii
                for s in range(cell_start[c], cell_start[c + 1]):
                    dx = scan_dir[s, 0]
                    dy = scan_dir[s, 1]
                    dz = scan_dir[s, 2]
                    t = dx * px + dy * py + dz * pz
                    if t < 0.0:
                        continue
                    ex = px - t * dx
                    ey = py - t * dy
                    ez = pz - t * dz
                    if ex * ex + ey * ey + ez * ez > beam_sq:
                        continue
                    gx = scan_pts[s, 0] - px
                    gy = scan_pts[s, 1] - py
                    gz = scan_pts[s, 2] - pz
                    d2 = gx * gx + gy * gy + gz * gz
                    for k in range(min(best, n_tol)):
                        if d2 <= tol_sq[k]:
                            best = k
                            break
                    if t < scan_r[s]:
                        free = True
        first[i] = best
        flag[i] = free
    return first, flag


def _prepare_scan(scan: Eth3dScan):
    pts = np.asarray(scan.points, np.float32)
    r = np.linalg.norm(pts.astype(np.float64), axis=1)
    keep = r > 0
    pts, r = pts[keep], r[keep]
    order, cell_start = _build_spherical_grid(pts)
    pts = pts[order].astype(np.float64)
    r = r[order]
    return pts, pts / r[:, None], r, cell_start


def classify_beam(recon_scan_frame: np.ndarray, scan: Eth3dScan, tolerances: np.ndarray,
                  options: EvaluationOptions) -> tuple[np.ndarray, np.ndarray]:
    """Official beam-model classification of points (given in the scan's frame) against one scan.

    Returns (first accurate tolerance index (N,) int, n_tol = never; free-space flag (N,) bool).
    """
    pts, dirs, r, cell_start = _prepare_scan(scan)
    tan_half = math.tan(math.radians(options.beam_divergence_halfangle_deg))
    return _classify_beam_kernel(np.asarray(recon_scan_frame, np.float64), pts, dirs, r, cell_start,
                                 np.asarray(tolerances, np.float64) ** 2, float(options.beam_start_radius),
                                 tan_half)


def classify_beam_reference(recon_scan_frame: np.ndarray, scan_points: np.ndarray, tolerances: np.ndarray,
                            beam_start_radius: float, half_angle_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Brute-force numpy version of :func:`classify_beam` (every scan ray is a candidate; for tests)."""
    g = np.asarray(scan_points, np.float64)
    g = g[np.linalg.norm(g, axis=1) > 0]
    rg = np.linalg.norm(g, axis=1)
    dirs = g / rg[:, None]
    tol_sq = np.asarray(tolerances, np.float64) ** 2
    n_tol = len(tol_sq)
    tan_half = math.tan(math.radians(half_angle_deg))
    first = np.full(len(recon_scan_frame), n_tol, np.int64)
    flag = np.zeros(len(recon_scan_frame), bool)
    for i, p in enumerate(np.asarray(recon_scan_frame, np.float64)):
        r = np.linalg.norm(p)
        if r == 0:
            continue
        beam = beam_start_radius + r * tan_half
        t = dirs @ p
        perp = np.sum((p[None, :] - t[:, None] * dirs) ** 2, axis=1)
        seen = (t >= 0) & (perp <= beam * beam)
        if not seen.any():
            continue
        d2 = np.sum((g[seen] - p) ** 2, axis=1)
        ok = d2[:, None] <= tol_sq[None, :]
        hits = np.flatnonzero(ok.any(axis=0))
        first[i] = hits[0] if len(hits) else n_tol
        flag[i] = bool((t[seen] < rg[seen]).any())
    return first, flag


def evaluate_eth3d(recon_xyz: np.ndarray, mlp_path: str | Path | list[Eth3dScan],
                   options: EvaluationOptions | None = None) -> EvaluationResult:
    """Score a reconstruction against ETH3D laser scans as the official program does.

    Args:
        recon_xyz: (N, 3) reconstructed points, global frame.
        mlp_path: ``scan_alignment.mlp`` (or scans already loaded with :func:`load_eth3d_mlp`).
    """
    options = (options or EvaluationOptions()).validate()
    tol = options.sorted_tolerances()
    n_tol = len(tol)
    recon = _as_points(recon_xyz, "reconstruction").astype(np.float32).astype(np.float64)
    scans = mlp_path if isinstance(mlp_path, list) else load_eth3d_mlp(mlp_path)
    merged = []
    for s in scans:
        pts = np.asarray(s.points, np.float64)
        merged.append((pts @ s.global_T_scan[:3, :3].T + s.global_T_scan[:3, 3]).astype(np.float32))
    gt = np.concatenate(merged).astype(np.float64)
    if len(gt) == 0:
        raise DeepCError("the ETH3D scans hold no points: nothing to evaluate against",
                         None if isinstance(mlp_path, list) else mlp_path)
    comp = _completeness(gt, _first_within(gt, recon, tol), n_tol, options.voxel_size)
    if len(recon) == 0:
        zeros = np.zeros(n_tol)
        return _result(tol, zeros, comp, 0, len(gt), zeros, _overlap_notes(zeros, comp, 0, tol))
    first = np.full(len(recon), n_tol, np.int64)
    free = np.zeros(len(recon), bool)
    for s in scans:
        R, t = s.global_T_scan[:3, :3], s.global_T_scan[:3, 3]
        local = (recon - t) @ R  # R^T (p - t), row vectors
        f, fl = classify_beam(local, s, tol, options)
        first = np.minimum(first, f)
        free |= fl
    not_acc = first[:, None] > np.arange(n_tol)[None, :]
    inaccurate = not_acc & free[:, None]
    acc = _accuracy(recon, first, inaccurate, options.voxel_size)
    unobserved = (not_acc & ~inaccurate).mean(axis=0)
    notes = _overlap_notes(acc, comp, len(recon), tol)
    if not notes and unobserved[-1] > 0.99:
        notes.append("over 99% of the reconstructed points are unobserved by the scans (too sparse scans "
                     "for the beam radius, or another scene?)")
    return _result(tol, acc, comp, len(recon), len(gt), unobserved, notes)


def evaluate_file(recon_path: str | Path, gt_path: str | Path,
                  options: EvaluationOptions | None = None,
                  gt_views: list[tuple[Camera, np.ndarray]] | None = None) -> EvaluationResult:
    """Evaluate a PLY against a GT ``.ply`` (points) or an ETH3D ``.mlp``; float or double PLYs."""
    recon = read_points(recon_path)
    gt_path = Path(gt_path)
    if gt_path.suffix.lower() == ".mlp":
        return evaluate_eth3d(recon, gt_path, options)
    return evaluate_points(recon, read_points(gt_path), options, gt_views)


# --------------------------------------------------------------------------------------------
# Synthetic ETH3D-format ground truth (for tests, benchmarks and checking an evaluator build).

# Axis-aligned boxes (min xyz, max xyz), metres: a ground plate and a box standing on it.
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
