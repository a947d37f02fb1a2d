"""The pixel probe: what PatchMatch did at up to 64 pixels of one view, half-step by half-step.

``run_patchmatch(..., probe=PixelProbe(view, [(x, y), ...]))`` records, for every red-black iteration of every
pass and level, each probed pixel's hypothesis before and after the half-step of its colour, every candidate
the kernel weighed (``explain.explain_pixel``) and what decided (docs/probe_schema.md has the schema). The
probe is off unless given: the kernels are untouched and the hooks cost one ``is None`` test per half-step.

Pixels are given at full resolution (column x, row y of the view's image); at pyramid level ℓ a pixel is the
one whose centre contains (x + 0.5, y + 0.5)·Wℓ/W (``pyramid``'s pixel-centre convention), so several probed
pixels may share a coarse pixel (their traces then share those entries).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from engine.core.errors import DeepCError
from engine.core.words import plural
from engine.patchmatch.context import ViewContext
from engine.patchmatch.kernels import ACTIVE_DRAW, neighbourhood_changed
from engine.patchmatch.probe.explain import explain_pixel
from engine.patchmatch.records import KernelParams, SamplingPattern
from engine.patchmatch.rng import combine, uniform
from engine.patchmatch.state import ViewState

MAX_PROBE_PIXELS = 64


def level_pixel(x: int, y: int, width: int, height: int, level_width: int, level_height: int) -> tuple[int, int]:
    """The pixel of a (level_width, level_height) pyramid level that contains full-resolution pixel (x, y)'s
    centre (full resolution ``width`` x ``height``)."""
    return (min(int((x + 0.5) * level_width / width), level_width - 1),
            min(int((y + 0.5) * level_height / height), level_height - 1))


def _hypothesis(state: ViewState, x: int, y: int) -> dict[str, Any]:
    return {"depth": float(state.depth[y, x]), "normal": [float(c) for c in state.normal[y, x]],
            "cost": float(state.cost[y, x])}


def _skipped(state: ViewState, pattern: SamplingPattern, key: np.uint64, params: KernelParams, x: int, y: int
             ) -> bool:
    """Whether the half-step kernel's active set leaves pixel (x, y) alone (``kernels.half_step_kernel``): the
    active set is on in this iteration, neither the pixel nor a pixel it reads moved in its last update, and the
    pixel's random draw is not in the share still updated."""
    changed = state.changed
    if params.active_share < 0 or changed is None or changed[y, x]:
        return False
    pixel_key = np.uint64(combine(key, y * state.depth.shape[1] + x))  # a Python int from outside numba
    if uniform(pixel_key, ACTIVE_DRAW) < params.active_share:
        return False
    return not neighbourhood_changed(changed, pattern.offsets, x, y)


def parse_pixels(pixels: Any) -> list[tuple[int, int]]:
    """Validated, de-duplicated (x, y) integer pairs (order kept); :class:`DeepCError` on anything else."""
    try:
        pairs = [tuple(p) for p in pixels]
    except TypeError:
        raise DeepCError(f"probe: pixels must be (x, y) pairs, got {pixels!r}") from None
    out: list[tuple[int, int]] = []
    for p in pairs:
        if len(p) != 2 or not all(isinstance(c, (int, np.integer)) and not isinstance(c, bool) for c in p):
            raise DeepCError(f"probe: a pixel is two integers (x, y), got {p!r}")
        xy = (int(p[0]), int(p[1]))
        if xy not in out:
            out.append(xy)
    if not out:
        raise DeepCError("probe: no pixel given")
    if len(out) > MAX_PROBE_PIXELS:
        raise DeepCError(f"probe: {len(out)} pixels, at most {MAX_PROBE_PIXELS} per view")
    return out


class PixelProbe:
    """Traces of up to :data:`MAX_PROBE_PIXELS` pixels of view ``view`` (index into the views given to
    ``run_patchmatch``); ``pixels``: (x, y) at full resolution (column, row). Bad pixels or views raise a
    one-line :class:`DeepCError` (here, or when the run binds the probe to its views)."""

    def __init__(self, view: int, pixels: list[tuple[int, int]]):
        if isinstance(view, bool) or not isinstance(view, (int, np.integer)) or view < 0:
            raise DeepCError(f"probe: view must be a view index >= 0, got {view!r}")
        self.view = int(view)
        self.pixels = parse_pixels(pixels)
        self.view_name: str | None = None
        self.width = self.height = 0
        self.source_names: list[str] = []
        self._entries: dict[tuple[int, int], list[dict[str, Any]]] = {p: [] for p in self.pixels}
        self._final: dict[tuple[int, int], dict[str, Any] | None] = {p: None for p in self.pixels}

    def bind(self, names: list[str], sizes: list[tuple[int, int]], sources: list[list[int]]) -> None:
        """Check the probe against the run's views (``names``, full-resolution ``sizes`` (W, H), source indices)
        and forget earlier traces."""
        if self.view >= len(names):
            raise DeepCError(f"probe: view {self.view} does not exist (the scene has {plural(len(names), 'view')}, "
                             f"0-{len(names) - 1})")
        self.view_name = names[self.view]
        self.width, self.height = sizes[self.view]
        for x, y in self.pixels:
            if not (0 <= x < self.width and 0 <= y < self.height):
                raise DeepCError(f"probe: pixel ({x}, {y}) is outside view {self.view_name} "
                                 f"({self.width}x{self.height}: x 0-{self.width - 1}, y 0-{self.height - 1})")
        self.source_names = [names[j] for j in sources[self.view]]
        for p in self.pixels:
            self._entries[p] = []
            self._final[p] = None

    def pass_probe(self, level: int, pass_index: int, level_width: int, level_height: int, detail: bool,
                   origin: tuple[int, int] = (0, 0), shape: tuple[int, int] | None = None) -> PassProbe:
        """The hook of one pass of the probed view (``view_pass.run_view_level(probe=...)``) at a level of
        ``level_width`` x ``level_height`` pixels; a pass over a crop of it gives the crop's ``origin`` (x, y)
        and ``shape`` (h, w): pixels outside the crop are not traced."""
        return PassProbe(self, level, pass_index, level_width, level_height, detail, origin, shape)

    def record(self, pixel: tuple[int, int], entry: dict[str, Any]) -> None:
        self._entries[pixel].append(entry)

    def set_final(self, pixel: tuple[int, int], final: dict[str, Any]) -> None:
        """The pixel's ``final`` entry (filled by the pipeline or ``engine.run.probe``, which know the later
        stages)."""
        self._final[pixel] = final

    def traces(self) -> list[dict[str, Any]]:
        """One dict per pixel (docs/probe_schema.md): ``view``, ``view_index``, ``x``, ``y``, ``width``,
        ``height``, ``source_views``, ``iterations`` (run order) and ``final``."""
        out = []
        for p in self.pixels:
            entries = self._entries[p]
            final = self._final[p]
            if final is None and entries:
                last = entries[-1]["after"]
                final = {"depth": last["depth"], "normal": last["normal"], "cost": last["cost"],
                         "counter_verdicts": None, "confidence": None, "gt_depth": None, "label": None,
                         "error": None}
            out.append({"view": self.view_name, "view_index": self.view, "x": p[0], "y": p[1],
                        "width": self.width, "height": self.height, "source_views": list(self.source_names),
                        "iterations": list(entries), "final": final})
        return out


