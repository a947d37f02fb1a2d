"""The colours of a comparison: one palette of the pixel cases (:data:`engine.compare.pixels.CASES`) for the
report's maps and the viewer's compare mode, and the viewer's per-point colour arrays, made once per colouring so
that switching colourings only sends arrays already made.

Colourings: "who is right" (each case its colour; where GT is missing, agree or disagree), "disagreement"
(where the runs differ by the comparison's rule — one right and the other wrong, or disagreeing without GT — against
the rest), "A / B" (one colour per run) and "image" (the view's image at the point's pixel).
"""

from __future__ import annotations

import numpy as np

from engine.compare.clouds import SIDES, CaseCloud
from engine.compare.pixels import CASE_TITLES, CASES, DIFFERENT, MAP_KINDS

#: RGB of each case
CASE_COLOURS = {"both_right": (120, 200, 120), "a_right_b_wrong": (40, 110, 255), "b_right_a_wrong": (255, 150, 0),
                "both_wrong": (230, 30, 30), "agree": (170, 170, 170), "disagree": (220, 0, 220),
                "only_a": (90, 90, 90), "only_b": (90, 90, 90)}
#: the report's four maps, in the palette's colours
COLOURS = {kind: CASE_COLOURS[kind] for kind in MAP_KINDS}
RUN_COLOURS = {"a": (0, 180, 190), "b": (240, 200, 0)}
SAME, NONE = (160, 160, 160), (0, 0, 0)
COLOURINGS = ("who is right", "disagreement", "A / B", "image")


def case_lut(colouring: str) -> np.ndarray:
    """(1 + len(CASES), 3) uint8: the colour of each case code under ``colouring`` ("who is right" or
    "disagreement"), black for code 0 (no case)."""
    if colouring == "who is right":
        colours = [CASE_COLOURS[c] for c in CASES]
    elif colouring == "disagreement":
        colours = [CASE_COLOURS["disagree"] if c in DIFFERENT else SAME for c in CASES]
    else:
        raise ValueError(f"colouring {colouring!r} is not one of the cases' ('who is right', 'disagreement')")
    return np.array([NONE, *colours], np.uint8)


def colour_arrays(clouds: dict[str, CaseCloud]) -> dict[str, dict[str, np.ndarray]]:
    """colouring (:data:`COLOURINGS`) -> "a" / "b" -> (N, 3) uint8 colours of that run's points."""
    out: dict[str, dict[str, np.ndarray]] = {}
    for colouring in COLOURINGS:
        if colouring in ("who is right", "disagreement"):
            lut = case_lut(colouring)
            out[colouring] = {side: lut[clouds[side].case] for side in SIDES}
        elif colouring == "A / B":
            out[colouring] = {side: np.broadcast_to(np.array(RUN_COLOURS[side], np.uint8), (len(clouds[side]), 3))
                              .copy() for side in SIDES}
        else:
            out[colouring] = {side: clouds[side].rgb for side in SIDES}
    return out


def legend_html(colouring: str, shares: dict[str, float] | None = None) -> str:
    """The legend of ``colouring``: a swatch and a title per colour, with the case's share in percent when given
    (``PixelCounts.shares()``)."""
    def swatch(rgb: tuple[int, int, int], text: str) -> str:
        return f"<div><span style='color:rgb{tuple(rgb)}'>■</span> {text}</div>"

    if colouring == "A / B":
        return "".join(swatch(RUN_COLOURS[s], s.upper()) for s in SIDES)
    if colouring == "image":
        return "<div>each point in its view's image colour</div>"
    if colouring == "disagreement":
        return swatch(CASE_COLOURS["disagree"], "the runs differ (one right, one wrong; or disagree without GT)") \
            + swatch(SAME, "the same verdict")
    rows = []
    for case in CASES[:6]:
        share = (shares or {}).get(case)
        pct = "" if share is None or share != share else f" · {share:.1f} %"
        rows.append(swatch(CASE_COLOURS[case], CASE_TITLES[case] + pct))
    return "".join(rows) + swatch(CASE_COLOURS["only_a"], "only one run has depth (no GT)")
