"""The ``deepc`` command line (CONTRACT.md §3).

Every user-facing problem ends in one line on stderr and exit status 2; success is 0 and, for
``regress``, "something regressed" is 1.
"""

from __future__ import annotations

import argparse
import signal
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path

from engine import __version__
from engine.errors import DeepCError
from engine.scene import SceneOptions, load_scene
from workbench.flags import add_options_flags, options_from_args, section_overrides

EXIT_OK, EXIT_REGRESSED, EXIT_USAGE = 0, 1, 2


def _eval(args: argparse.Namespace) -> int:
    from workbench.eval_command import cmd_eval
    return cmd_eval(args)


def _train(args: argparse.Namespace) -> int:
    from workbench.train_command import cmd_train
    return cmd_train(args)


def _view(args: argparse.Namespace) -> int:
    from workbench.viewer import serve
    serve(args.target, host=args.host, port=args.port)
    return EXIT_OK


def _regress(args: argparse.Namespace) -> int:
    from engine.interrupt import deferred_interrupts
    from workbench.regress import cmd_regress
    with deferred_interrupts():  # in-process pipelines: stop at the engine's safe points, as `run` does
        return cmd_regress(args)


def _replay(args: argparse.Namespace) -> int:
    from workbench.replay import replay
    return replay(args.recording, layout=args.layout, web=args.web, host=args.host, port=args.port)


def cmd_info(args: argparse.Namespace) -> int:
    scene = load_scene(args.scene, options_from_args(SceneOptions, args))
    print(scene.summary())
    return EXIT_OK


# PatchMatch options offered as flags; the rest are reachable with --set patchmatch.NAME=VALUE.
RUN_PATCHMATCH_FLAGS = ["schedule", "iterations", "seed", "pattern", "plane_propagation", "ncc_weighting",
                        "view_sampling", "levels", "geom_passes", "num_threads"]


SET_SECTIONS = ("patchmatch", "confidence", "refinement", "fusion", "stream")


def run_options_from_args(args: argparse.Namespace):
    """(SceneOptions, PipelineOptions, StreamOptions) from the flags of :func:`add_run_option_flags`;
    shared by ``deepc run`` and the entries of a regression suite."""
    from engine.fusion import DEFAULT_PRESET, FUSION_PRESETS, FusionOptions
    from engine.patchmatch import PatchMatchOptions
    from engine.pipeline import PipelineOptions
    from workbench.stream import StreamOptions

    for item in args.set:
        section = item.partition("=")[0].partition(".")[0]
        if section not in SET_SECTIONS:
            raise DeepCError(f"--set {item!r}: unknown stage {section!r} (one of {', '.join(SET_SECTIONS)})")
    scene_options = options_from_args(SceneOptions, args)
    patchmatch = options_from_args(PatchMatchOptions, args,
                                   **section_overrides(args.set, "patchmatch", PatchMatchOptions))
    preset = args.fusion_preset or DEFAULT_PRESET
    fusion = options_from_args(FusionOptions, args, base=FUSION_PRESETS[preset],
                               **section_overrides(args.set, "fusion", FusionOptions))
    from engine.confidence.options import ConfidenceOptions
    confidence = ConfidenceOptions(**section_overrides(args.set, "confidence", ConfidenceOptions))
    if getattr(args, "weights", None):
        confidence = confidence.replace(weights=str(Path(args.weights).resolve()))
    from engine.refinement.options import RefinementOptions
    refinement = RefinementOptions(**section_overrides(args.set, "refinement", RefinementOptions))
    options = PipelineOptions(pipeline=args.pipeline, patchmatch=patchmatch, confidence=confidence,
                              refinement=refinement, fusion=fusion).validate()
    stream_options = StreamOptions(**section_overrides(args.set, "stream", StreamOptions)).validate()
    if options.pipeline in ("fast", "full"):  # bad weights fail before PatchMatch
        _check_weights(Path(options.confidence.weights or _default_weights()))
        if options.pipeline == "full":
            from engine.confidence.weights import DEFAULT_REFINED_WEIGHTS
            _check_weights(Path(options.confidence.refined_weights or DEFAULT_REFINED_WEIGHTS))
    return scene_options, options, stream_options


