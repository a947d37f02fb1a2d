"""Both runs' compared depth maps as point clouds whose every point knows its pixel's case: what the viewer's
compare mode draws and colours (``deepc view RUN_A --compare RUN_B``).

Each compared view's two maps, at the pair's common size (:func:`engine.compare.comparison.common_depths`), are
back-projected through the view's camera rescaled to that size; a point carries the case of its pixel
(:func:`engine.compare.pixels.case_codes`), so the clouds are coloured by the comparison's own rule and never by a
second one. (The runs' fused clouds have no pixel of origin to take a case from; they are scored, not drawn.)
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from engine.compare.comparison import Comparison, ViewComparison, common_depths
from engine.compare.pixels import case_codes
from engine.io.images import resize_area

SIDES = ("a", "b")


@dataclasses.dataclass
class CaseCloud:
    """One run's compared pixels as points.

    Attributes:
        xyz: (N, 3) float32 world points, scene units.
        rgb: (N, 3) uint8 colour of the view's image at the point's pixel.
        case: (N,) uint8 case code of the pixel (1 + index in :data:`engine.compare.pixels.CASES`).
        view: (N,) int32 scene index of the view the point is a pixel of.
        pixel: (N, 2) int32 (column, row) of that pixel at the view's common size.
    """

    xyz: np.ndarray
    rgb: np.ndarray
    case: np.ndarray
    view: np.ndarray
    pixel: np.ndarray

    def __len__(self) -> int:
        return len(self.xyz)


def _view_points(comparison: Comparison, view: ViewComparison, step: int) -> dict[str, CaseCloud]:
    """Both runs' points of one view, every ``step``-th pixel in each direction."""
    depths = dict(zip(SIDES, common_depths(comparison.a, comparison.b, view.keys, view.size), strict=True))
    camera = comparison.scene.views[view.index].camera.rescaled(*view.size)
    image = np.asarray(comparison.scene.image(view.index), np.float32)
    if image.shape[1::-1] != view.size:
        image = resize_area(image, view.size)
    codes = case_codes(view.maps)[::step, ::step]
    rgb = (np.clip(image[::step, ::step], 0, 1) * 255 + 0.5).astype(np.uint8)
    rows, cols = np.mgrid[:view.size[1]:step, :view.size[0]:step]
    out = {}
    for side, depth in depths.items():
        world = camera.backproject(depth)[::step, ::step]
        keep = np.isfinite(world).all(axis=2)
        out[side] = CaseCloud(world[keep].astype(np.float32), rgb[keep], codes[keep],
                              np.full(int(keep.sum()), view.index, np.int32),
                              np.stack([cols[keep], rows[keep]], axis=1).astype(np.int32))
    return out


def pixel_step(comparison: Comparison, max_points: int) -> int:
    """The step (in pixels, both directions) that keeps at most ``max_points`` of all compared views' pixels."""
    pixels = sum(v.size[0] * v.size[1] for v in comparison.views)
    return max(1, math.ceil(math.sqrt(pixels / max_points)))


def case_clouds(comparison: Comparison, max_points: int = 200_000) -> dict[str, CaseCloud]:
    """"a" / "b" -> the run's compared pixels as a :class:`CaseCloud`, every view subsampled by one integer step
    (:func:`pixel_step`) so that each cloud has ``max_points`` points at most (a browser draws every point it is
    sent)."""
    step = pixel_step(comparison, max_points)
    parts = [_view_points(comparison, v, step) for v in comparison.views]
    return {side: CaseCloud(*(np.concatenate([getattr(p[side], f.name) for p in parts])
                              for f in dataclasses.fields(CaseCloud))) for side in SIDES}
