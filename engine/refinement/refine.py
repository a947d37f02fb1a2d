"""Confidence-guided piece-wise planar depth refinement of one depth map (Rossi et al. 2020).

``refine_depth`` builds a pyramid (Rossi et al. 2020), minimises its energy from the coarsest scale
to the finest with the chosen solver, warm-starting each scale from the previous one, and returns a
dense depth map and the normals of its local planes.

Input conventions: depth in model units with 0 (or non-finite) = none; confidence in [0, 1] (NaN = 0);
index-space intrinsics (Schönberger et al. 2016); normals in the camera frame facing the camera.

Bad input: maps whose sizes differ, non-square-3x3 intrinsics, an empty or inverted depth range and
confidence outside [0, 1] raise :class:`DeepCError`. A map with nothing to refine from (no depth inside
the range, or zero confidence at every such pixel) raises :class:`NoDataError` (a DeepCError): the
energy would then be the regulariser alone, whose minimisers are arbitrary planes, so any output would
be invented. Batch drivers catch it and write an empty map for that view (see ``refine_views``).
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from engine.core.errors import DeepCError
from engine.refinement.energy import ScaleProblem, energy_terms
from engine.refinement.graph import similarity_graph
from engine.refinement.options import RefinementOptions
from engine.refinement.planes import (
    gradient_init,
    nearest_fill,
    normal_to_u,
    pyramid_shapes,
    resize_linear,
    resize_nearest,
    scale_intrinsics,
    u_to_normal,
)
from engine.refinement.primal_dual import solve_primal_dual


class NoDataError(DeepCError):
    """A depth map without a single confident depth inside the depth range: nothing to refine."""


@dataclasses.dataclass(eq=False)
class RefinedMap:
    """Result of :func:`refine_depth`.

    Attributes:
        depth: (H, W) float32 dense depth in model units, inside the depth range.
        normal: (H, W, 3) float32 unit camera-frame normals facing the camera.
        seconds: wall time of the whole refinement.
        shapes: (H, W) of every scale, coarse to fine.
        iterations: solver iterations per scale, coarse to fine.
        energy: final energy per scale, coarse to fine (each on its own scale's graph).
        seconds_per_scale: wall time per scale (graph build + solve), coarse to fine.
        solver: "adam" or "fast".
    """

    depth: np.ndarray
    normal: np.ndarray
    seconds: float
    shapes: list[tuple[int, int]]
    iterations: list[int]
    energy: list[float]
    seconds_per_scale: list[float]
    solver: str


@dataclasses.dataclass(eq=False)
class _Inputs:
    gray: np.ndarray
    depth: np.ndarray
    confidence: np.ndarray
    K: np.ndarray
    z_min: float
    z_max: float
    normal: np.ndarray | None


def _check_inputs(gray, depth, confidence, K, depth_range, normal, options: RefinementOptions) -> _Inputs:
    gray = np.asarray(gray, np.float64)
    depth = np.asarray(depth, np.float64)
    confidence = np.asarray(confidence, np.float64)
    if gray.ndim != 2:
        raise DeepCError(f"refinement: grey image must be (H, W), got shape {gray.shape}")
    shape = gray.shape
    if depth.shape != shape:
        raise DeepCError(f"refinement: depth map is {depth.shape[::-1]} (W, H) but the image is {shape[::-1]}")
    if confidence.shape != shape:
        raise DeepCError(f"refinement: confidence map is {confidence.shape[::-1]} (W, H) but the image is "
                         f"{shape[::-1]}")
    if normal is not None:
        normal = np.asarray(normal, np.float64)
        if normal.shape != shape + (3,):
            raise DeepCError(f"refinement: normal map has shape {normal.shape}, expected {shape + (3,)}")
        normal = np.where(np.isfinite(normal), normal, 0.0)
    K = np.asarray(K, np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise DeepCError(f"refinement: intrinsics must be a finite 3x3 matrix with fx, fy > 0, got {K.tolist()}")
    z_min, z_max = (float(v) for v in depth_range)
    if not (np.isfinite(z_min) and np.isfinite(z_max) and 0 < z_min < z_max):
        raise DeepCError(f"refinement: depth range must satisfy 0 < min < max, got ({z_min}, {z_max})")
    confidence = np.where(np.isfinite(confidence), confidence, 0.0)
    if confidence.size and (confidence.min() < -1e-6 or confidence.max() > 1 + 1e-6):
        raise DeepCError(f"refinement: confidence must lie in [0, 1], found values in "
                         f"[{confidence.min():.3g}, {confidence.max():.3g}]")
    confidence = np.clip(confidence, 0.0, 1.0)
    if options.confidence_threshold is not None:
        confidence = (confidence >= options.confidence_threshold).astype(np.float64)
    depth = np.where(np.isfinite(depth), depth, 0.0)
    return _Inputs(gray, depth, confidence, K, z_min, z_max, normal)


def _in_range(depth: np.ndarray, z_min: float, z_max: float) -> np.ndarray:
    return (depth >= z_min) & (depth <= z_max)


def build_problem(gray: np.ndarray, depth: np.ndarray, confidence: np.ndarray, depth_range: tuple[float, float],
                  options: RefinementOptions) -> ScaleProblem:
    """The energy of one scale for maps already at that scale's size (no input checks)."""
    z_min, z_max = depth_range
    valid = _in_range(depth, z_min, z_max)
    data = np.where(valid, 1.0 / np.where(valid, depth, 1.0), 0.0)
    graph = similarity_graph(gray, options.window, options.patch, options.sigma_int, options.sigma_spa,
                             options.degree)
    return ScaleProblem(graph, data.ravel().astype(np.float32),
                        np.where(valid, confidence, 0.0).ravel().astype(np.float32),
                        1.0 / z_max, 1.0 / z_min, options.lambda_data, options.lambda_reg, options.gamma)


def _initial_planes(inp: _Inputs, depth: np.ndarray, normal: np.ndarray | None, K: np.ndarray,
                    options: RefinementOptions) -> tuple[np.ndarray, np.ndarray]:
    """(d (H, W), u (H, W, 2)) at the coarsest scale (Rossi et al. 2020)."""
    valid = _in_range(depth, inp.z_min, inp.z_max)
    d = np.where(valid, 1.0 / np.where(valid, depth, 1.0), 0.0)
    if options.hole_init == "nearest":
        d = nearest_fill(d, valid)
    d = np.clip(d, 1.0 / inp.z_max, 1.0 / inp.z_min)  # far plane where nothing was filled
    if normal is None:
        return d, gradient_init(np.where(valid, d, 0.0) if options.hole_init == "far" else d)
    has_normal = valid & (np.linalg.norm(normal, axis=-1) > 0.5)
    if options.hole_init == "nearest":
        normal = nearest_fill(normal, has_normal)
        has_normal = np.linalg.norm(normal, axis=-1) > 0.5
    u = normal_to_u(normal, 1.0 / d, K)
    return d, np.where(has_normal[..., None], u, 0.0)


def refine_depth(gray: np.ndarray, depth: np.ndarray, confidence: np.ndarray, K_idx: np.ndarray,
                 depth_range: tuple[float, float], normal: np.ndarray | None = None,
                 options: RefinementOptions | None = None) -> RefinedMap:
    """Refine one depth map (Rossi et al. 2020).

    Args:
        gray: (H, W) grey image in [0, 1] (builds the similarity graph).
        depth: (H, W) depth in model units, 0 or non-finite = none.
        confidence: (H, W) confidence in [0, 1]; NaN = 0.
        K_idx: (3, 3) index-space intrinsics at this resolution.
        depth_range: (z_min, z_max); the result is clipped to it and inputs outside it are ignored.
        normal: optional (H, W, 3) camera-frame normals, used to initialise the plane orientations.
        options: energy and solver options (defaults: the paper's, fast solver).
    Returns:
        A :class:`RefinedMap`.
    Raises:
        DeepCError on inconsistent input, NoDataError when no pixel carries a confident depth.
    """
    options = (options or RefinementOptions()).validate()
    start = time.perf_counter()
    inp = _check_inputs(gray, depth, confidence, K_idx, depth_range, normal, options)
    fidelity = np.where(_in_range(inp.depth, inp.z_min, inp.z_max), inp.confidence, 0.0)
    if not np.any(fidelity > 0):
        n_valid = int(_in_range(inp.depth, inp.z_min, inp.z_max).sum())
        reason = ("no pixel has a depth inside the range" if n_valid == 0
                  else f"all {n_valid} pixels with depth have zero confidence")
        raise NoDataError(f"refinement: nothing to refine from: {reason} "
                          f"(range {inp.z_min:.4g}..{inp.z_max:.4g})")
    shapes = pyramid_shapes(inp.gray.shape, options.scales)[::-1]  # coarse -> fine
    iters = options.iters if options.solver == "adam" else options.fast_iters
    d = u = None
    K_prev = None
    out_iters, out_energy, out_seconds = [], [], []
    for s, shape in enumerate(shapes):
        t = time.perf_counter()
        K = scale_intrinsics(inp.K, inp.gray.shape, shape)
        depth_s = resize_nearest(inp.depth, shape)
        problem = build_problem(resize_linear(inp.gray, shape), depth_s, resize_nearest(inp.confidence, shape),
                                (inp.z_min, inp.z_max), options)
        if d is None:
            normal_s = None if inp.normal is None else resize_nearest(inp.normal, shape)
            d, u = _initial_planes(inp, depth_s, normal_s, K, options)
        else:  # warm start: upsample the previous scale's depth and 3-D normals, back to (d, u) here
            normal_prev = u_to_normal(u, d, K_prev)
            z = resize_nearest(1.0 / d, shape)
            d = 1.0 / z
            u = normal_to_u(resize_nearest(normal_prev, shape), z, K)
        n_it = int(iters[s])
        if options.solver == "adam":
            from engine.refinement.adam import solve_adam  # lazy: torch, only for the reference solver

            d_f, u_f, done = solve_adam(problem, d.ravel(), u.reshape(-1, 2), n_it, options.lr[s], options.lr_slots[s])
        else:
            d_f, u_f, done = solve_primal_dual(problem, d.ravel(), u.reshape(-1, 2), n_it, options.fast_balance)
        out_energy.append(energy_terms(problem, d_f, u_f)["total"])
        d = d_f.reshape(shape).astype(np.float64)
        u = u_f.reshape(shape + (2,)).astype(np.float64)
        K_prev = K
        out_iters.append(done)
        out_seconds.append(time.perf_counter() - t)
    depth_out = np.clip(1.0 / d, inp.z_min, inp.z_max).astype(np.float32)
    normal_out = u_to_normal(u, d, inp.K).astype(np.float32)
    return RefinedMap(depth_out, normal_out, time.perf_counter() - start, shapes, out_iters, out_energy,
                      out_seconds, options.solver)


def map_energy(gray: np.ndarray, depth: np.ndarray, confidence: np.ndarray, K_idx: np.ndarray,
               depth_range: tuple[float, float], refined_depth: np.ndarray, refined_normal: np.ndarray,
               options: RefinementOptions | None = None) -> dict[str, float]:
    """Energy terms (Rossi et al. 2020, finest scale) of a refined (depth, normal) pair for the given input;
    compares solvers on equal terms."""
    options = (options or RefinementOptions()).validate()
    inp = _check_inputs(gray, depth, confidence, K_idx, depth_range, None, options)
    problem = build_problem(inp.gray, inp.depth, inp.confidence, (inp.z_min, inp.z_max), options)
    d = 1.0 / np.asarray(refined_depth, np.float64)
    u = normal_to_u(np.asarray(refined_normal, np.float64), np.asarray(refined_depth, np.float64), inp.K)
    return energy_terms(problem, d.ravel(), u.reshape(-1, 2))