def cmd_run(args: argparse.Namespace) -> int:
    from engine.interrupt import deferred_interrupts
    from engine.pipeline import run_pipeline
    from workbench.progress import PassProgress

    scene_options, options, stream_options = run_options_from_args(args)
    scene = load_scene(args.scene, scene_options)
    print(scene.summary(), file=sys.stderr)
    _check_memory(args, scene, options)
    checkpoint = _prepare_output(args)
    record = None if args.record is None else (args.record or str(Path(args.out) / "recording.rrd"))
    live = recording = None
    progress = PassProgress()
    try:
        if not args.headless:
            from workbench.replay import live_viewer
            live = live_viewer(args.host)
            print(f"live PatchMatch stream: {live.url}", file=sys.stderr)
        if record or live:
            recording = _open_recording(record, scene, options, stream_options, live.grpc_url if live else None)
        try:
            # SIGINT/SIGTERM stop the run at the engine's next safe point, never inside a kernel call
            with deferred_interrupts():
                result = run_pipeline(scene, args.out, options, observer=recording.stream if recording else None,
                                      progress=progress, checkpoint=checkpoint)
        except BaseException:
            if recording:
                recording.abandon()
            raise
        finally:
            progress.close()
        if recording:
            recording.finish()
            if record:
                print(f"recording: {record} ({recording.stream.logged_steps} logged iterations)", file=sys.stderr)
        if checkpoint.stats.reused or checkpoint.stats.rejected:
            print(f"resumed: {checkpoint.stats.reused} saved PatchMatch view states reused, "
                  f"{checkpoint.stats.rejected} rejected and recomputed", file=sys.stderr)
        _print_run_summary(result.metrics, args.out)
        if not args.headless:
            from workbench.viewer import serve
            serve(args.out, host=args.host, port=args.port)
    finally:
        if live:
            live.stop()
    return EXIT_OK


def _check_memory(args: argparse.Namespace, scene, options) -> None:
    """Refuse a run whose estimated peak memory does not fit (engine/memory.py), naming a size that does."""
    from engine.memory import estimate_run_memory, largest_fitting_size, load_kernels

    load_kernels()  # the JIT runtime's memory becomes part of the measured baseline
    estimate = estimate_run_memory(scene, options)
    if args.max_memory is not None:
        limit = int(args.max_memory * (1 << 20))
        estimate.available = limit if estimate.available is None else min(estimate.available, limit)
    print(estimate.summary(), file=sys.stderr)
    if estimate.fits or args.ignore_memory_check:
        return
    size = largest_fitting_size(scene, options, estimate)
    hint = f"try --max-image-size {size}" if size else "no image size fits"
    raise DeepCError(f"not enough memory: the run needs about {estimate.peak / (1 << 20):,.0f} MiB, "
                     f"{estimate.available / (1 << 20):,.0f} MiB are available; {hint}, "
                     "or --ignore-memory-check to run anyway", args.scene)


def _prepare_output(args: argparse.Namespace):
    """Clean what a killed run left (temporary files) and open the PatchMatch checkpoint of OUT."""
    from engine.checkpoint import CHECKPOINT_DIR, PatchMatchCheckpoint
    from engine.io.atomic import remove_stale_temp_files

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise DeepCError("--out exists and is not a folder", out)
    try:
        removed = remove_stale_temp_files(out) if out.is_dir() else []
    except OSError as exc:
        raise DeepCError(f"cannot clean the output folder: {exc.strerror or exc}", out) from None
    if removed:
        print(f"removed {len(removed)} temporary file(s) left by an interrupted run", file=sys.stderr)
    return PatchMatchCheckpoint(out / CHECKPOINT_DIR, resume=args.resume)


_CHECKED_WEIGHTS: set[tuple[str, int, int]] = set()


def _check_weights(path: Path) -> None:
    """Load the weights once (network built, every tensor checked) so that bad weights fail before anything
    runs; a suite naming the same file many times checks it once (keyed by size and modification time)."""
    from engine.confidence.weights import load_weights

    try:
        stat = path.stat()
        key = (str(path), stat.st_size, stat.st_mtime_ns)
    except OSError:
        key = None
    if key is None or key not in _CHECKED_WEIGHTS:
        load_weights(path)
        _CHECKED_WEIGHTS.add(key)


