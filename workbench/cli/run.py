"""``deepc run SCENE --out OUT``: reconstruct a scene, streaming it live or recording it, then view the result.

Without ``--headless`` the run streams to rerun and to the live 3-D viewer (``workbench/viewer/live.py``),
whose server becomes the tuning viewer of the run when it ends (``workbench.viewer.app.serve``).

Before anything runs, the estimated peak memory is checked against what is available (``engine/run/memory.py``)
and what a killed run left in OUT is cleaned; ``--resume`` reuses the verified PatchMatch states of an
interrupted run. SIGINT and SIGTERM stop the run at the engine's next safe point.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from engine.core.errors import DeepCError
from engine.core.interrupt import deferred_interrupts
from engine.core.observer import ObserverList
from engine.core.words import plural
from engine.io.atomic import remove_stale_temp_files
from engine.patchmatch.probe.pixel_probe import PixelProbe
from engine.run.checkpoint import CHECKPOINT_DIR, PatchMatchCheckpoint
from engine.run.eta import LATER_SHARE, RunEta, format_minutes, pass_plan
from engine.run.folder import RunMetrics
from engine.run.fused_maps import FusionRule
from engine.run.memory import estimate_run_memory, largest_fitting_size, load_kernels
from engine.run.pass_history import HISTORY_DIR, PassHistory
from engine.run.per_view import SceneView
from engine.run.pipeline import PipelineOptions, run_pipeline
from engine.run.probe import probe_run, resolve_view
from engine.run.probe_output import PROBES_DIR
from engine.run.view_shares import view_share_lines
from engine.scene import Scene, load_scene, working_size_line
from workbench.cli.progress import PassProgress
from workbench.flags.run import parse_probe
from workbench.flags.run_options import mesh_options, run_options_from_args


def cmd_run(args: argparse.Namespace) -> int:
    scene_options, options, stream_options = run_options_from_args(args)
    mesh = mesh_options(args.mesh, args.set)
    scene = load_scene(args.scene, scene_options)
    print(scene.summary(), file=sys.stderr)
    print(working_size_line(scene.views, scene_options.max_image_size, scene.image_sizes), file=sys.stderr)
    _check_memory(args, scene, options)
    checkpoint = _prepare_output(args)
    executor = _executor(args)
    probe, history = _probe_and_history(args, scene, executor is None)
    record = None if args.record is None else (args.record or str(Path(args.out) / "recording.rrd"))
    live = recording = live_view = None
    progress = PassProgress()
    eta = progress.eta = _run_eta(scene, options, progress)
    try:
        if not args.headless:
            from workbench.rerun.replay import live_viewer  # lazy: rerun

            live = live_viewer(args.host)
            print(f"live PatchMatch stream: {live.url}", file=sys.stderr)
            from workbench.viewer.live import start_live_viewer  # lazy: viser

            live_view = start_live_viewer(scene, options, args.host, args.port, mesh=mesh.method != "none")
            live_view.eta = eta
        if record or live:
            from workbench.rerun.run_recording import open_run_recording  # lazy: rerun

            recording = open_run_recording(record, scene, options, stream_options, live.grpc_url if live else None)
            if live_view is not None:  # the live 3-D viewer colours by the confidence the stream scores
                for companion in recording.stream.companions:
                    if hasattr(companion, "listeners"):
                        companion.listeners.append(live_view.set_confidence)
        try:
            # SIGINT/SIGTERM stop the run at the engine's next safe point, never inside a kernel call
            with deferred_interrupts():
                observer = _observer(eta, recording.stream if recording else None, live_view)
                result = run_pipeline(scene, args.out, options, observer=observer, progress=progress,
                                      checkpoint=checkpoint, mesh=mesh, probe=probe, history=history,
                                      executor=executor)
        except BaseException:
            if recording:
                recording.abandon()
            raise
        finally:
            progress.close()
        traces = _probe_traces(args, probe, history, checkpoint)
        if recording:
            if traces:
                from workbench.rerun.probe import log_probe  # lazy: rerun

                for trace in traces:
                    log_probe(recording.stream.rec, scene, trace, options.patchmatch.window)
            recording.finish()
            if record:
                print(f"recording: {record} ({recording.stream.logged_steps} logged iterations)", file=sys.stderr)
        if checkpoint.stats.reused or checkpoint.stats.rejected:
            print(f"resumed: {checkpoint.stats.reused} saved PatchMatch view states reused, "
                  f"{checkpoint.stats.rejected} rejected and recomputed", file=sys.stderr)
        print_run_summary(RunMetrics.from_dict(result.metrics), args.out)
        if probe is not None:
            print(f"probe: {len(probe.pixels)} pixel trace(s) of view {probe.view_name} in "
                  f"{Path(args.out) / PROBES_DIR / probe.view_name}", file=sys.stderr)
        if not args.headless:
            from workbench.viewer.app import serve  # lazy: viser

            serve(args.out, host=args.host, port=args.port, server=live_view.hand_over(), on_open=live_view.release)
    finally:
        if live_view:
            live_view.stop()
        if live:
            live.stop()
        if executor is not None:
            executor.close()
    return 0


def _probe_traces(args: argparse.Namespace, probe: PixelProbe | None, history: PassHistory | None,
                  checkpoint: PatchMatchCheckpoint) -> list[dict]:
    """The traces of ``--probe`` after the run (also logged to its recording)."""
    if probe is None:
        return []
    if checkpoint.stats.reused and history is not None:
        # passes restored from the checkpoint were not traced: trace the view again from the history
        return probe_run(args.out, probe.view, probe.pixels)
    return probe.traces()


def _probe_and_history(args: argparse.Namespace, scene: Scene,
                       local: bool = True) -> tuple[PixelProbe | None, PassHistory | None]:
    """The pixel probe of ``--probe`` (checked against the scene before anything runs) and the pass history
    (neither with per-view tasks on Dask: ``local`` False)."""
    probe = None
    if getattr(args, "probe", None) and not local:
        raise DeepCError("--probe needs --executor local")
    if not local:
        if getattr(args, "history", False):
            print("no pass history with --executor dask: 'deepc probe' cannot trace this run later", file=sys.stderr)
        return None, None
    if getattr(args, "probe", None):
        name, pixels = parse_probe(args.probe)
        probe = PixelProbe(resolve_view([u.name for u in scene.views], name), pixels)
        v = scene.views[probe.view]
        probe.bind([u.name for u in scene.views], [(u.camera.width, u.camera.height) for u in scene.views],
                   [list(u.source_views) for u in scene.views])
        print(f"probe: {len(probe.pixels)} pixel(s) of view {v.name}", file=sys.stderr)
    history = PassHistory(Path(args.out) / HISTORY_DIR) if getattr(args, "history", False) else None
    return probe, history


def _run_eta(scene: Scene, options: PipelineOptions, progress: PassProgress) -> RunEta:
    """The whole run's ETA (``engine/run/eta.py``): timed from PatchMatch's first view on, which is the
    calibration a line announces ("estimated N min on this machine")."""
    def announce(seconds: float) -> None:
        progress.note(f"estimated {format_minutes(seconds)} on this machine for the rest of the run (a rough "
                      "estimate from the first view; the bars show the run's ETA as it runs)")

    plan = pass_plan([SceneView(scene, i) for i in range(len(scene.views))], options.patchmatch)
    return RunEta(plan, LATER_SHARE.get(options.pipeline, 0.1), on_first_view=announce)


def _observer(*observers: object | None) -> object | None:
    """The run's observer: those given that run (the rerun stream, the live 3-D viewer), fanned out when there
    are several; None when none runs, so that the engine builds no events at all."""
    present = [o for o in observers if o is not None]
    return None if not present else present[0] if len(present) == 1 else ObserverList(present)


def _executor(args: argparse.Namespace):
    """None for ``--executor local`` (the in-process pipeline), else the Dask executor (its dashboard printed)."""
    if getattr(args, "executor", "local") == "local":
        return None
    if args.workers < 1:
        raise DeepCError("--workers must be at least 1")
    from engine.run.distributed.dask_executor import DaskExecutor  # lazy: dask

    executor = DaskExecutor(args.scheduler, args.workers)
    print(executor.describe(), file=sys.stderr)
    return executor


def _check_memory(args: argparse.Namespace, scene: Scene, options: PipelineOptions) -> None:
    """Refuse a run whose estimated peak memory does not fit (engine/run/memory.py), naming a size that does."""
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


def _prepare_output(args: argparse.Namespace) -> PatchMatchCheckpoint:
    """Clean what a killed run left (temporary files) and open the PatchMatch checkpoint of OUT."""
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


def print_run_summary(metrics: RunMetrics, out: str) -> None:
    """What ``deepc run`` prints when it is done: sizes, times, depth and cloud quality."""
    seconds = metrics.seconds
    print(f"{metrics.scene}: {plural(metrics.num_images, 'view')} at {metrics.image_size[0]}x"
          f"{metrics.image_size[1]}, pipeline {metrics.pipeline}, {seconds['total']:.1f} s "
          f"(PatchMatch {seconds['patchmatch']:.1f} s)")
    if metrics.depth is not None:
        d = metrics.depth
        print(f"depth vs GT: within 1% {d['within_1pct']:.1f}%, within 5% {d['within_5pct']:.1f}%, "
              f"valid {d['valid_fraction']:.1f}%, abs rel {d['abs_rel']:.4f}")
    if metrics.refined_depth is not None:
        d = metrics.refined_depth
        print(f"refined depth vs GT: within 1% {d['within_1pct']:.1f}%, within 5% {d['within_5pct']:.1f}%, "
              f"valid {d['valid_fraction']:.1f}% ({seconds['refinement']:.1f} s)")
    if metrics.pipeline in ("fast", "full"):
        auc = f", ROC-AUC vs labels {metrics.confidence_auc:.2f}" if metrics.confidence_auc is not None else ""
        rule = FusionRule.from_saved(metrics.options, metrics.pipeline)  # the threshold the filter applied
        print(f"confidence: {seconds['confidence']:.1f} s, {metrics.confidence_kept_pct:.1f}% of the estimates "
              f"kept at {rule.threshold_option} {rule.fused_confidence_tau:g}{auc}")
    print(f"fused cloud: {metrics.fused_points:,} points ({seconds['fusion']:.1f} s)")
    if metrics.views:
        lines, warnings = view_share_lines(metrics.views)
        print("\n".join(lines))
        for line in warnings:
            print(line, file=sys.stderr)
    if metrics.eval is not None:
        e = metrics.eval
        for t, a, c, f in zip(e["tolerances"], e["accuracy"], e["completeness"], e["f1"], strict=True):
            if abs(t - 0.02) < 1e-9 or abs(t - 0.05) < 1e-9:
                print(f"at {t * 100:g} cm: F1 {f:.1f}, accuracy {a:.1f}, completeness {c:.1f}")
    if metrics.mesh is not None:
        print_mesh_summary(metrics.mesh)
    print(f"outputs in {out}")


def print_mesh_summary(mesh: dict) -> None:
    """One line for the mesh, its notes, and its F1 at 2 and 5 cm when it was scored."""
    voxel = f", voxel {mesh['voxel']:.3g}" if mesh.get("voxel") else ""
    print(f"mesh ({mesh['method']}{voxel}): {mesh['vertices']:,} vertices, {mesh['triangles']:,} triangles "
          f"({mesh['seconds']:.1f} s)")
    for note in mesh.get("notes", []):
        print(f"mesh: {note}")
    e = mesh.get("eval")
    if e is not None:
        for t, a, c, f in zip(e["tolerances"], e["accuracy"], e["completeness"], e["f1"], strict=True):
            if abs(t - 0.02) < 1e-9 or abs(t - 0.05) < 1e-9:
                print(f"mesh at {t * 100:g} cm: F1 {f:.1f}, accuracy {a:.1f}, completeness {c:.1f}")
