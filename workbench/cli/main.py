"""The ``deepc`` command line: one subcommand per module (run, mesh, probe, info, eval, compare, view, replay, regress,
train).

Every user-facing problem ends in one line on stderr and exit status 2; success is 0 and, for
``regress``, "a quality metric changed beyond its tolerance" (either way) is 1.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import warnings
from collections.abc import Sequence

from engine import __version__
from engine.core.errors import DeepCError
from engine.core.interrupt import EXIT_INTERRUPTED, deferred_interrupts
from engine.meshing.options import MESH_METHODS
from engine.scene import SceneOptions
from workbench.cli.compare import add_compare_arguments, tolerance_fraction
from workbench.cli.probe import add_probe_arguments
from workbench.flags.help_options import HelpOptionsAction
from workbench.flags.options import add_options_flags
from workbench.flags.run import add_executor_flags, add_probe_flags, add_run_option_flags
from workbench.flags.train import add_train_arguments

# The commands' own modules are imported when their command runs: the engine pipeline, training, the
# regression mode and the viewers stay off the start-up of every `deepc` call (`deepc --help` included).

EXIT_OK, EXIT_REGRESSED, EXIT_USAGE = 0, 1, 2


def _run(args: argparse.Namespace) -> int:
    from workbench.cli.run import cmd_run  # lazy: the engine pipeline

    return cmd_run(args)


def _eval(args: argparse.Namespace) -> int:
    from workbench.cli.eval import cmd_eval  # lazy: the evaluation

    return cmd_eval(args)


def _compare(args: argparse.Namespace) -> int:
    from workbench.cli.compare import cmd_compare  # lazy: the evaluation and the run readers

    return cmd_compare(args)


def _train(args: argparse.Namespace) -> int:
    from workbench.cli.train import cmd_train  # lazy: the engine pipeline (torch once training starts)

    return cmd_train(args)


def _mesh(args: argparse.Namespace) -> int:
    from workbench.cli.mesh import cmd_mesh  # lazy: the engine pipeline (open3d when meshing)

    return cmd_mesh(args)


def _probe(args: argparse.Namespace) -> int:
    from workbench.cli.probe import cmd_probe  # lazy: the engine pipeline

    return cmd_probe(args)


def _view(args: argparse.Namespace) -> int:
    if args.compare:
        tolerance = tolerance_fraction(args.tolerance)
        from workbench.viewer.compare import serve_compare  # lazy: viser, the comparison

        serve_compare(args.target, args.compare, host=args.host, port=args.port, scene=args.scene, maps=args.maps,
                      tolerance=tolerance)
        return EXIT_OK
    from workbench.viewer.app import serve  # lazy: viser

    serve(args.target, host=args.host, port=args.port)
    return EXIT_OK


def _regress(args: argparse.Namespace) -> int:
    from workbench.regress.command import cmd_regress  # lazy: the engine pipeline and the report

    with deferred_interrupts():  # in-process pipelines: stop at the engine's safe points, as `run` does
        return cmd_regress(args)


def _replay(args: argparse.Namespace) -> int:
    from workbench.rerun.replay import replay  # lazy: rerun

    return replay(args.recording, layout=args.layout, web=args.web, host=args.host, port=args.port, view=args.view,
                  compare=args.compare)


def _info(args: argparse.Namespace) -> int:
    from workbench.cli.info import cmd_info  # lazy: the memory estimator (numba)

    return cmd_info(args)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="deepc", description="DeepC Workbench: PatchMatch MVS with deep confidence, made visible.")
    parser.add_argument("--version", action="version", version=f"deepc {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    run = sub.add_parser("run", help="reconstruct a scene: PatchMatch, confidence, filtering/refinement, fusion",
                         description="Reconstruct a COLMAP workspace (SCENE/images, SCENE/sparse) into OUT.")
    run.add_argument("scene", help="COLMAP workspace folder")
    run.add_argument("--out", required=True, help="output folder (stereo maps, fused.ply, metrics.json)")
    add_run_option_flags(run)
    run.add_argument("--help-options", action=HelpOptionsAction,
                     help="list every --set STAGE.NAME=VALUE option (type, default, unit, where the default comes "
                          "from, what it does) and exit")
    add_probe_flags(run)
    run.add_argument("--mesh", choices=MESH_METHODS, default="none",
                     help="also write OUT/mesh.ply: 'poisson' on the fused cloud, 'tsdf' of the maps fusion used "
                          "(default: none; settings with --set mesh.NAME=VALUE)")
    run.add_argument("--record", metavar="FILE.rrd", nargs="?", const="", default=None,
                     help="write a rerun recording (default path: OUT/recording.rrd)")
    run.add_argument("--headless", action="store_true",
                     help="no viewer, no window: print progress and exit (otherwise the run streams live to rerun "
                          "and to the 3-D browser viewer, which becomes the tuning viewer when the run ends)")
    run.add_argument("--resume", action="store_true",
                     help="continue an interrupted run in OUT: reuse its verified per-view PatchMatch states "
                          "(same scene, options and seed give the same outputs as an uninterrupted run)")
    run.add_argument("--max-memory", type=float, metavar="MB",
                     help="refuse the run if its estimated peak memory exceeds this (default: what is available)")
    run.add_argument("--ignore-memory-check", action="store_true",
                     help="run even when the estimated peak memory exceeds the available memory")
    add_executor_flags(run)
    run.add_argument("--host", default="127.0.0.1", help="address the viewers bind (default: 127.0.0.1)")
    run.add_argument("--port", type=int, default=8080, help="port of the browser viewer (default: 8080)")
    run.set_defaults(handler=_run)

    mesh = sub.add_parser("mesh", help="a surface (mesh.ply) from a finished run, scored when the scene has GT",
                          description="Mesh the run in RUN_DIR: screened Poisson on its fused cloud, or TSDF "
                                      "integration of the maps its pipeline fused; writes RUN_DIR/mesh.ply and "
                                      "adds a 'mesh' block to its metrics.json.")
    mesh.add_argument("run_dir", metavar="RUN_DIR")
    mesh.add_argument("--method", choices=MESH_METHODS[1:], default="poisson", help="default: poisson")
    mesh.add_argument("--set", action="append", default=[], metavar="mesh.NAME=VALUE",
                      help="mesh options, e.g. --set mesh.poisson_depth=10, --set mesh.tsdf_voxel_px=1")
    mesh.set_defaults(handler=_mesh)

    info = sub.add_parser("info", help="check a scene in seconds: cameras, working size, undistortion, memory, "
                                       "views, depth ranges and source views (undistorts nothing)")
    info.add_argument("scene", help="COLMAP workspace folder")
    add_options_flags(info, SceneOptions)
    info.set_defaults(handler=_info)

    ev = sub.add_parser("eval", help="ETH3D-style accuracy, completeness and F1 of a point cloud")
    ev.add_argument("recon", metavar="RECON.ply")
    ev.add_argument("gt", metavar="GT.ply", help="ground-truth points (or an ETH3D scan_alignment.mlp)")
    ev.add_argument("--tolerances", default="0.01,0.02,0.05,0.1,0.2,0.5", help="comma-separated, model units")
    ev.add_argument("--json", metavar="OUT.json", help="also write the table as JSON")
    ev.set_defaults(handler=_eval)

    compare = sub.add_parser("compare", help="two runs of one scene pixel by pixel: ours, COLMAP's or OpenMVS's",
                             description="Compare two runs (deepc run folders, COLMAP dense workspaces or OpenMVS "
                                         "densify folders) view by view: who is right where GT exists, where they "
                                         "disagree where it does not, and their fused clouds' F1.")
    add_compare_arguments(compare)
    compare.set_defaults(handler=_compare)

    view = sub.add_parser("view", help="the live-tuning browser viewer (viser)")
    view.add_argument("target", metavar="OUT_OR_SCENE")
    view.add_argument("--host", default="127.0.0.1", help="address to bind (default: 127.0.0.1, this machine only)")
    view.add_argument("--port", type=int, default=8080)
    view.add_argument("--compare", metavar="RUN_B", default=None,
                      help="compare mode: OUT_OR_SCENE (a deepc run, COLMAP dense workspace or OpenMVS densify folder) "
                           "against RUN_B, as deepc compare compares them")
    view.add_argument("--scene", metavar="SCENE", default=None, help="with --compare: as deepc compare --scene")
    view.add_argument("--maps", choices=("fused", "raw"), default="fused", help="with --compare: as deepc compare")
    view.add_argument("--tolerance", type=float, default=1.0, metavar="PERCENT",
                      help="with --compare: as deepc compare (default: 1)")
    view.set_defaults(handler=_view)

    probe = sub.add_parser("probe", help="trace pixels of a finished run through PatchMatch, or re-run a region",
                           description="Why is this depth wrong? Re-runs one view of a finished run from its pass "
                                       "history and writes every half-step of the given pixels to "
                                       "RUN_DIR/probes/VIEW/X_Y.json (docs/probe_schema.md); --region re-runs a "
                                       "box with changed options.")
    add_probe_arguments(probe)
    probe.set_defaults(handler=_probe)

    replay = sub.add_parser("replay", help="replay a .rrd recording in the rerun viewer")
    replay.add_argument("recording", metavar="FILE.rrd")
    replay.add_argument("--layout", default=None,
                        help="blueprint from layouts/: iterations, pipelines, confidence or probe, built from what "
                             "the recording holds (default: iterations; pipelines for a recording of results only, "
                             "probe for one of probed pixels only)")
    replay.add_argument("--view", metavar="NAME", default=None,
                        help="the view to show: its image name (e.g. view_003.png), its index or its entity name "
                             "(default: the first view)")
    replay.add_argument("--compare", metavar="B.rrd", default=None,
                        help="a second recording: both merged (entities under a/ and b/), each map of A beside B's, "
                             "a tab per view (--layout does not apply)")
    replay.add_argument("--web", action="store_true", help="serve the web viewer even when there is a display")
    replay.add_argument("--host", default="127.0.0.1", help="address of the web viewer (default: 127.0.0.1)")
    replay.add_argument("--port", type=int, default=9090,
                        help="port of the web viewer (default: 9090; 0 = any free port)")
    replay.set_defaults(handler=_replay)

    regress = sub.add_parser("regress", help="headless regression runs against committed baselines",
                             description="Run every scene x pipeline of a suite headless, compare the metrics with "
                                         "the baselines, print the deltas and write an HTML report. Exit 0 when "
                                         "no quality metric changed beyond its tolerance, 1 when one did, better "
                                         "or worse (named), 2 on bad input. Times are information only: ratios "
                                         "to the baseline's after a calibration workload. A suite "
                                         "file lists [[scene]] and [[pipeline]] tables whose keys are deepc run "
                                         "flags; see sample_scenes/suite.toml.")
    regress.add_argument("--suite", metavar="FILE.toml", help="suite file (default: sample_scenes/suite.toml)")
    regress.add_argument("--baseline", metavar="DIR", help="baseline folder (default: the suite's 'baseline' key, "
                         "tests/baselines for the default suite)")
    regress.add_argument("--update-baseline", action="store_true",
                         help="rewrite the baselines with this run's metrics and print what changed")
    regress.add_argument("--reason", metavar="TEXT", default=None,
                         help="with --update-baseline: why they are remade (stored with them, shown in the report)")
    regress.add_argument("--report", metavar="DIR", help="folder for report.html, summary.json and the runs' "
                         "outputs (default: runs/regress)")
    regress.add_argument("--record", action="store_true",
                         help="also write a rerun recording of every run, linked from the report")
    regress.set_defaults(handler=_regress)

    train = sub.add_parser("train", help="train the confidence network on scenes with GT depth",
                           description="Run the engine on scenes with GT depth (cached), label the maps and "
                                       "train the confidence network; resumable, deterministic for a seed.")
    add_train_arguments(train)
    train.set_defaults(handler=_train)
    return parser


def _warning_line(message, category, filename, lineno, file=None, line=None):  # noqa: ARG001
    print(f"deepc: warning: {' '.join(str(message).split())}", file=sys.stderr)


def _terminate(signum, frame):  # noqa: ARG001
    # SIGTERM cleans up like Ctrl+C: no orphaned viewer, no partial file (deferred during `run`'s pipeline)
    raise KeyboardInterrupt


def main(argv: Sequence[str] | None = None) -> int:
    try:
        return _main(argv)
    except BrokenPipeError:  # `deepc run --help-options | head`: the reader has what it wanted
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at interpreter exit
        return EXIT_OK


def _main(argv: Sequence[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    warnings.showwarning = _warning_line
    # pycolmap, where a command needs it, is imported by engine.io.colmap_model.import_pycolmap, which keeps this
    # handler (its glog installs one that aborts)
    signal.signal(signal.SIGTERM, _terminate)
    try:
        return int(args.handler(args) or 0)
    except DeepCError as exc:
        print(f"deepc: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("deepc: interrupted", file=sys.stderr)
        if argv is None:  # the process's own command line (not a test calling main): exit without teardown
            _exit_now()
        return EXIT_INTERRUPTED


def _exit_now() -> None:
    """Exit with status 130 without the interpreter's teardown: the command's own clean-ups (finally blocks:
    viewers stopped, recordings abandoned, executors closed) have run, and the teardown (freeing every module
    and array, numba's threads) took 2.6 s on the loaded 2-core machine, past the 2 s a Ctrl-C may take."""
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(EXIT_INTERRUPTED)


if __name__ == "__main__":
    sys.exit(main())