def _default_weights() -> Path:
    from engine.confidence.weights import DEFAULT_WEIGHTS
    return DEFAULT_WEIGHTS


def _open_recording(path: str | None, scene, options, stream_options, live_url: str | None = None):
    from layouts import DEFAULT, LAYOUTS
    from workbench.recording import Recording
    from workbench.stream import RerunStream, entity_name

    blueprint = LAYOUTS[DEFAULT]([entity_name(v.index, v.name) for v in scene.views])
    recording = Recording(path, blueprint, live_url)
    views = [(v.name, v.camera, scene.image(v.index), v.source_views) for v in scene.views]
    gt = [scene.gt_depth(v.index) for v in scene.views]
    recording.stream = RerunStream(recording.rec, views, gt, stream_options,
                                   pass_iterations=options.patchmatch.pass_iterations)
    recording.stream.set_depth_ranges([v.depth_range for v in scene.views])
    return recording


def _print_run_summary(metrics: dict, out: str) -> None:
    seconds = metrics["seconds"]
    print(f"{metrics['scene']}: {metrics['num_images']} views at {metrics['image_size'][0]}x"
          f"{metrics['image_size'][1]}, pipeline {metrics['pipeline']}, {seconds['total']:.1f} s "
          f"(PatchMatch {seconds['patchmatch']:.1f} s)")
    if "depth" in metrics:
        d = metrics["depth"]
        print(f"depth vs GT: within 1% {d['within_1pct']:.1f}%, within 5% {d['within_5pct']:.1f}%, "
              f"valid {d['valid_fraction']:.1f}%, abs rel {d['abs_rel']:.4f}")
    if "refined_depth" in metrics:
        d = metrics["refined_depth"]
        print(f"refined depth vs GT: within 1% {d['within_1pct']:.1f}%, within 5% {d['within_5pct']:.1f}%, "
              f"valid {d['valid_fraction']:.1f}% ({seconds['refinement']:.1f} s)")
    if metrics["pipeline"] in ("fast", "full"):
        auc = f", ROC-AUC vs labels {metrics['confidence_auc']:.2f}" if "confidence_auc" in metrics else ""
        print(f"confidence: {seconds['confidence']:.1f} s, {metrics['confidence_kept_pct']:.1f}% of the estimates "
              f"kept at tau {metrics['options']['confidence']['tau']:g}{auc}")
    print(f"fused cloud: {metrics['fused_points']:,} points ({seconds['fusion']:.1f} s)")
    if "eval" in metrics:
        e = metrics["eval"]
        for t, a, c, f in zip(e["tolerances"], e["accuracy"], e["completeness"], e["f1"], strict=True):
            if abs(t - 0.02) < 1e-9 or abs(t - 0.05) < 1e-9:
                print(f"at {t * 100:g} cm: F1 {f:.1f}, accuracy {a:.1f}, completeness {c:.1f}")
    print(f"outputs in {out}")


