"""ETH3D's own ground truth: laser scans listed by a MeshLab project, and the official evaluator's beam model."""

from __future__ import annotations

import dataclasses
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numba
import numpy as np

from engine.core.errors import DeepCError
from engine.evaluation.options import EvaluationOptions
from engine.evaluation.point_index import first_within
from engine.evaluation.result import EvaluationResult, make_result, overlap_notes
from engine.evaluation.voxels import as_points, voxel_accuracy, voxel_completeness
from engine.io.ply import read_points


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
    recon = as_points(recon_xyz, "reconstruction").astype(np.float32).astype(np.float64)
    scans = mlp_path if isinstance(mlp_path, list) else load_eth3d_mlp(mlp_path)
    merged = []
    for s in scans:
        pts = np.asarray(s.points, np.float64)
        merged.append((pts @ s.global_T_scan[:3, :3].T + s.global_T_scan[:3, 3]).astype(np.float32))
    gt = np.concatenate(merged).astype(np.float64)
    if len(gt) == 0:
        raise DeepCError("the ETH3D scans hold no points: nothing to evaluate against",
                         None if isinstance(mlp_path, list) else mlp_path)
    comp = voxel_completeness(gt, first_within(gt, recon, tol), n_tol, options.voxel_size)
    if len(recon) == 0:
        zeros = np.zeros(n_tol)
        return make_result(tol, zeros, comp, 0, len(gt), zeros, overlap_notes(zeros, comp, 0, tol))
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
    acc = voxel_accuracy(recon, first, inaccurate, options.voxel_size)
    unobserved = (not_acc & ~inaccurate).mean(axis=0)
    notes = overlap_notes(acc, comp, len(recon), tol)
    if not notes and unobserved[-1] > 0.99:
        notes.append("over 99% of the reconstructed points are unobserved by the scans (too sparse scans "
                     "for the beam radius, or another scene?)")
    return make_result(tol, acc, comp, len(recon), len(gt), unobserved, notes)

