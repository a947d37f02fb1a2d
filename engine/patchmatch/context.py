"""Everything the kernels need about one reference view at one level, computed once per pass."""

from __future__ import annotations

import dataclasses

import numpy as np

from engine.camera import Camera
from engine.patchmatch.geometry import relative_geometry
from engine.patchmatch.ncc import bilateral_moments, pad_sources, window_offsets_2d
from engine.patchmatch.options import PatchMatchOptions


@dataclasses.dataclass
class ViewContext:
    """Reference-side NCC terms, padded source images and ref->source geometry.

    Shapes: kinv (9,); wgt, wa (H, W, S) f32; mu_a, var_a (H, W) f32; offs (S, 2) i32;
    src (N, Hm+1, Wm+1) f32 and its ravel ``flat``; sizes (N, 2) i32 (W, H); ox, oy (S,) f32 offsets;
    A, B (N, 9), b, c, centers (N, 3) f64;
    sdepth (N, Hm, Wm) f32 source depth maps (zeros of shape (N, 1, 1) when not needed).
    """

    kinv: np.ndarray
    wgt: np.ndarray
    wa: np.ndarray
    mu_a: np.ndarray
    var_a: np.ndarray
    offs: np.ndarray
    src: np.ndarray
    sizes: np.ndarray
    A: np.ndarray
    b: np.ndarray
    B: np.ndarray
    c: np.ndarray
    centers: np.ndarray
    sdepth: np.ndarray
    ox: np.ndarray
    oy: np.ndarray
    flat: np.ndarray

    @property
    def stride(self) -> int:
        return int(self.src.shape[2])

    @property
    def plane(self) -> int:
        return int(self.src.shape[1] * self.src.shape[2])

    @property
    def num_sources(self) -> int:
        return int(self.A.shape[0])


def weighting_sigma(options: PatchMatchOptions) -> float:
    """Colour sigma in the units of the chosen weighting."""
    return options.sigma_color if options.ncc_weighting == "colmap" else options.acmm_sigma_color


def build_context(ref_img: np.ndarray, ref_cam: Camera, src_imgs: list[np.ndarray], src_cams: list[Camera],
                  options: PatchMatchOptions, src_depths: list[np.ndarray] | None = None) -> ViewContext:
    """Precompute the :class:`ViewContext` of one reference view (images float32 in [0, 1])."""
    offs = window_offsets_2d(options.window_offsets())
    wgt, wa, mu_a, var_a = bilateral_moments(ref_img, offs, options.ncc_weighting, options.sigma_spatial,
                                             weighting_sigma(options))
    src, sizes = pad_sources(src_imgs)
    geo = relative_geometry(ref_cam, src_cams)
    if src_depths is None:
        sdepth = np.zeros((len(src_imgs), 1, 1), np.float32)
    else:
        sdepth = np.zeros((len(src_imgs), src.shape[1] - 1, src.shape[2] - 1), np.float32)
        for j, d in enumerate(src_depths):
            sdepth[j, : d.shape[0], : d.shape[1]] = d
    return ViewContext(geo["kinv"], wgt, wa, mu_a, var_a, offs, src, sizes, geo["A"], geo["b"], geo["B"],
                       geo["c"], geo["centers"], sdepth, offs[:, 0].astype(np.float32), offs[:, 1].astype(np.float32),
                       src.reshape(-1))
