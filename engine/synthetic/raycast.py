"""Exact analytic ray casting of simple primitives (pure numpy, vectorised).

World frame: right-handed, z up, units are metres. A ray is ``origin + s * direction``; directions
need not be unit length. Camera rays from :meth:`engine.core.camera.Camera.pixel_rays` have camera-frame
z component 1, so for them the ray parameter ``s`` *is* the camera z-depth (Schönberger et al. 2016: depth is
camera z, not ray length); the Euclidean hit distance is ``s * |direction|``.

Every primitive implements ``intersect(origins, directions) -> (s, normal)`` with ``s`` (N,) the
nearest hit parameter > ``EPS`` (``inf`` for a miss) and ``normal`` (N, 3) the unit outward
surface normal at the hit (undefined for misses). :func:`cast` takes the nearest hit over a list
of primitives (occlusions) and returns normals turned to face the ray.
"""

from __future__ import annotations

import dataclasses

import numpy as np

EPS = 1e-9  # smallest accepted ray parameter; rays start on the surface for shadow rays


def _as_rays(origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    o = np.broadcast_to(np.asarray(origins, np.float64), d.shape)
    return o, d


def _unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


@dataclasses.dataclass(frozen=True)
class Quad:
    """A planar rectangle (or an infinite plane when both half extents are ``inf``).

    Attributes:
        center: (3,) a point of the plane, the rectangle's centre.
        u_axis, v_axis: (3,) in-plane directions (v is re-orthogonalised against u).
        half_u, half_v: half extents along u and v (metres); ``inf`` = unbounded.
    """

    center: tuple
    u_axis: tuple
    v_axis: tuple
    half_u: float = np.inf
    half_v: float = np.inf
    planar = True

    def bounds(self) -> tuple[np.ndarray, float] | None:
        """Bounding sphere (centre (3,), radius), or None when unbounded."""
        if not (np.isfinite(self.half_u) and np.isfinite(self.half_v)):
            return None
        return np.asarray(self.center, np.float64), float(np.hypot(self.half_u, self.half_v))

    def frame(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        u = _unit(self.u_axis)
        v = np.asarray(self.v_axis, np.float64)
        v = _unit(v - (v @ u) * u)
        return u, v, np.cross(u, v)

    def intersect(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        o, d = _as_rays(origins, directions)
        u, v, n = self.frame()
        c = np.asarray(self.center, np.float64)
        denom = d @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            s = ((c - o) @ n) / denom
        s = np.where(np.isfinite(s) & (s > EPS), s, np.inf)
        hit = np.isfinite(s)
        rel = o[hit] + s[hit, None] * d[hit] - c
        inside = (np.abs(rel @ u) <= self.half_u) & (np.abs(rel @ v) <= self.half_v)
        s[np.flatnonzero(hit)[~inside]] = np.inf
        return s, np.broadcast_to(n, d.shape).copy()


@dataclasses.dataclass(frozen=True)
class Box:
    """An oriented box.

    Attributes:
        center: (3,) centre.
        half_size: (3,) half extents along the box axes.
        rotation: (3, 3) columns are the box axes in world coordinates (identity = axis-aligned).
    """

    center: tuple
    half_size: tuple
    rotation: tuple = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    planar = True

    def bounds(self) -> tuple[np.ndarray, float]:
        return np.asarray(self.center, np.float64), float(np.linalg.norm(self.half_size))

    def intersect(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        o, d = _as_rays(origins, directions)
        Rb = np.asarray(self.rotation, np.float64)
        h = np.asarray(self.half_size, np.float64)
        ol = (o - np.asarray(self.center, np.float64)) @ Rb  # box-local coordinates
        dl = d @ Rb
        dl = np.where(np.abs(dl) < 1e-300, 1e-300, dl)  # slab test needs finite 1/d
        t1 = (-h - ol) / dl
        t2 = (h - ol) / dl
        tmin = np.minimum(t1, t2)
        tnear = tmin.max(axis=1)
        tfar = np.maximum(t1, t2).min(axis=1)
        hit = (tnear <= tfar) & (tfar > EPS)
        entering = tnear > EPS  # origin outside: the entry face; inside: the exit face
        s = np.where(hit, np.where(entering, tnear, tfar), np.inf)
        axis = np.where(entering, tmin.argmax(axis=1), np.maximum(t1, t2).argmin(axis=1))
        rows = np.arange(len(d))
        nl = np.zeros_like(dl)
        nl[rows, axis] = -np.sign(dl[rows, axis]) * np.where(entering, 1.0, -1.0)
        return s, nl @ Rb.T


@dataclasses.dataclass(frozen=True)
class Sphere:
    """A sphere with ``center`` (3,) and ``radius`` (metres)."""

    center: tuple
    radius: float
    planar = False

    def bounds(self) -> tuple[np.ndarray, float]:
        return np.asarray(self.center, np.float64), float(self.radius)

    def intersect(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        o, d = _as_rays(origins, directions)
        c = np.asarray(self.center, np.float64)
        oc = o - c
        a = np.einsum("ij,ij->i", d, d)
        b = np.einsum("ij,ij->i", oc, d)
        cc = np.einsum("ij,ij->i", oc, oc) - self.radius**2
        disc = b * b - a * cc
        root = np.sqrt(np.maximum(disc, 0.0))
        # Stable roots: q = -(b + sign(b) root); s = q/a and cc/q.
        q = -(b + np.copysign(root, b))
        with np.errstate(divide="ignore", invalid="ignore"):
            r1, r2 = q / a, cc / q
        lo, hi = np.minimum(r1, r2), np.maximum(r1, r2)
        s = np.where(lo > EPS, lo, np.where(hi > EPS, hi, np.inf))
        s = np.where((disc >= 0) & np.isfinite(s), s, np.inf)
        p = o + np.where(np.isfinite(s), s, 0.0)[:, None] * d
        return s, (p - c) / self.radius


@dataclasses.dataclass(frozen=True)
class Cylinder:
    """A vertical (world z axis) capped cylinder, e.g. a thin pole.

    Attributes:
        base: (3,) centre of the bottom cap.
        radius: radius (metres).
        height: length along +z (metres).
    """

    base: tuple
    radius: float
    height: float
    planar = False

    def bounds(self) -> tuple[np.ndarray, float]:
        c = np.asarray(self.base, np.float64) + [0.0, 0.0, self.height / 2]
        return c, float(np.hypot(self.radius, self.height / 2))

    def intersect(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        o, d = _as_rays(origins, directions)
        b0 = np.asarray(self.base, np.float64)
        z0, z1 = b0[2], b0[2] + self.height
        ox, oy = o[:, 0] - b0[0], o[:, 1] - b0[1]
        dx, dy = d[:, 0], d[:, 1]
        a = dx * dx + dy * dy
        b = ox * dx + oy * dy
        c = ox * ox + oy * oy - self.radius**2
        disc = b * b - a * c
        root = np.sqrt(np.maximum(disc, 0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            cand = np.stack([(-b - root) / a, (-b + root) / a])  # side, near and far
        z = o[:, 2] + cand * d[:, 2]
        side_ok = (disc >= 0) & (a > 0) & (cand > EPS) & (z >= z0) & (z <= z1) & np.isfinite(cand)
        side = np.where(side_ok, cand, np.inf).min(axis=0)
        caps = []
        for zc in (z0, z1):
            with np.errstate(divide="ignore", invalid="ignore"):
                sc = (zc - o[:, 2]) / d[:, 2]
                px, py = ox + sc * dx, oy + sc * dy
            ok = np.isfinite(sc) & (sc > EPS) & (px * px + py * py <= self.radius**2)
            caps.append(np.where(ok, sc, np.inf))
        s = np.minimum(side, np.minimum(caps[0], caps[1]))
        p = o + np.where(np.isfinite(s), s, 0.0)[:, None] * d
        normal = np.zeros_like(d)
        on_side = np.isfinite(s) & (s == side)
        normal[on_side, 0] = (p[on_side, 0] - b0[0]) / self.radius
        normal[on_side, 1] = (p[on_side, 1] - b0[1]) / self.radius
        normal[~on_side & (s == caps[0]), 2] = -1.0
        normal[~on_side & (s == caps[1]), 2] = 1.0
        return s, normal


Primitive = Quad | Box | Sphere | Cylinder


@dataclasses.dataclass
class Hits:
    """Nearest hits of N rays.

    Attributes:
        s: (N,) float64 ray parameter of the hit (``inf`` = miss). For rays with z component 1 in a
            camera frame this is the camera z-depth.
        distance: (N,) float64 Euclidean hit distance ``s * |direction|`` (``inf`` = miss).
        normal: (N, 3) float64 unit world normal facing the ray origin (zeros for misses).
        prim: (N,) int32 index of the primitive hit, -1 for a miss.
        point: (N, 3) float64 world hit point (NaN for misses).
    """

    s: np.ndarray
    distance: np.ndarray
    normal: np.ndarray
    prim: np.ndarray
    point: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        return self.prim >= 0


def _may_hit(primitive: Primitive, o: np.ndarray, d: np.ndarray) -> np.ndarray | None:
    """(N,) bool: rays that pass the primitive's bounding sphere (None = all); a cheap pre-test."""
    b = primitive.bounds()
    if b is None:
        return None
    center, radius = b
    oc = center - o
    along = np.einsum("ij,ij->i", oc, d)
    dd = np.einsum("ij,ij->i", d, d)
    dist2 = np.einsum("ij,ij->i", oc, oc) - along * along / dd
    r = radius * (1.0 + 1e-9) + 1e-12  # never cull a grazing hit
    return (dist2 <= r * r) & (along > -r * np.sqrt(dd))


def _intersect(primitive: Primitive, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``primitive.intersect`` evaluated only on rays that pass the bounding-sphere test."""
    mask = _may_hit(primitive, o, d)
    if mask is None:
        return primitive.intersect(o, d)
    s = np.full(len(d), np.inf)
    normal = np.zeros_like(d)
    if mask.any():
        s[mask], normal[mask] = primitive.intersect(o[mask], d[mask])
    return s, normal


def cast(primitives: list[Primitive], origins: np.ndarray, directions: np.ndarray) -> Hits:
    """Nearest hit of each ray among ``primitives`` (occlusions resolved by the smallest ``s``).

    Args:
        primitives: the scene's primitives; the index in this list is the primitive id.
        origins: (3,) or (N, 3) ray origins (world).
        directions: (N, 3) ray directions (world, any length).
    """
    o, d = _as_rays(origins, directions)
    n = len(d)
    best = np.full(n, np.inf)
    normal = np.zeros((n, 3))
    prim = np.full(n, -1, np.int32)
    for index, primitive in enumerate(primitives):
        s, nrm = _intersect(primitive, o, d)
        closer = s < best
        best[closer] = s[closer]
        normal[closer] = nrm[closer]
        prim[closer] = index
    hit = prim >= 0
    flip = np.einsum("ij,ij->i", normal, d) > 0  # two-sided quads; face the viewer
    normal[flip] *= -1.0
    point = np.full((n, 3), np.nan)
    point[hit] = o[hit] + best[hit, None] * d[hit]
    return Hits(best, best * np.linalg.norm(d, axis=1), normal, prim, point)


def occluded(primitives: list[Primitive], origins: np.ndarray, direction: np.ndarray,
             max_s: float = np.inf) -> np.ndarray:
    """(N,) bool: does the ray from each origin along ``direction`` (3,) hit anything before ``max_s``?"""
    o = np.asarray(origins, np.float64).reshape(-1, 3)
    d = np.broadcast_to(np.asarray(direction, np.float64), o.shape)
    blocked = np.zeros(len(o), bool)
    for primitive in primitives:
        todo = ~blocked
        if not todo.any():
            break
        s, _ = _intersect(primitive, o[todo], d[todo])
        blocked[np.flatnonzero(todo)[s < max_s]] = True
    return blocked
