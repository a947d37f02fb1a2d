"""Class-coded maps and legends of the rerun stream: what a colour means, in which unit, and what 'no data' is.

Maps whose value a user reads by hovering (relative error against GT, counter, confidence, labels) are logged as
``rr.SegmentationImage`` class ids with an ``rr.AnnotationContext`` on the same entity, so rerun's hover names the
value and its unit ("relative error 1.25-1.50 %") instead of "Depth 0.2". Class 0 is always "no data" (black).
Every map kind has a markdown legend (:data:`LEGENDS`), logged as ``legend/<kind>`` text documents and shown by the
layouts (``layouts/``).
"""

from __future__ import annotations

import numpy as np

from engine.core.words import plural
from workbench.maps.images import colormap_lut

NO_DATA = 0
ERROR_STEP = 0.25  # percent per class of the error map
ERROR_CLASSES = 200  # 200 classes of 0.25 % cover 0-50 %; class 201 is "50 % or more"
CONFIDENCE_CLASSES = 101  # confidence 0.00 .. 1.00 in steps of 0.01
COUNTER_MAX = 20
COST_STEP = 0.01  # cost per class of the cost map: 201 classes cover 0-2
COST_CLASSES = 201


def error_classes(rel_percent: np.ndarray) -> np.ndarray:
    """Relative depth error in percent (NaN = no depth or no GT) -> uint8 class ids (0 = no data)."""
    ok = np.isfinite(rel_percent)
    ids = np.minimum(np.floor(np.where(ok, rel_percent, 0) / ERROR_STEP), ERROR_CLASSES).astype(np.int32) + 1
    return np.where(ok, ids, NO_DATA).astype(np.uint8)


def confidence_classes(confidence: np.ndarray, invalid: np.ndarray | None) -> np.ndarray:
    """Confidence in [0, 1] -> uint8 class ids 1..101 (0 = no depth)."""
    ids = np.rint(np.clip(np.nan_to_num(confidence, nan=0.0), 0, 1) * 100).astype(np.uint8) + 1
    if invalid is not None:
        ids[invalid] = NO_DATA
    return ids


def counter_classes(counter: np.ndarray, invalid: np.ndarray | None) -> np.ndarray:
    """Counter (number of geometrically consistent source views) -> uint8 class ids k + 1 (0 = no depth)."""
    ids = np.clip(np.rint(np.nan_to_num(counter, nan=0.0)), 0, COUNTER_MAX).astype(np.uint8) + 1
    if invalid is not None:
        ids[invalid] = NO_DATA
    return ids


def cost_classes(cost: np.ndarray, invalid: np.ndarray | None) -> np.ndarray:
    """Matching cost in [0, 2] -> uint8 class ids 1..201 in steps of 0.01 (0 = no depth)."""
    ids = np.rint(np.clip(np.nan_to_num(cost, nan=2.0), 0, 2) / COST_STEP).astype(np.uint8) + 1
    if invalid is not None:
        ids[invalid] = NO_DATA
    return ids


def count_classes(count: np.ndarray) -> np.ndarray:
    """Number of selected source views -> uint8 class ids count + 1 (no class 0: every pixel has a count)."""
    return (np.minimum(count, 254) + 1).astype(np.uint8)


def label_classes(labels: np.ndarray) -> np.ndarray:
    """Label map (1 inlier, 0 outlier, -1 unlabeled) -> uint8 class ids (2 inlier, 1 outlier, 0 unlabeled)."""
    return np.where(labels < 0, NO_DATA, labels.astype(np.int16) + 1).astype(np.uint8)


def _context(entries: list[tuple[int, str, tuple[int, int, int]]], none: str):
    import rerun as rr  # lazy: rerun

    return rr.AnnotationContext([(NO_DATA, none, (0, 0, 0)), *entries])


def error_context():
    lut = colormap_lut("inferno", ERROR_CLASSES + 1)
    entries = [(k + 1, f"relative error {k * ERROR_STEP:.2f}-{(k + 1) * ERROR_STEP:.2f} %",
                tuple(int(c) for c in lut[k])) for k in range(ERROR_CLASSES)]
    entries.append((ERROR_CLASSES + 1, f"relative error {ERROR_CLASSES * ERROR_STEP:.0f} % or more",
                    tuple(int(c) for c in lut[ERROR_CLASSES])))
    return _context(entries, "no data (no depth estimate or no GT depth)")


def confidence_context():
    lut = colormap_lut("viridis", CONFIDENCE_CLASSES)
    return _context([(k + 1, f"confidence {k / 100:.2f}", tuple(int(c) for c in lut[k]))
                     for k in range(CONFIDENCE_CLASSES)], "no data (no depth estimate)")


