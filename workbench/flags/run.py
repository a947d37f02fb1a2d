"""The flags of ``deepc run`` that choose what a run computes.

``deepc run`` and the entries of a regression suite (``workbench/regress/suite.py``) declare the same
flags with :func:`add_run_option_flags`; ``workbench/flags/run_options.py`` turns them into options, so a
suite entry means exactly what the same flags mean on the command line.
"""

from __future__ import annotations

import argparse

from engine.core.errors import DeepCError
from engine.fusion import DEFAULT_PRESET, FUSION_PRESETS, FusionOptions
from engine.patchmatch import PatchMatchOptions
from engine.scene import SceneOptions
from workbench.flags.options import add_options_flags
from workbench.rerun.options import DEFAULT_CONFIDENCE_EVERY

# PatchMatch options offered as flags; the rest are reachable with --set patchmatch.NAME=VALUE (the stages --set
# reaches are ``workbench.flags.run_options.run_sections``: every options dataclass of the pipeline).
RUN_PATCHMATCH_FLAGS = ["schedule", "iterations", "seed", "pattern", "plane_propagation", "ncc_weighting",
                        "view_sampling", "levels", "geom_passes", "num_threads"]


def add_run_option_flags(parser: argparse.ArgumentParser) -> None:
    """The flags that choose what ``deepc run`` computes (pipeline and stage options); a regression
    suite's entries use the same names."""
    parser.add_argument("--pipeline", choices=("vanilla", "fast", "full"), default="vanilla",
                        help="vanilla: PatchMatch + fusion; fast: + confidence filtering; full: + refinement")
    add_options_flags(parser.add_argument_group("scene"), SceneOptions)
    add_options_flags(parser.add_argument_group("patchmatch"), PatchMatchOptions, only=RUN_PATCHMATCH_FLAGS)
    fusion_group = parser.add_argument_group("fusion")
    fusion_group.add_argument("--fusion-preset", choices=sorted(FUSION_PRESETS), default=None,
                              help=f"fusion thresholds (default: {DEFAULT_PRESET} = 1 px, 1%%, 20°, 2 pixels, "
                                   "every kept pixel its own point, every pipeline; dense = 0.5 px, one median "
                                   "point per cluster; the paper's (Kuhn et al. 2020, §5): deepc = 1 px, 1%%, 20°, "
                                   "3 pixels, refined_paper = its 5° for refined maps, colmap, acmm, deepc_lowres); "
                                   "the flags below override single values")
    add_options_flags(fusion_group, FusionOptions, only=["max_reproj_error", "max_depth_error", "max_normal_error",
                                                         "min_num_pixels", "point_per_pixel"])
    parser.add_argument("--weights", metavar="FILE", default=None,
                        help="confidence-network weights for --pipeline fast and full (default: the shipped "
                             "engine/confidence/weights/deepc_middle.pt); the filter threshold is "
                             "--set confidence.tau=0.1")
    parser.add_argument("--stream-confidence-every", type=int, default=None, metavar="K",
                        help="while PatchMatch runs, every K-th iteration of each view: its counter map and the "
                             "confidence network's map (any pipeline) in the rerun stream (default: "
                             f"{DEFAULT_CONFIDENCE_EVERY} when streaming live, off with --headless; 0 = off)")
    parser.add_argument("--set", action="append", default=[], metavar="STAGE.NAME=VALUE",
                        help="any option of any stage (every one is listed by --help-options), e.g. --set "
                             "patchmatch.tau0=0.7, --set confidence.tau=0.3, --set fusion.check_num_images=20, "
                             "--set refinement.sky.far_factor=2, or thin the rerun stream: --set stream.every=2, "
                             "stream.view=0, stream.max_size=160")


def add_probe_flags(parser: argparse.ArgumentParser) -> None:
    """``deepc run``'s pixel probe and pass history (docs/probe_schema.md); not part of regression suites."""
    parser.add_argument("--probe", metavar="VIEW:X,Y[;X,Y...]", default=None,
                        help="trace up to 64 pixels (column X, row Y at full resolution) of one view (name or "
                             "index) through every PatchMatch half-step into OUT/probes/VIEW/X_Y.json")
    parser.add_argument("--history", action=argparse.BooleanOptionalAction, default=True,
                        help="keep OUT/history/ (the source depth maps every geometric pass read), so that "
                             "'deepc probe' can trace pixels of this run later (default: on)")


def parse_probe(text: str) -> tuple[str, list[tuple[int, int]]]:
    """``VIEW:X,Y[;X,Y...]`` -> (VIEW, [(X, Y), ...]); a one-line :class:`DeepCError` when malformed."""
    view, sep, spec = text.rpartition(":")
    if not sep or not view:
        raise DeepCError(f"--probe {text!r}: expected VIEW:X,Y[;X,Y...]")
    return view, [parse_pixel(p, "--probe") for p in spec.split(";") if p.strip()]


def parse_pixel(text: str, flag: str = "--pixel") -> tuple[int, int]:
    """``X,Y`` -> (X, Y) integers; a one-line :class:`DeepCError` when malformed."""
    parts = text.split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        return int(parts[0]), int(parts[1])
    except ValueError:
        raise DeepCError(f"{flag}: {text!r} is not a pixel X,Y (two integers)") from None


def add_executor_flags(parser: argparse.ArgumentParser) -> None:
    """Where the per-view work of ``deepc run`` runs (``engine/distributed``; docs/distributed.md)."""
    group = parser.add_argument_group("executor")
    group.add_argument("--executor", choices=("local", "dask"), default="local",
                       help="local: everything in this process (default); dask: PatchMatch per view and pass, "
                            "counter maps and confidence per view as Dask tasks (same maps)")
    group.add_argument("--scheduler", metavar="ADDRESS", default=None,
                       help="with --executor dask: a running Dask scheduler, e.g. tcp://host:8786 (its workers must "
                            "see OUT and the scene at the same paths); default: a LocalCluster on this machine")
    group.add_argument("--workers", type=int, default=2, metavar="N",
                       help="with --executor dask and no --scheduler: worker processes of the LocalCluster, each "
                            "with cores / N numba threads (default: 2)")