class PassProbe:
    """One pass of the probed view: explains its pixels before each half-step of their colour and records
    the hypothesis the kernel wrote after it."""

    def __init__(self, probe: PixelProbe, level: int, pass_index: int, level_width: int, level_height: int,
                 detail: bool, origin: tuple[int, int] = (0, 0), shape: tuple[int, int] | None = None):
        self.probe, self.level, self.pass_index, self.detail = probe, level, pass_index, detail
        self.origin = origin
        h, w = shape if shape is not None else (level_height, level_width)
        # probed pixels by their pixel in the pass's maps (the level's, or a crop's at ``origin``)
        self.at_level: dict[tuple[int, int], list[tuple[int, int]]] = {}
        for p in probe.pixels:
            qx, qy = level_pixel(p[0], p[1], probe.width, probe.height, level_width, level_height)
            q = (qx - origin[0], qy - origin[1])
            if 0 <= q[0] < w and 0 <= q[1] < h:
                self.at_level.setdefault(q, []).append(p)
        self._start: dict[tuple[int, int], tuple] = {}
        self._pending: dict[tuple[int, int], dict[str, Any]] = {}

    def start(self, state: ViewState) -> None:
        """The pass's starting hypotheses (the upsampled ones in a detail-restorer pass)."""
        self._start = {(x, y): (float(state.depth[y, x]), tuple(float(c) for c in state.normal[y, x]))
                       for x, y in self.at_level}

    def before(self, state: ViewState, ctx: ViewContext, colour: int, cpre: np.ndarray, pattern: SamplingPattern,
               key: np.uint64, params: KernelParams, iteration: int) -> None:
        """Explain the pixels of ``colour`` from the state the half-step starts from."""
        names = self.probe.source_names
        for x, y in self.at_level:
            if (x + y) % 2 != colour:  # a crop's colours are its own (x, y)
                continue
            ex = explain_pixel(state.maps(), state.view_costs, ctx.reference_windows(), ctx.source_images(),
                               pattern, key, params, cpre, x, y)
            current = ex["candidates"][0]
            if self.detail and (current["depth"], tuple(current["normal"])) == self._start.get((x, y)):
                current["origin"] = "upsampled"
            selected = [names[j] for j in ex["selected"]]
            for c in ex["candidates"]:
                c["selected_views"] = selected
                c["view_weights"] = ex["view_weights"]
            skipped = _skipped(state, pattern, key, params, x, y)
            if skipped:  # the kernel leaves the pixel alone: its hypothesis stays, whatever the candidates cost
                ex["winner"], ex["decided_by"] = 0, "active_set"
            self._pending[(x, y)] = {
                "level": self.level, "pass": self.pass_index, "pass_kind": "geometric" if params.geometric
                else "photometric", "iteration": iteration, "colour": colour, "x_level": x + self.origin[0],
                "y_level": y + self.origin[1],
                "before": _hypothesis(state, x, y), "after": None, "candidates": ex["candidates"],
                "winner": ex["winner"], "decided_by": ex["decided_by"], "skipped": skipped,
                "source_views": list(names),
                "view_weights": ex["view_weights"], "selected_views": selected,
                "detail_restorer_reference": ex["restorer_reference"], "perturbation": params.perturbation,
                "min_improvement": params.min_improvement}

    def after(self, state: ViewState, colour: int) -> None:
        """Record what the kernel wrote for the pixels explained before this half-step."""
        for (x, y), entry in list(self._pending.items()):
            if entry["colour"] != colour:
                continue
            after = _hypothesis(state, x, y)
            entry["after"] = after
            win = entry["candidates"][entry["winner"]]
            # the explainer follows the kernel's decisions: its winner is the hypothesis the kernel stored
            entry["explained"] = bool(np.array_equal(np.float32([win["depth"], *win["normal"]]),
                                                     np.float32([after["depth"], *after["normal"]])))
            for p in self.at_level[(x, y)]:
                self.probe.record(p, entry)
            del self._pending[(x, y)]
