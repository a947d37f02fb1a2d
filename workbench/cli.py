"""The ``deepc`` command line (CONTRACT.md §3).

Every user-facing problem ends in one line on stderr and exit status 2; success is 0 and, for
``regress``, "something regressed" is 1.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Callable, Sequence

from engine import __version__
from engine.errors import DeepCError
from engine.scene import SceneOptions, load_scene
from workbench.flags import add_options_flags, options_from_args

EXIT_OK, EXIT_REGRESSED, EXIT_USAGE = 0, 1, 2


class NotYetImplemented(DeepCError):
    """A subcommand whose pipeline stage has not been built yet."""


def _not_yet(command: str, stage: str) -> Callable[[argparse.Namespace], int]:
    def handler(args: argparse.Namespace) -> int:
        raise NotYetImplemented(f"deepc {command}: {stage} does not exist yet in this version")
    return handler


def cmd_info(args: argparse.Namespace) -> int:
    scene = load_scene(args.scene, options_from_args(SceneOptions, args))
    print(scene.summary())
    return EXIT_OK


def cmd_run(args: argparse.Namespace) -> int:
    scene = load_scene(args.scene, options_from_args(SceneOptions, args))
    print(scene.summary())
    raise NotYetImplemented("deepc run: the PatchMatch stage does not exist yet in this version "
                            "(the scene above loaded and is valid)")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="deepc", description="DeepC Workbench: PatchMatch MVS with deep confidence, made visible.")
    parser.add_argument("--version", action="version", version=f"deepc {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    run = sub.add_parser("run", help="reconstruct a scene: PatchMatch, confidence, filtering/refinement, fusion",
                         description="Reconstruct a COLMAP workspace (SCENE/images, SCENE/sparse) into OUT.")
    run.add_argument("scene", help="COLMAP workspace folder")
    run.add_argument("--out", required=True, help="output folder (stereo maps, fused.ply, metrics.json)")
    run.add_argument("--pipeline", choices=("vanilla", "fast", "full"), default="vanilla",
                     help="vanilla: PatchMatch + fusion; fast: + confidence filtering; full: + refinement")
    scene_group = run.add_argument_group("scene")
    add_options_flags(scene_group, SceneOptions)
    pm = run.add_argument_group("patchmatch")
    pm.add_argument("--schedule", choices=("paper", "acmm"), default=None,
                    help="red-black iterations per pass: paper = 8 in every pass, acmm = 3/2/2")
    pm.add_argument("--iterations", type=int, default=None, help="override the iteration count of every pass")
    pm.add_argument("--seed", type=int, default=None, help="random seed (same seed, same output)")
    run.add_argument("--record", metavar="FILE.rrd", default=None, help="write a rerun recording")
    run.add_argument("--headless", action="store_true", help="no viewer, no window: print progress and exit")
    run.set_defaults(handler=cmd_run)

    info = sub.add_parser("info", help="load a scene and print its views, depth ranges and source views")
    info.add_argument("scene", help="COLMAP workspace folder")
    add_options_flags(info, SceneOptions)
    info.set_defaults(handler=cmd_info)

    ev = sub.add_parser("eval", help="ETH3D-style accuracy, completeness and F1 of a point cloud")
    ev.add_argument("recon", metavar="RECON.ply")
    ev.add_argument("gt", metavar="GT.ply", help="ground-truth points (or an ETH3D scan_alignment.mlp)")
    ev.add_argument("--tolerances", default="0.01,0.02,0.05,0.1,0.2,0.5", help="comma-separated, model units")
    ev.add_argument("--json", metavar="OUT.json", help="also write the table as JSON")
    ev.set_defaults(handler=_not_yet("eval", "the evaluation stage"))

    view = sub.add_parser("view", help="the live-tuning browser viewer (viser)")
    view.add_argument("target", metavar="OUT_OR_SCENE")
    view.add_argument("--host", default="127.0.0.1", help="address to bind (default: 127.0.0.1, this machine only)")
    view.add_argument("--port", type=int, default=8080)
    view.set_defaults(handler=_not_yet("view", "the viewer"))

    replay = sub.add_parser("replay", help="replay a .rrd recording in the rerun viewer")
    replay.add_argument("recording", metavar="FILE.rrd")
    replay.add_argument("--layout", default=None, help="layout name from layouts/")
    replay.set_defaults(handler=_not_yet("replay", "the rerun replay"))

    regress = sub.add_parser("regress", help="headless regression runs against committed baselines")
    regress.add_argument("--suite", help="suite file (TOML)")
    regress.add_argument("--baseline", help="baseline folder")
    regress.add_argument("--update-baseline", action="store_true")
    regress.add_argument("--report", help="folder for the HTML report")
    regress.add_argument("--record", action="store_true", help="also record .rrd files")
    regress.set_defaults(handler=_not_yet("regress", "the regression mode"))

    train = sub.add_parser("train", help="train the confidence network")
    train.add_argument("scenes", nargs="*", help="scenes with ground truth")
    train.set_defaults(handler=_not_yet("train", "the confidence network"))
    return parser


def _warning_line(message, category, filename, lineno, file=None, line=None):  # noqa: ARG001
    print(f"deepc: warning: {' '.join(str(message).split())}", file=sys.stderr)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    warnings.showwarning = _warning_line
    try:
        return int(args.handler(args) or 0)
    except DeepCError as exc:
        print(f"deepc: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("deepc: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
