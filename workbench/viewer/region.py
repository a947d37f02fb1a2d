"""What the inspector's region re-run shows: the box's depth and error before | after, their colour scales, and
the numbers (depths changed, within 1 % of GT before and after) with enough digits that a change shows."""

from __future__ import annotations

from typing import Any

import numpy as np

from workbench.maps.images import colorize
from workbench.viewer.legends import Scale
from workbench.viewer.session import DEPTH_ERROR_PCT

REGION_TILE = 200  # longest side of each before/after map in the region picture
MAX_DIGITS = 3  # decimals the within-1 % figures may take to tell before from after


def region_scales(result: Any, depth_range: tuple[float, float]) -> list[Scale]:
    """The picture's colour scales: depth over the box's own 2-98 % range (a box spans a sliver of the view's
    ``depth_range``, the fallback), then the error against GT in % of the GT depth when there is GT."""
    both = np.concatenate([np.ravel(result.depth_before), np.ravel(result.depth_after)])
    both = both[np.isfinite(both) & (both > 0)]
    lo, hi = (float(v) for v in np.percentile(both, (2, 98))) if len(both) else depth_range
    if hi <= lo:
        lo, hi = depth_range
    digits = max(2, 1 - int(np.floor(np.log10(max(hi - lo, 1e-9)))))  # the ends differ in what is printed
    scales = [Scale("region depth, before | after", lo, hi, "turbo", "m", no_data="no estimate", digits=digits)]
    if result.error_before is not None and result.error_after is not None:
        scales.append(Scale("region depth error vs GT, % of the GT depth", 0.0, DEPTH_ERROR_PCT, "RdYlGn_r", "%",
                            no_data="no estimate or no GT", saturates=True, digits=1))
    return scales


def _tile(values: np.ndarray | None, lo: float, hi: float, cmap: str, invalid: np.ndarray | None) -> np.ndarray:
    from PIL import Image  # lazy: pillow

    if values is None:
        return np.full((REGION_TILE // 2, REGION_TILE, 3), 200, np.uint8)
    rgb = colorize(values, lo, hi, cmap, invalid)
    h, w = rgb.shape[:2]
    scale = max(1, REGION_TILE // max(h, w))
    return np.asarray(Image.fromarray(rgb).resize((w * scale, h * scale), Image.NEAREST))


def region_picture(result: Any, scales: list[Scale], pixel: tuple[int, int] | None) -> np.ndarray:
    """(H, W, 3) uint8: depth before | after on top, error before | after below (when known), each coloured by
    its scale of :func:`region_scales`; the inspected pixel in magenta."""
    rows = []
    pairs = [(result.depth_before, result.depth_after)]
    if len(scales) > 1:
        pairs.append((np.asarray(result.error_before) * 100, np.asarray(result.error_after) * 100))
    for (before, after), scale in zip(pairs, scales, strict=False):
        tiles = []
        for values in (before, after):
            values = np.asarray(values, np.float32)
            invalid = ~np.isfinite(values) | ((values <= 0) if scale.cmap == "turbo" else np.zeros_like(values, bool))
            tile = _tile(np.nan_to_num(values, nan=0.0), scale.vmin, scale.vmax, scale.cmap, invalid).copy()
            if pixel is not None:
                step = tile.shape[0] // values.shape[0]
                px, py = (pixel[0] - result.box[0]) * step, (pixel[1] - result.box[1]) * step
                tile[max(0, py - 1):py + step + 1, max(0, px - 1):px + step + 1] = (255, 0, 255)
            tiles.append(tile)
        gap = np.full((tiles[0].shape[0], 6, 3), 255, np.uint8)
        rows.append(np.concatenate([tiles[0], gap, tiles[1]], axis=1))
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 6), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows]
    return np.concatenate(rows, axis=0)


def change_text(before: float, after: float, unit: str = "%") -> str:
    """"61.76 % → 61.84 % (+0.08 points)": the fewest decimals (1 to ``MAX_DIGITS``) that tell the two apart,
    the change being the difference of the printed figures; "unchanged" when they are equal."""
    if before == after:
        return f"{before:.1f} {unit} (unchanged)"
    for digits in range(1, MAX_DIGITS + 1):
        old, new = f"{before:.{digits}f}", f"{after:.{digits}f}"
        if old != new:
            return f"{old} {unit} → {new} {unit} ({float(new) - float(old):+.{digits}f} points)"
    return f"{old} {unit} (changed by less than {10.0 ** -MAX_DIGITS:g} points)"


def region_markdown(result: Any) -> str:
    """The region's numbers: depth changed, within 1 % of GT before and after, time."""
    before, after = np.asarray(result.depth_before), np.asarray(result.depth_after)
    changed = 100.0 * float(np.count_nonzero(before != after)) / max(1, before.size)
    lines = [f"left: before · right: after · {changed:.1f} % of the box's depths changed"]
    if result.within_1pct_before is not None and result.within_1pct_after is not None:
        lines.append(f"within 1 % of GT: **{change_text(result.within_1pct_before, result.within_1pct_after)}**")
    else:
        lines.append("no GT depth: no error maps")
    lines.append(f"re-run took {float(result.seconds):.2f} s in the engine")
    return "  \n".join(lines)
