"""What a named panel of the rerun web viewer shows, read from a screenshot (for the replay browser tests).

egui draws the whole viewer into one canvas, so there is no DOM to query: a panel is found from the blueprint the
viewer was given and the screenshot. The blueprint gives where the panel named ``003 · depth (m)`` lies as fractions of
the panel area (egui_tiles' shares, an automatic grid's columns as egui_tiles chooses them, a tab container showing its
active tab); the screenshot
gives the panel area (between the top bar's and the time panel's separator lines) and the exact panel, the nearest
of rerun's 1-px separator lines (light theme) on each side of that point. Then:

- :func:`colormap_share`: how much of a panel's body is drawn in a map's colour scale (matplotlib's, which rerun's
  turbo, viridis, magma and inferno follow): a map is shown, not an empty "No data available." panel;
- :func:`text_lines`: how many lines of dark text a panel shows: the explanation of a map the recording lacks,
  not a one-line "(empty)".
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
from collections.abc import Iterator

import numpy as np

SEPARATOR = (223, 223, 223)  # the 1-px lines between rerun's panels and below its top bar (light theme)
TITLE_BAR_PX = 30  # a panel's title bar (name and buttons) above its body
COLOUR_TOLERANCE = 24.0  # RGB distance within which a pixel counts as a colour of the scale (rounding, blending)


@dataclasses.dataclass(frozen=True)
class Box:
    """A rectangle of pixels [x0, x1) × [y0, y1) of a screenshot; ``header_px``: the rows at its top that are title
    and tab bars, not the panel's content."""

    x0: int
    y0: int
    x1: int
    y1: int
    header_px: int = TITLE_BAR_PX

    def pixels(self, shot: np.ndarray) -> np.ndarray:
        """The (h, w, 3) pixels of ``shot`` inside the box."""
        return shot[self.y0:self.y1, self.x0:self.x1, :3]

    def body(self) -> Box:
        """The box without its header and its outer pixel: what the panel draws its content in."""
        return Box(self.x0 + 1, min(self.y0 + self.header_px, self.y1), self.x1 - 1, self.y1 - 1, 0)


@dataclasses.dataclass(frozen=True)
class Placement:
    """Where the blueprint puts a panel: fractions of the panel area, and the tab bars drawn above its title bar."""

    x0: float
    y0: float
    x1: float
    y1: float
    tab_bars: int = 0


def _split(start: float, stop: float, shares: list[float] | None, count: int) -> list[tuple[float, float]]:
    weights = list(shares) if shares else [1.0] * count
    total = sum(weights) or 1.0
    edges = np.cumsum([0.0] + weights) / total
    return [(start + (stop - start) * a, start + (stop - start) * b) for a, b in zip(edges, edges[1:], strict=False)]


def _is_container(item) -> bool:
    return isinstance(getattr(item, "contents", None), (list, tuple)) and bool(getattr(item, "kind", None))


#: egui_tiles' automatic grid: the tile aspect ratio (width / height) it aims at (``Behavior::ideal_tile_aspect_ratio``)
IDEAL_TILE_ASPECT = 4 / 3


def grid_columns(count: int, aspect: float | None) -> int:
    """Columns of egui_tiles' automatic grid of ``count`` tiles in a box of ``aspect`` (width / height, pixels): the
    count whose tiles come nearest to :data:`IDEAL_TILE_ASPECT`, each empty cell costing as much as an aspect off by
    2 / ``count`` (``num_columns_heuristic``; 8 maps in a wide box take 4 × 2, not 3 × 3); without an aspect,
    ⌈√count⌉."""
    if aspect is None:
        return math.ceil(math.sqrt(count))
    best, best_loss = 1, math.inf
    for columns in range(1, count + 1):
        rows = math.ceil(count / columns)
        loss = abs(IDEAL_TILE_ASPECT - aspect * rows / columns) * count + 2.0 * (columns * rows - count)
        if loss < best_loss:
            best, best_loss = columns, loss
    return best