def counter_context():
    lut = colormap_lut("coolwarm", 6)
    return _context([(k + 1, f"counter {k}{'+' if k == COUNTER_MAX else ''} (consistent source views)",
                      tuple(int(c) for c in lut[min(k, 5)])) for k in range(COUNTER_MAX + 1)],
                    "no data (no depth estimate)")


def cost_context():
    lut = colormap_lut("magma", COST_CLASSES)
    return _context([(k + 1, f"matching cost {k * COST_STEP:.2f} (1 - NCC; 0 perfect, 2 no match)",
                      tuple(int(c) for c in lut[k])) for k in range(COST_CLASSES)], "no data (no depth estimate)")


def selected_count_context(n_sources: int):
    n = max(n_sources, 1)
    lut = colormap_lut("viridis", n + 1)
    sources = plural(n_sources, "source view")
    return _context([(k + 1, f"{k} of {sources} selected", tuple(int(c) for c in lut[min(k, n)]))
                     for k in range(33)], "no data")  # a uint32 mask selects at most 32


def label_context():
    return _context([(1, "outlier (reprojection error >= 2 px in every counted source view)", (220, 50, 47)),
                     (2, "inlier (reprojection error < 2 px in a source view)", (60, 180, 75))],
                    "unlabeled (no depth, no GT, beyond the depth range or seen by no source view)")


CONTEXTS = {"error": error_context, "confidence": confidence_context, "counter": counter_context,
            "label": label_context, "cost": cost_context}

LEGENDS: dict[str, str] = {
    "depth": "**depth (m)** — camera-frame z in metres (the model's units), colour scale *turbo* from the view's "
             "depth range minimum (blue) to maximum (red). Hover: *Depth* is the depth in metres (rerun prints it "
             "without its unit; the panel title has it), *Val* the stored step. No data: transparent (0 = no "
             "estimate).",
    "normal": "**normal** — unit normal in the camera frame (x right, y down, z forward), RGB = (n + 1) / 2: a "
              "surface facing the camera, n = (0, 0, -1), is olive; tilting right adds red, down adds green. "
              "No data: black.",
    "cost": "**cost** — aggregated matching cost of the stored hypothesis, 1 − NCC, unitless, 0 (perfect, dark) to 2 "
            "(no match, bright), colour scale *magma*, in 0.01 classes; hover names the value. No data: black.",
    "selected_count": "**views used** — number of source views PatchMatch selected for the pixel, 0 to the view's "
                      "number of source views, colour scale *viridis*; hover names the count.",
    "error": "**error vs GT** — relative depth error |z − z_GT| / z_GT in percent, colour scale *inferno* from 0 % "
             "(black-purple) to 50 % or more (yellow), in 0.25 % classes; hover names the class. Logged with the maps "
             "at every logged iteration of every level. No data (no estimate or no GT): black.",
    "counter": "**counter** — number of source views whose depth agrees with this pixel's (geometric consistency), "
               "colour scale *coolwarm* 0 (blue) to 5+ (red). Computed after PatchMatch (at each view's last "
               "iteration) and, when the stream scores confidence while PatchMatch runs, every k-th iteration "
               "against the other views' latest maps. No data: black.",
    "confidence": "**confidence** — the DeepC network's probability that the depth is an inlier, 0 to 1, colour "
                  "scale *viridis*; hover names the value. The fast/full pipelines compute it after PatchMatch; a "
                  "live stream also scores the current maps every k-th iteration (any pipeline, "
                  "--stream-confidence-every). No data: black.",
    "label": "**labels** — GT labels (Kuhn et al. 2020): green inlier (< 2 px reprojection error in a source view), "
             "red outlier, black unlabeled. Needs GT depth and confidence (the stage or the live scoring); compare "
             "with confidence.",
}


#: What a hover's *Position* counts. Rerun reads it off the logged image and no transform changes that, so the
#: coarse levels are logged at their own size (a quarter of the bytes of an upsampled copy) and this says how to
#: get to the full-resolution pixels the viser inspector takes.
HOVER_POSITION = ("**Hover position** — *Position* is a pixel of the map as logged: at pyramid level L it is 2^L "
                  "full-resolution pixels across, and a recording that bounds the map size shrinks it further. "
                  "Multiply by the view's *px scale* plot (full-res px per map px, stats/<view>/pixel_scale) for the "
                  "full-resolution pixel the viewer's inspector takes.")


def legend_markdown(kinds: list[str] | None = None) -> str:
    """One markdown document explaining what a hover's position counts and the colour scale, unit and 'no data'
    of each map kind."""
    kinds = kinds or list(LEGENDS)
    return ("# Colour legends\n\n" + HOVER_POSITION + "\n\n"
            + "\n\n".join(f"- {LEGENDS[k]}" for k in kinds if k in LEGENDS) + "\n")
