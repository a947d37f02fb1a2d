"""Solid (3-D) procedural textures evaluated at world points.

A texture is a function of the world hit point only, so a surface point has the same albedo in
every view (what multi-view stereo assumes). All randomness comes from an integer hash of the
lattice coordinates and a per-texture seed: no global RNG, identical results on every run.
"""

from __future__ import annotations

import dataclasses

import numpy as np

KINDS = ("noise", "checker", "stripes", "blobs", "weak")


def _hash01(ix: np.ndarray, iy: np.ndarray, iz: np.ndarray, seed: int) -> np.ndarray:
    """Uniform [0, 1) hash of integer lattice points (uint32 arithmetic wraps by design)."""
    h = (ix.astype(np.int64).astype(np.uint32) * np.uint32(0x8DA6B343)
         ^ iy.astype(np.int64).astype(np.uint32) * np.uint32(0xD8163841)
         ^ iz.astype(np.int64).astype(np.uint32) * np.uint32(0xCB1AB31F)
         ^ np.uint32((seed * 0x165667B1) & 0xFFFFFFFF))
    h ^= h >> np.uint32(15)
    h *= np.uint32(0x2C1B3C6D)
    h ^= h >> np.uint32(12)
    h *= np.uint32(0x297A2D39)
    h ^= h >> np.uint32(15)
    return h.astype(np.float64) * (1.0 / 4294967296.0)


def value_noise(points: np.ndarray, seed: int) -> np.ndarray:
    """(N,) smooth value noise in [0, 1] at (N, 3) points (lattice spacing 1, quintic fade)."""
    p = np.asarray(points, np.float64)
    base = np.floor(p)
    f = p - base
    w = f * f * f * (f * (f * 6.0 - 15.0) + 10.0)
    i = base.astype(np.int64)
    out = np.zeros(len(p))
    for dx in (0, 1):
        wx = w[:, 0] if dx else 1.0 - w[:, 0]
        for dy in (0, 1):
            wy = w[:, 1] if dy else 1.0 - w[:, 1]
            for dz in (0, 1):
                wz = w[:, 2] if dz else 1.0 - w[:, 2]
                out += wx * wy * wz * _hash01(i[:, 0] + dx, i[:, 1] + dy, i[:, 2] + dz, seed)
    return out


def fbm(points: np.ndarray, seed: int, octaves: int = 4, lacunarity: float = 2.03, gain: float = 0.55) -> np.ndarray:
    """(N,) fractal sum of value noise, normalised to [0, 1]; octave k has frequency lacunarity**k."""
    total = np.zeros(len(points))
    amp, norm = 1.0, 0.0
    # A fixed rotation-like shear per octave hides the lattice axes.
    shear = np.array([[0.80, 0.36, -0.48], [-0.60, 0.48, -0.64], [0.0, 0.80, 0.60]])
    p = np.asarray(points, np.float64)
    for k in range(octaves):
        total += amp * value_noise(p, seed + 101 * k)
        norm += amp
        amp *= gain
        p = (p @ shear.T) * lacunarity + 17.31
    return total / norm


@dataclasses.dataclass(frozen=True)
class Texture:
    """A solid texture: a scalar pattern s(p) in [0, 1] mixing two albedo colours.

    Attributes:
        kind: one of ``KINDS``. "weak" is a faint low-frequency variation (hard for matching).
        color_a, color_b: linear RGB albedo in [0, 1] at s = 0 and s = 1.
        scale: feature size in metres (the pattern's base period).
        contrast: > 0; values above 1 push s towards 0/1 (harder edges, stronger texture).
        octaves: noise octaves (finer detail with more).
        seed: hash seed of this texture.
        roughness: amplitude ratio of successive noise octaves (higher = more fine detail).
    """

    kind: str = "noise"
    color_a: tuple = (0.15, 0.15, 0.15)
    color_b: tuple = (0.85, 0.85, 0.85)
    scale: float = 0.2
    contrast: float = 1.5
    octaves: int = 4
    seed: int = 0
    roughness: float = 0.55

    def pattern(self, points: np.ndarray) -> np.ndarray:
        """(N,) pattern value in [0, 1] at (N, 3) world points."""
        p = np.asarray(points, np.float64) / self.scale
        detail = fbm(p * 2.0, self.seed + 7, self.octaves, gain=self.roughness)
        if self.kind == "noise":
            s = fbm(p, self.seed, self.octaves, gain=self.roughness)
        elif self.kind == "checker":
            cells = np.floor(p).astype(np.int64).sum(axis=1) & 1
            s = 0.75 * cells + 0.25 * detail
        elif self.kind == "stripes":
            warp = fbm(p * 0.5, self.seed + 3, 2)
            phase = p @ np.array([0.83, 0.31, 0.46]) + 1.5 * warp
            s = 0.7 * (0.5 + 0.5 * np.sin(2 * np.pi * phase)) + 0.3 * detail
        elif self.kind == "blobs":
            field = fbm(p, self.seed, 3)
            s = 0.7 * _smooth_step(0.45, 0.55, field) + 0.3 * detail
        elif self.kind == "weak":
            s = fbm(p * 0.25, self.seed, 2)
        else:
            raise ValueError(f"unknown texture kind {self.kind!r}; expected one of {KINDS}")
        s = 0.5 + (s - 0.5) * self.contrast
        return np.clip(s, 0.0, 1.0)

    def albedo(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) linear RGB albedo in [0, 1] at (N, 3) world points."""
        s = self.pattern(points)[:, None]
        a = np.asarray(self.color_a, np.float64)
        b = np.asarray(self.color_b, np.float64)
        return (1.0 - s) * a + s * b


def _smooth_step(lo: float, hi: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - lo) / (hi - lo), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)
