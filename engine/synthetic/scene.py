"""Plain data of a synthetic scene: the recipe (:class:`SceneRecipe`) and what rendering it gives
(:class:`SceneData`).

World frame: right-handed, z up, metres. Cameras follow COLMAP (``X_cam = R X_world + t``,
x right, y down, z forward) and :class:`engine.core.camera.Camera` conventions.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from engine.core.camera import Camera
from engine.core.options import Options, option
from engine.synthetic.raycast import Primitive
from engine.synthetic.texture import Texture


@dataclasses.dataclass
class RenderSettings(Options):
    """How views are rendered (everything after the geometry; all ours)."""

    supersample: int = option(3, "anti-aliasing: s x s colour samples per pixel (depth uses the pixel centre)",
                              source="ours", low=1, high=8)
    ambient: float = option(0.35, "ambient light (fraction of albedo)", source="ours")
    sun: float = option(0.75, "directional light intensity", source="ours")
    shadows: bool = option(True, "cast shadows of the directional light", source="ours")
    shadow_strength: float = option(0.7, "fraction of the directional light a shadow removes", source="ours", low=0,
                                    high=1)
    exposure: float = option(1.0, "linear gain before clipping and gamma", source="ours")
    gamma: float = option(2.2, "display gamma (encoded = linear ** (1 / gamma))", source="ours", above=0)
    noise_sigma: float = option(1.5, "Gaussian sensor noise, standard deviation", unit="8-bit grey levels",
                                source="ours", low=0)
    blur_sigma: float = option(0.0, "Gaussian optical blur (0 = none)", unit="px", source="ours", low=0)
    jpeg_quality: int = option(0, "JPEG round trip at this quality, 1-95 (0 = none)", source="ours", low=0, high=95)


@dataclasses.dataclass
class SparseSettings(Options):
    """How the SfM-like sparse model is drawn from the ground truth (all ours)."""

    cell_size: int = option(8, "one feature per cell of this side (the best-textured pixel)", unit="px",
                            source="ours", low=2)
    border: int = option(3, "no features this close to the image border", unit="px", source="ours")
    min_score: float = option(4.0, "minimum gradient magnitude of a feature", unit="grey levels / px", source="ours")
    depth_tolerance: float = option(0.005, "relative GT-depth agreement for a point to count as visible",
                                    source="ours", above=0)
    min_views: int = option(2, "keep points observed in at least this many views", source="ours", low=2)
    noise_px: float = option(0.3, "standard deviation of 2-D observation noise, clipped at 2 sigma", unit="px",
                             source="ours")
    noise_rel_3d: float = option(0.001, "standard deviation of 3-D position noise relative to depth, clipped at 2 "
                                 "sigma", source="ours")
    neighbours: int = option(0, "look for a feature only in the views this many places either side of its own "
                             "(0 = all)", source="ours", low=0)


@dataclasses.dataclass
class SceneRecipe:
    """A renderable recipe.

    Attributes:
        name: scene name (folder name when exported).
        seed: seed of all random draws made while rendering (noise, sparse features).
        primitives: geometry; the list index is the primitive id.
        textures: one texture per primitive.
        light_dir: (3,) unit direction *towards* the directional light (world).
        sky_horizon, sky_zenith: linear RGB of the sky gradient.
        cameras: one :class:`Camera` per view.
        image_names: one name per view (as in the COLMAP model).
        render, sparse: settings.
        gt_voxel: voxel size (metres) for thinning the GT point cloud.
        description: one paragraph for the README.
        recipe: how to rebuild it (function and arguments), for the README.
    """

    name: str
    seed: int
    primitives: list[Primitive]
    textures: list[Texture]
    light_dir: np.ndarray
    sky_horizon: tuple
    sky_zenith: tuple
    cameras: list[Camera]
    image_names: list[str]
    render: RenderSettings = dataclasses.field(default_factory=RenderSettings)
    sparse: SparseSettings = dataclasses.field(default_factory=SparseSettings)
    gt_voxel: float = 0.02
    description: str = ""
    recipe: str = ""

    def __post_init__(self) -> None:
        if len(self.textures) != len(self.primitives):
            raise ValueError("one texture per primitive is required")
        if len(self.image_names) != len(self.cameras):
            raise ValueError("one image name per camera is required")
        self.light_dir = np.asarray(self.light_dir, np.float64) / np.linalg.norm(self.light_dir)
        self.render.validate()
        self.sparse.validate()


@dataclasses.dataclass
class SparseModel:
    """An SfM-like sparse model: P points and M observations.

    Attributes:
        xyz: (P, 3) float64 world positions (perturbed like SfM output).
        rgb: (P, 3) uint8 colours.
        obs_point: (M,) int64 index into ``xyz`` of each observation.
        obs_view: (M,) int64 view index of each observation.
        obs_xy: (M, 2) float64 continuous image coordinates (COLMAP: pixel centres at +0.5), perturbed.
    """

    xyz: np.ndarray
    rgb: np.ndarray
    obs_point: np.ndarray
    obs_view: np.ndarray
    obs_xy: np.ndarray

    @property
    def num_points(self) -> int:
        return len(self.xyz)

    def track_lengths(self) -> np.ndarray:
        """(P,) number of observations of each point."""
        return np.bincount(self.obs_point, minlength=self.num_points)


@dataclasses.dataclass
class SceneData:
    """A rendered scene with exact ground truth (V views of H x W pixels).

    Attributes:
        scene: the recipe it came from.
        images: V x (H, W, 3) uint8 RGB.
        depths: V x (H, W) float32 GT camera z-depth, 0 where nothing is hit (sky).
        normals: V x (H, W, 3) float32 GT unit normals in the view's camera frame, facing the camera
            (zeros for sky).
        prim_ids: V x (H, W) int32 primitive id per pixel, -1 for sky.
        sparse: the sparse model.
        gt_points: (G, 3) float64 GT surface points (world), voxel-thinned union of all views.
    """

    scene: SceneRecipe
    images: list[np.ndarray]
    depths: list[np.ndarray]
    normals: list[np.ndarray]
    prim_ids: list[np.ndarray]
    sparse: SparseModel
    gt_points: np.ndarray

    @property
    def cameras(self) -> list[Camera]:
        return self.scene.cameras

    @property
    def image_names(self) -> list[str]:
        return self.scene.image_names

    def coverage(self) -> float:
        """Fraction of pixels (all views) with GT depth."""
        return float(np.mean([np.mean(d > 0) for d in self.depths]))