def add_run_option_flags(parser: argparse.ArgumentParser) -> None:
    """The flags that choose what ``deepc run`` computes (pipeline and stage options); a regression
    suite's entries use the same names."""
    parser.add_argument("--pipeline", choices=("vanilla", "fast", "full"), default="vanilla",
                        help="vanilla: PatchMatch + fusion; fast: + confidence filtering; full: + refinement")
    add_options_flags(parser.add_argument_group("scene"), SceneOptions)
    from engine.patchmatch import PatchMatchOptions
    add_options_flags(parser.add_argument_group("patchmatch"), PatchMatchOptions, only=RUN_PATCHMATCH_FLAGS)
    from engine.fusion import DEFAULT_PRESET, FUSION_PRESETS, FusionOptions
    fusion_group = parser.add_argument_group("fusion")
    fusion_group.add_argument("--fusion-preset", choices=sorted(FUSION_PRESETS), default=None,
                              help=f"fusion thresholds (default: {DEFAULT_PRESET} = 1 px, 1%%, 20°, 2 pixels, "
                                   "every kept pixel its own point, every pipeline; dense = 0.5 px, one median "
                                   "point per cluster; SPEC §7.3's: deepc = the paper's 1 px, 1%%, 20°, 3 pixels, "
                                   "refined_paper = its 5° for refined maps, colmap, acmm, deepc_lowres); "
                                   "the flags below override single values")
    add_options_flags(fusion_group, FusionOptions, only=["max_reproj_error", "max_depth_error", "max_normal_error",
                                                         "min_num_pixels", "point_per_pixel"])
    parser.add_argument("--weights", metavar="FILE", default=None,
                        help="confidence-network weights for --pipeline fast and full (default: the shipped "
                             "engine/confidence/weights/deepc_middle.pt); the filter threshold is "
                             "--set confidence.tau=0.1")
    parser.add_argument("--set", action="append", default=[], metavar="STAGE.NAME=VALUE",
                        help="any other stage option, e.g. --set patchmatch.tau0=0.7, --set confidence.tau=0.3, "
                             "--set fusion.check_num_images=20, "
                             "or thin the rerun stream: --set stream.every=2, stream.view=0, stream.max_size=160")


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
    run.add_argument("--record", metavar="FILE.rrd", nargs="?", const="", default=None,
                     help="write a rerun recording (default path: OUT/recording.rrd)")
    run.add_argument("--headless", action="store_true",
                     help="no viewer, no window: print progress and exit (otherwise the run streams live to rerun "
                          "and the result opens in the browser viewer)")
    run.add_argument("--resume", action="store_true",
                     help="continue an interrupted run in OUT: reuse its verified per-view PatchMatch states "
                          "(same scene, options and seed give the same outputs as an uninterrupted run)")
    run.add_argument("--max-memory", type=float, metavar="MB",
                     help="refuse the run if its estimated peak memory exceeds this (default: what is available)")
    run.add_argument("--ignore-memory-check", action="store_true",
                     help="run even when the estimated peak memory exceeds the available memory")
    run.add_argument("--host", default="127.0.0.1", help="address the viewers bind (default: 127.0.0.1)")
    run.add_argument("--port", type=int, default=8080, help="port of the browser viewer (default: 8080)")
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
    ev.set_defaults(handler=_eval)

    view = sub.add_parser("view", help="the live-tuning browser viewer (viser)")
    view.add_argument("target", metavar="OUT_OR_SCENE")
    view.add_argument("--host", default="127.0.0.1", help="address to bind (default: 127.0.0.1, this machine only)")
    view.add_argument("--port", type=int, default=8080)
    view.set_defaults(handler=_view)

    replay = sub.add_parser("replay", help="replay a .rrd recording in the rerun viewer")
    replay.add_argument("recording", metavar="FILE.rrd")
    replay.add_argument("--layout", default=None,
                        help="blueprint from layouts/: iterations, pipelines or confidence (default: the one "
                             "embedded in the recording)")
    replay.add_argument("--web", action="store_true", help="serve the web viewer even when there is a display")
    replay.add_argument("--host", default="127.0.0.1", help="address of the web viewer (default: 127.0.0.1)")
    replay.add_argument("--port", type=int, default=9090, help="port of the web viewer")
    replay.set_defaults(handler=_replay)

    regress = sub.add_parser("regress", help="headless regression runs against committed baselines",
                             description="Run every scene x pipeline of a suite headless, compare the metrics with "
                                         "the baselines, print the deltas and write an HTML report. Exit 0 when "
                                         "nothing regressed, 1 when something did (named), 2 on bad input. A suite "
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
    from workbench.train_command import add_train_arguments
    add_train_arguments(train)
    train.set_defaults(handler=_train)
    return parser


def _warning_line(message, category, filename, lineno, file=None, line=None):  # noqa: ARG001
    print(f"deepc: warning: {' '.join(str(message).split())}", file=sys.stderr)


def _terminate(signum, frame):  # noqa: ARG001
    # SIGTERM cleans up like Ctrl+C: no orphaned viewer, no partial file (deferred during `run`'s pipeline)
    raise KeyboardInterrupt


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    warnings.showwarning = _warning_line
    import pycolmap  # noqa: F401  (its glog installs a SIGTERM handler that aborts: ours must come after)
    signal.signal(signal.SIGTERM, _terminate)
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
