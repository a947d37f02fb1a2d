"""Fusion thresholds (``FusionOptions``) and the named parameter sets (``FUSION_PRESETS``)."""

from __future__ import annotations

import dataclasses

from engine.options import Options, check, option


@dataclasses.dataclass
class FusionOptions(Options):
    """COLMAP-style fusion thresholds (SPEC.md §7, §12 ``fusion``); defaults = DeepC ETH3D high-res."""

    max_reproj_error: float = option(1.0, "largest reprojection error of the seed point in a fused view",
                                     metavar="PX")
    max_depth_error: float = option(0.01, "largest relative depth difference |z_proj - z| / z", metavar="REL")
    max_normal_error: float = option(20.0, "largest angle between a fused pixel's normal and the seed normal",
                                     metavar="DEGREES")
    min_num_pixels: int = option(3, "fewest fused pixels (seed included) for a point to be kept", metavar="N")
    max_num_pixels: int = option(10000, "stop a traversal after this many pixels", metavar="N")
    max_traversal_depth: int = option(100, "longest chain of views a traversal may follow", metavar="N")
    check_num_images: int = option(50, "overlapping views (most shared sparse points) searched per view",
                                   metavar="N")
    point_per_pixel: bool = option(False, "emit every pixel of a kept cluster as its own point instead of "
                                   "the cluster's median point (not COLMAP's behaviour)")

    def validate(self) -> FusionOptions:
        super().validate()
        check(self.max_reproj_error >= 0, "max_reproj_error", self.max_reproj_error, "must be >= 0")
        check(self.max_depth_error >= 0, "max_depth_error", self.max_depth_error, "must be >= 0")
        check(0 <= self.max_normal_error <= 180, "max_normal_error", self.max_normal_error,
              "must be in [0, 180] degrees")
        check(self.min_num_pixels >= 0, "min_num_pixels", self.min_num_pixels, "must be >= 0")
        check(self.max_num_pixels >= max(1, self.min_num_pixels), "max_num_pixels", self.max_num_pixels,
              "must be >= 1 and >= min_num_pixels")
        check(self.max_traversal_depth > 0, "max_traversal_depth", self.max_traversal_depth, "must be > 0")
        check(self.check_num_images > 0, "check_num_images", self.check_num_images, "must be > 0")
        return self



FUSION_PRESETS: dict[str, FusionOptions] = {
    # COLMAP's own defaults.
    "colmap": FusionOptions(max_reproj_error=2.0, max_depth_error=0.01, max_normal_error=10.0, min_num_pixels=5),
    # "COLMAP fusion with ACMM parameters" (DeepC Table 1): reference + 2 consistent views.
    "acmm": FusionOptions(max_reproj_error=2.0, max_depth_error=0.01, max_normal_error=10.0, min_num_pixels=3),
    # DeepC vanilla / filtered maps, ETH3D high-res (Table 2 setting: 20 deg, 1 px, 2 supporting views).
    "deepc": FusionOptions(max_reproj_error=1.0, max_depth_error=0.01, max_normal_error=20.0, min_num_pixels=3),
    # DeepC on ETH3D low-res and Tanks and Temples: normal threshold quartered, 3 supporting views.
    "deepc_lowres": FusionOptions(max_reproj_error=1.0, max_depth_error=0.01, max_normal_error=5.0,
                                  min_num_pixels=4),
    # DeepC refined maps as SPEC.md §7.3 writes them: the paper's 5 deg, 3 pixels (the pixel count is [rec]).
    "refined_paper": FusionOptions(max_reproj_error=1.0, max_depth_error=0.01, max_normal_error=5.0,
                                   min_num_pixels=3),
    # Refined maps as --pipeline full fuses them: chosen on the four held-out synthetic scenes
    # (benchmarks/experiments/refined_fusion_sweep.py): a second pixel suffices, since the second network and the
    # depth/reprojection checks already test consistency (3 -> 2 px: F1 at 2 cm +3.7 to +7.9 points), and
    # 10 deg beats 5 deg on all four (+0.4 to +1.5): our refined normals at these resolutions are noisier
    # than the paper's (planar-normal error 5.5 deg mean on fountain_p11 768), so 5 deg splits true surfaces.
    "refined": FusionOptions(max_reproj_error=1.0, max_depth_error=0.01, max_normal_error=10.0, min_num_pixels=2),
    # What every pipeline fuses with by default (DEFAULT_PRESET). The paper's 1 px was set on ETH3D high-res
    # images (6048 px wide); at this tool's working sizes (<= 1536 px) a pixel is a 4-8x larger footprint,
    # and a 1 px radius around the seed's projection merges 2-3 neighbouring pixels of every view into one
    # median point: points are 2-3x sparser than the maps and blur across them. Half a pixel takes one
    # pixel per view, so the cloud keeps the maps' density, and a second agreeing view then suffices.
    # Chosen on the five held-out synthetic scenes (benchmarks/experiments/fusion_presets.py): F1 at 2 cm +2.8 to
    # +11.8 points over `deepc` on vanilla and fast maps, +1.6 to +8.5 over `refined` on refined maps,
    # never worse at 5 cm; the same on tiny, small and fountain_p11 (768, peer rule: 52.0 -> 54.9).
    "dense": FusionOptions(max_reproj_error=0.5, max_depth_error=0.01, max_normal_error=20.0, min_num_pixels=2),
    # What every pipeline fuses with by default (DEFAULT_PRESET): the clusters of `deepc`'s checks with a
    # second pixel enough, each pixel its own point. A cluster's median averages views whose cameras and
    # depths disagree slightly and leaves one point where the views sampled the surface n times; keeping the
    # verified pixels keeps every view's samples (3-4x the points of `dense`). Chosen on the five held-out
    # synthetic scenes (benchmarks/experiments/fusion_presets.py): F1 above `dense` on all five, on vanilla,
    # fast and full maps, at every tolerance (1 cm +3.9 to +12.1, 2 cm +1.4 to +5.1, 5 cm +0.6 to +2.1; accuracy at 2 cm
    # -2.3 to +0.5); with per-pixel points 1 px beats 0.5 px on all five. Also on tiny, small and
    # fountain_p11 (768, peer rule, vanilla: 54.9 -> 57.1 at 2 cm).
    "pixels": FusionOptions(max_reproj_error=1.0, max_depth_error=0.01, max_normal_error=20.0, min_num_pixels=2,
                            point_per_pixel=True),
}



DEFAULT_PRESET = "pixels"

