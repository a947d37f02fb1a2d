"""The HTML report of ``deepc regress``.

``analysis`` reads a run folder into what the report shows besides the metrics (ROC curves, depth
errors, thumbnails), ``figures`` draws the plots and thumbnails as embeddable PNGs, and ``page`` writes
the self-contained HTML file.
"""

from workbench.regress.report.analysis import (
    ERROR_MAP_MAX,
    LabelFunction,
    RunAnalysis,
    analyse_run,
    default_label_function,
    relative_depth_labels,
    shown_views,
)
from workbench.regress.report.figures import error_histogram_figure, eval_figure, png_data_uri, roc_figure
from workbench.regress.report.page import render_report, run_section, write_report

__all__ = ["ERROR_MAP_MAX", "LabelFunction", "RunAnalysis", "analyse_run", "default_label_function",
           "error_histogram_figure", "eval_figure", "png_data_uri", "relative_depth_labels", "render_report",
           "roc_figure", "run_section", "shown_views", "write_report"]