def _place(item, box: Placement, out: dict[str, Placement], aspect: float | None = None) -> None:
    """Place ``item`` (an rrb container or view) in ``box``; a child not at the box's top loses its tab bars.
    ``aspect``: the whole panel area's width / height in pixels (for an automatic grid's columns), if known."""
    if not _is_container(item):
        out[item.name] = box
        return
    contents, kind = item.contents, str(item.kind)
    if "Horizontal" in kind:
        for child, (a, b) in zip(contents, _split(box.x0, box.x1, item.column_shares, len(contents)), strict=True):
            _place(child, Placement(a, box.y0, b, box.y1, box.tab_bars), out, aspect)
    elif "Vertical" in kind:
        for i, (child, (a, b)) in enumerate(zip(contents, _split(box.y0, box.y1, item.row_shares, len(contents)),
                                                strict=True)):
            _place(child, Placement(box.x0, a, box.x1, b, box.tab_bars if i == 0 else 0), out, aspect)
    elif "Grid" in kind:
        box_aspect = None if aspect is None else aspect * (box.x1 - box.x0) / max(box.y1 - box.y0, 1e-9)
        columns = item.grid_columns or grid_columns(len(contents), box_aspect)
        rows = math.ceil(len(contents) / columns)
        xs, ys = _split(box.x0, box.x1, None, columns), _split(box.y0, box.y1, None, rows)
        for i, child in enumerate(contents):
            (left, right), (top, bottom) = xs[i % columns], ys[i // columns]
            _place(child, Placement(left, top, right, bottom, box.tab_bars if i < columns else 0), out, aspect)
    else:  # tabs: the active one fills the container; a view's tab is its title, a container's is one bar more
        child = contents[item.active_tab or 0]
        _place(child, dataclasses.replace(box, tab_bars=box.tab_bars + _is_container(child)), out, aspect)


def layout_fractions(blueprint, aspect: float | None = None) -> dict[str, Placement]:
    """The panels an ``rrb.Blueprint`` shows, by title, placed as fractions of the panel area (``aspect``: its
    width / height in pixels, for the columns of an automatic grid: :func:`grid_columns`)."""
    out: dict[str, Placement] = {}
    _place(blueprint.root_container, Placement(0.0, 0.0, 1.0, 1.0), out, aspect)
    return out


def separators(shot: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels of rerun's separator colour."""
    return np.all(shot[..., :3] == SEPARATOR, axis=-1)


def panel_area(shot: np.ndarray) -> Box:
    """The part of the page the blueprint's panels share: below the top bar, above the time panel (the first two
    rows of separator colour across the page; a notification may cover part of the top one)."""
    share = separators(shot).mean(axis=1)
    top = next((int(y) for y in np.nonzero(share > 0.6)[0] if y < 80), 0)
    bottom = next((int(y) for y in np.nonzero(share > 0.95)[0] if y > top + 50), shot.shape[0])
    return Box(0, top + 1, shot.shape[1], bottom)


def _edge(lines: np.ndarray, centre: int, step: int, limit: int) -> int:
    """The first index from ``centre`` towards ``limit`` (by ``step``) where ``lines`` (a share per row or column of
    separator pixels) says a separator line crosses, or ``limit``."""
    for i in range(centre, limit, step):
        if lines[i] > 0.6:
            return i
    return limit


def find_panel(shot: np.ndarray, blueprint, title: str) -> Box:
    """The box of the panel titled ``title``: the nearest separator lines around the point where the blueprint puts
    that panel's centre. Raises AssertionError when the blueprint has no such panel or the box found is not where
    the blueprint puts it (the viewer shows another layout, or none)."""
    area = panel_area(shot)
    fractions = layout_fractions(blueprint, (area.x1 - area.x0) / max(area.y1 - area.y0, 1))
    assert title in fractions, f"no panel {title!r} in the layout (it shows {sorted(fractions)})"
    place = fractions[title]
    fx0, fy0, fx1, fy1 = place.x0, place.y0, place.x1, place.y1
    width, height = area.x1 - area.x0, area.y1 - area.y0
    want = Box(area.x0 + round(fx0 * width), area.y0 + round(fy0 * height),
               area.x0 + round(fx1 * width), area.y0 + round(fy1 * height))
    cx, cy = (want.x0 + want.x1) // 2, (want.y0 + want.y1) // 2
    lines = separators(shot)
    # the middle half of the expected box: a separator line crosses it whole, an image or a glyph does not
    qx, qy = (want.x1 - want.x0) // 4, (want.y1 - want.y0) // 4
    columns = lines[want.y0 + qy:want.y1 - qy].mean(axis=0)
    rows = lines[:, want.x0 + qx:want.x1 - qx].mean(axis=1)
    found = Box(_edge(columns, cx, -1, area.x0 - 1) + 1, _edge(rows, cy, -1, area.y0 - 1) + 1,
                _edge(columns, cx, 1, area.x1), _edge(rows, cy, 1, area.y1), TITLE_BAR_PX * (1 + place.tab_bars))
    slack_x, slack_y = 0.1 * width, 0.1 * height  # tab bars, margins and rounding move edges a little
    assert (abs(found.x0 - want.x0) <= slack_x and abs(found.x1 - want.x1) <= slack_x
            and abs(found.y0 - want.y0) <= slack_y and abs(found.y1 - want.y1) <= slack_y), \
        f"panel {title!r}: found {found}, the layout puts it at {want}"
    return found


def colormap_share(pixels: np.ndarray, colormap: str) -> float:
    """The share of ``pixels`` ((h, w, 3) RGB) within COLOUR_TOLERANCE of a colour of matplotlib's ``colormap``."""
    from matplotlib import colormaps  # lazy: matplotlib

    scale = (colormaps[colormap](np.linspace(0, 1, 256))[:, :3] * 255).astype(np.float32)
    flat = pixels.reshape(-1, 3).astype(np.float32)
    if not len(flat):
        return 0.0
    nearest = np.min(((flat[:, None, :] - scale[None]) ** 2).sum(-1), axis=1)
    return float(np.mean(nearest <= COLOUR_TOLERANCE ** 2))


def text_lines(pixels: np.ndarray, dark: int = 120) -> int:
    """How many lines of dark, colourless text ``pixels`` ((h, w, 3) RGB, a light panel) hold: runs of rows with
    dark grey pixels, split by at least two rows without any."""
    rgb = pixels.astype(np.int16)
    ink = (rgb.max(-1) < dark) & (np.ptp(rgb, axis=-1) < 40)
    rows = ink.sum(axis=1) >= 2
    lines, gap = 0, 2
    for has_ink in rows:
        if has_ink and gap >= 2:
            lines += 1
        gap = 0 if has_ink else gap + 1
    return lines


def map_problem(pixels: np.ndarray, colormap: str, min_share: float = 0.6) -> str | None:
    """None when a panel body's ``pixels`` show a map in ``colormap``: at least ``min_share`` of them in its colours
    and the picture not one flat colour; else what they show instead."""
    rgb = pixels.reshape(-1, 3)
    share = colormap_share(pixels, colormap)
    if share < min_share:
        return (f"{share:.0%} of the panel in {colormap} colours (want {min_share:.0%}); "
                f"mean colour {rgb.mean(0).round()}")
    white = np.all(pixels >= 250, axis=-1)  # the panel's background around the letterboxed picture
    ys, xs = np.nonzero(~white)
    picture = pixels[ys.min():ys.max() + 1, xs.min():xs.max() + 1].reshape(-1, 3).astype(np.float64)
    median = np.median(picture, axis=0)
    if np.mean(np.abs(picture - median).max(axis=1) <= 12) >= 0.97:  # anti-aliased edges aside, one colour
        return f"one flat colour {median} where the map should be"
    return None


def explanation_problem(pixels: np.ndarray, min_lines: int = 2) -> str | None:
    """None when a panel body's ``pixels`` show at least ``min_lines`` lines of text and no map (the text panel of a
    map the recording lacks); else what they show instead."""
    lines = text_lines(pixels)
    light = np.all(pixels >= 200, axis=-1).mean()
    if lines < min_lines or light < 0.7:
        return f"{lines} lines of text on a {light:.0%} light panel (want an explanation of {min_lines}+ lines)"
    return None


def panels_match(a: np.ndarray | None, b: np.ndarray | None, level: int = 8, share: float = 0.002) -> bool:
    """True when two screenshots of a panel (RGB arrays) show the same picture: the same size, and at most ``share``
    of the pixels differ by more than ``level`` in a channel (egui draws the same state the same way; blending and a
    blinking cursor aside). None (the panel was not on the page) matches only None."""
    if a is None or b is None:
        return a is None and b is None
    if a.shape != b.shape:
        return False
    differs = np.abs(a.astype(np.int16) - b.astype(np.int16)).max(axis=-1) > level
    return float(differs.mean()) <= share


def settled_from(shots: list[np.ndarray | None], **tolerance) -> int:
    """The index of the first of ``shots`` (a panel's screenshots in the order taken) from which every later one
    matches the last (:func:`panels_match`): when the panel reached its final state, as far as these shots tell."""
    if not shots:
        raise ValueError("no screenshots")
    final, index = shots[-1], len(shots) - 1
    while index > 0 and panels_match(shots[index - 1], final, **tolerance):
        index -= 1
    return index


@contextlib.contextmanager
def following(name: str = "iterations") -> Iterator[None]:
    """While open, the layout ``name`` of ``layouts.LAYOUTS`` has a time panel that follows the newest data, as a live
    run's does, instead of opening paused at the start as ``deepc replay`` does: for a benchmark or a screenshot of
    a recording's last iteration (``WebViewer`` writes its layout files when it starts)."""
    from layouts import LAYOUTS

    layout = LAYOUTS[name]
    LAYOUTS[name] = lambda contents, view: layout(dataclasses.replace(contents, live=True), view)
    try:
        yield
    finally:
        LAYOUTS[name] = layout
