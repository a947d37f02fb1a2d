"""The report's pictures as embeddable PNG data URIs: map thumbnails and the matplotlib plots (F1, accuracy
and completeness against tolerance; ROC curves; depth-error histograms)."""

from __future__ import annotations

import base64
import io
from typing import TYPE_CHECKING, Any

import numpy as np
from PIL import Image

if TYPE_CHECKING:
    from matplotlib.figure import Figure

THUMBNAIL_WIDTH = 200
_ROC_POINTS = 400  # points per plotted ROC curve
_HIST_BINS = np.logspace(-4, 0, 49)  # relative depth error 0.01 % .. 100 %


def png_data_uri(rgb: np.ndarray, smooth: bool = False, width: int = THUMBNAIL_WIDTH) -> str:
    """(H, W, 3) uint8 -> 'data:image/png;base64,...', shrunk to ``width`` (maps: nearest, never blended)."""
    image = Image.fromarray(np.ascontiguousarray(rgb))
    if image.width > width:
        size = (width, max(1, round(image.height * width / image.width)))
        image = image.resize(size, Image.Resampling.BOX if smooth else Image.Resampling.NEAREST)
    buffer = io.BytesIO()
    image.save(buffer, format="PNG", optimize=True)
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


def _figure(width: float = 4.6, height: float = 3.3):
    from matplotlib.figure import Figure  # lazy: matplotlib

    fig = Figure(figsize=(width, height), dpi=100, layout="constrained")
    return fig, fig.add_subplot()


def figure_data_uri(fig: Figure) -> str:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


def eval_figure(curves: dict[str, dict[str, Any]], baseline: dict[str, Any] | None = None) -> str | None:
    """F1 (solid), accuracy (dashed) and completeness (dotted) against tolerance, one colour per curve set
    (pipelines of a scene, or "current"); the baseline in grey."""
    curves = {name: block for name, block in curves.items() if block}
    if not curves and not baseline:
        return None
    fig, ax = _figure()
    sets = list(curves.items()) + ([("baseline", baseline)] if baseline else [])
    for n, (name, block) in enumerate(sets):
        color = "0.55" if name == "baseline" else f"C{n}"
        for key, style in (("f1", "-"), ("accuracy", "--"), ("completeness", ":")):
            ax.plot(block["tolerances"], block[key], style, color=color, marker="o", markersize=3,
                    label=f"{name} {'F1' if key == 'f1' else key}")
    ax.set_xscale("log")
    ax.set_xlabel("tolerance (model units)")
    ax.set_ylabel("%")
    ax.set_ylim(0, 100)
    ax.set_title("F1, accuracy, completeness vs tolerance")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    return figure_data_uri(fig)


def roc_figure(curves: dict[str, tuple[np.ndarray, np.ndarray, float]], label_name: str) -> str | None:
    if not curves:
        return None
    fig, ax = _figure()
    for n, (name, (fpr, tpr, auc)) in enumerate(curves.items()):
        step = max(1, len(fpr) // _ROC_POINTS)
        keep = np.unique(np.append(np.arange(0, len(fpr), step), len(fpr) - 1))
        ax.plot(fpr[keep], tpr[keep], color=f"C{n}", label=f"{name}: AUC {auc * 100:.2f}")
    ax.plot([0, 1], [0, 1], color="0.7", linestyle=":", linewidth=1)
    ax.set_xlabel("false positive rate (outliers kept)")
    ax.set_ylabel("true positive rate (inliers kept)")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_title(f"ROC ({label_name})", fontsize=9)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    return figure_data_uri(fig)


def error_histogram_figure(errors: dict[str, np.ndarray]) -> str | None:
    errors = {k: v for k, v in errors.items() if v.size}
    if not errors:
        return None
    fig, ax = _figure()
    for n, (name, values) in enumerate(errors.items()):
        counts, _ = np.histogram(np.clip(values, _HIST_BINS[0], _HIST_BINS[-1]), bins=_HIST_BINS)
        ax.stairs(100.0 * counts / values.size, _HIST_BINS * 100, color=f"C{n}",
                  label=f"{name}: median {np.median(values) * 100:.2f} %")
    for x in (1.0, 5.0):
        ax.axvline(x, color="0.5", linestyle=":", linewidth=1)
    ax.set_xscale("log")
    ax.set_xlabel("|z - z*| / z* (%), clipped to 0.01 .. 100")
    ax.set_ylabel("% of pixels with estimate and GT")
    ax.set_title("depth error")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    return figure_data_uri(fig)
