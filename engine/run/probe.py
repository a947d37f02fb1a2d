"""The pixel probe on a finished run, and PatchMatch re-run on a region of one view with changed options.

A view's PatchMatch depends, besides its own inputs, only on the source depth maps its geometric passes read;
``deepc run`` keeps those in ``OUT/history/`` (``engine.run.pass_history``). :func:`probe_run` re-runs the probed
view alone through every level and pass (``patchmatch.engine.replay_view``: the run's maps bit for bit) with
the probe on, so that the last trace entry's ``after.depth`` is the stored depth. :func:`rerun_region` starts
from the exact state a given level and pass started from, re-runs a crop of the view (plus the margin the
window and the sampling pattern read) with changed options through the remaining passes and levels, and
compares the crop's depth before and after with GT. A replay's pass-start states are kept in memory (the last
few views) and on disk (``engine.run.probe_states``, bounded): a second probe of the same view, in this process or
a later one, starts every pass from them and updates only the pixels the probed ones depend on
(``engine.patchmatch.probe.partial``: the same traces, entry for entry), and a region re-run starts at once.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from engine.core.camera import Camera
from engine.core.errors import DeepCError
from engine.core.words import plural
from engine.patchmatch import PatchMatchOptions, PatchMatchView, effective_levels
from engine.patchmatch.multiscale import level_start, replay_view, run_view_pass, view_pyramids
from engine.patchmatch.probe.partial import trace_from_states
from engine.patchmatch.probe.pixel_probe import PixelProbe, level_pixel
from engine.patchmatch.propagation import sampling_pattern
from engine.patchmatch.pyramid import level_size
from engine.patchmatch.state import ViewState
from engine.run.folder import map_path, read_map, read_run_metrics, run_scene
from engine.run.pass_history import HISTORY_DIR, PassHistory
from engine.run.pipeline import PipelineOptions, patchmatch_views
from engine.run.probe_output import final_entries, final_region, view_gt_depth, write_traces
from engine.run.probe_states import StateStore, ViewStates

ProgressFn = Callable[[str, int, int], Any]
#: options a region re-run cannot change (they change the schedule the stored states belong to)
FIXED_OPTIONS = ("levels", "min_level_size", "geom_passes")
_CACHE_VIEWS = 2  # replays kept in memory (each: the view's states at every pass start, ~the view's maps x 4)


@dataclasses.dataclass
class _Run:
    """A finished run's scene, PatchMatch inputs and options, and its pass history."""

    run_dir: Path
    scene: Any
    views: list[PatchMatchView]
    options: PipelineOptions
    n_levels: int
    history: PassHistory
    # (level, pass) -> {view: the depth map that geometric pass read}, as the probes of this run have loaded them
    snapshots: dict[tuple[int, int], dict[int, np.ndarray]] = dataclasses.field(default_factory=dict)
    gt: dict[int, np.ndarray | None] = dataclasses.field(default_factory=dict)  # view -> GT depth at the maps' size
    # view -> (images, cameras) of its pyramid: a probe of any view needs its sources' too, so they are made once
    pyramid: dict[int, tuple[list, list]] = dataclasses.field(default_factory=dict)
    # the run's final maps as written (every view's depth; per view its other maps and final_region), read once
    final_depths: list[np.ndarray] | None = None
    final_maps: dict[int, dict[str, np.ndarray | None]] = dataclasses.field(default_factory=dict)
    final_regions: dict[int, np.ndarray | None] = dataclasses.field(default_factory=dict)

    def gt_depth(self, i: int, shape: tuple[int, int]) -> np.ndarray | None:
        """View ``i``'s GT depth at its maps' ``shape`` (H, W) (``probe_output.view_gt_depth``), read once."""
        if i not in self.gt:
            self.gt[i] = view_gt_depth(self.scene, i, shape)
        return self.gt[i]

    def pyramids(self, needed: set[int]) -> tuple[list, list]:
        """``multiscale.view_pyramids`` of the views ``needed`` (None for the others), each made once."""
        missing = sorted(j for j in needed if j not in self.pyramid)
        if missing:
            images, cameras = view_pyramids([u if j in missing else None for j, u in enumerate(self.views)],
                                            self.n_levels)
            for j in missing:
                self.pyramid[j] = (images[j], cameras[j])
        return ([self.pyramid[j][0] if j in needed else None for j in range(len(self.views))],
                [self.pyramid[j][1] if j in needed else None for j in range(len(self.views))])

    def load_snapshot(self, level: int, pass_index: int, indices: list[int]) -> dict[int, np.ndarray]:
        """``PassHistory.load_snapshot``, each view's map read from disk once."""
        kept = self.snapshots.setdefault((level, pass_index), {})
        missing = [j for j in indices if j not in kept]
        if missing:
            kept.update(self.history.load_snapshot(level, pass_index, missing))
        return {j: kept[j] for j in indices}


@dataclasses.dataclass
class _Replay:
    """One view's replay: its state at every pass start (level, pass) and level end (level, 'end'), the
    iterations each pass ran, the pyramids of the view and its sources, and the fine-window regions of its passes
    (made by the first trace from these states)."""

    states: dict[tuple[int, Any], tuple[np.ndarray, np.ndarray]]
    iterations: dict[tuple[int, int], int]
    images: list
    cameras: list
    regions: dict = dataclasses.field(default_factory=dict)


_replays: collections.OrderedDict[tuple, _Replay] = collections.OrderedDict()


@dataclasses.dataclass
class RegionResult:
    """What :func:`rerun_region` found.

    Attributes:
        box: (x0, y0, width, height) at full resolution.
        depth_before, depth_after: (height, width) f32 depth of the box in the run and after the re-run (0 = none).
        error_before, error_after: (height, width) f32 relative error |z - z_gt| / z_gt (NaN where either is
            missing), or None without GT depth.
        within_1pct_before, within_1pct_after: % of the box's pixels with GT and an estimate that are within 1 %
            (``metrics.depth_metrics``), or None.
        traces: the probe's traces of ``probe_pixels`` (docs/probe_schema.md) over the re-run passes.
        seconds: wall-clock time of the call.
    """

    box: tuple[int, int, int, int]
    depth_before: np.ndarray
    depth_after: np.ndarray
    error_before: np.ndarray | None
    error_after: np.ndarray | None
    within_1pct_before: float | None
    within_1pct_after: float | None
    traces: list[dict[str, Any]]
    seconds: float


_runs: collections.OrderedDict[tuple, _Run] = collections.OrderedDict()


def _open_run(run_dir: str | Path) -> _Run:
    """The run in ``run_dir`` (kept in memory while its metrics.json is unchanged: loading the scene's images
    would otherwise dominate a region re-run)."""
    run_dir = Path(run_dir)
    try:
        key = (str(run_dir.resolve()), (run_dir / "metrics.json").stat().st_mtime_ns)
    except OSError:
        key = None
    if key in _runs:
        _runs.move_to_end(key)
        return _runs[key]
    run = _load_run(run_dir)
    if key is not None:
        _runs[key] = run
        while len(_runs) > _CACHE_VIEWS:
            _runs.popitem(last=False)
    return run


def _load_run(run_dir: Path) -> _Run:
    metrics = read_run_metrics(run_dir)
    options = PipelineOptions.from_dict({k: v for k, v in metrics.options.items() if k != "scene"}, saved=True)
    scene = run_scene(run_dir)
    views = patchmatch_views(scene)
    pm = options.patchmatch
    n_levels = effective_levels(views, pm)
    history = PassHistory(run_dir / HISTORY_DIR)
    history.open(views, pm, n_levels, [(lv, p) for lv in range(n_levels) for p in range(1, 1 + pm.geom_passes)])
    return _Run(run_dir, scene, views, options, n_levels, history)


def resolve_view(names: list[str], view: str | int) -> int:
    """The index of ``view`` among the views ``names`` (a name, or an index given as int or digits); a one-line
    :class:`DeepCError` if there is none."""
    if isinstance(view, str) and view in names:
        return names.index(view)
    if isinstance(view, (int, np.integer)) or (isinstance(view, str) and view.isdigit()):
        i = int(view)
        if 0 <= i < len(names):
            return i
        raise DeepCError(f"probe: view {i} does not exist (there are {plural(len(names), 'view')}, 0-{len(names) - 1})")
    shown = ", ".join(names[:6]) + (", ..." if len(names) > 6 else "")
    raise DeepCError(f"probe: no view named {view!r} (views: {shown})")


def forget_replays() -> None:
    """Drop the replays kept in memory (the run folders' state stores stay): the next probe of a view reads its
    states from disk, as a new process would."""
    _replays.clear()


def _memory_key(run: _Run, i: int) -> tuple:
    return str(run.run_dir.resolve()), i, map_path(run.run_dir, "depth", run.views[i].name).stat().st_mtime_ns


def _store(run: _Run) -> StateStore:
    return run.history.states.store


def _store_key(run: _Run, i: int) -> str | None:
    """The key of view ``i``'s stored states (``probe_states.replay_key``), None without a stored depth map."""
    depth = read_map(run.run_dir, "depth", run.views[i].name)
    return None if depth is None else run.history.view_key(i, depth)


def _remember(key: tuple, rep: _Replay) -> _Replay:
    _replays[key] = rep
    while len(_replays) > _CACHE_VIEWS:
        _replays.popitem(last=False)
    return rep


def _stored_replay(run: _Run, i: int) -> _Replay | None:
    """View ``i``'s replay from memory or from the run's state store (None if neither holds it)."""
    key = _memory_key(run, i)
    if key in _replays:
        _replays.move_to_end(key)
        return _replays[key]
    store_key = _store_key(run, i)
    got = None if store_key is None else _store(run).load(i, store_key)
    if got is None:
        return None
    v = run.views[i]
    needed = {i, *v.source_views}
    images, cameras = run.pyramids(needed)
    return _remember(key, _Replay(got.states, got.iterations, images, cameras))


def _replay(run: _Run, i: int, probe: PixelProbe | None = None, progress: ProgressFn | None = None,
            keep: bool = True) -> _Replay:
    """Replay view ``i`` of ``run`` whole (its traces into ``probe``), keeping its pass-start states in memory and,
    with ``keep``, in the run's state store; without a probe a kept replay is reused."""
    if probe is None:
        rep = _stored_replay(run, i)
        if rep is not None:
            return rep
    pm = run.options.patchmatch
    states: dict[tuple[int, Any], tuple[np.ndarray, np.ndarray]] = {}
    iterations: dict[tuple[int, int], int] = {}
    kept: dict[str, Any] = {"passes": 0}
    total = run.n_levels * (1 + pm.geom_passes)

    def on_pass(level: int, pass_index: int, phase: str, st: ViewState, images: list, cameras: list) -> None:
        states[(level, pass_index if phase == "start" else "end")] = (st.depth.copy(), st.normal.copy())
        kept["images"], kept["cameras"] = images, cameras
        if progress is not None and phase == "start":
            progress(f"replaying view {run.views[i].name}", kept["passes"], total)
            kept["passes"] += 1

    def on_iter(event: Any) -> None:  # a converged pass ends early: its length is part of the replay
        iterations[(event.level, event.pass_index)] = event.iteration + 1

    maps = replay_view(run.views, i, run.load_snapshot, pm, probe=probe, on_pass=on_pass, on_iter=on_iter,
                       pyramids=run.pyramids({i, *run.views[i].source_views}))
    stored = read_map(run.run_dir, "depth", run.views[i].name)
    if stored is None or not np.array_equal(maps.depth, stored):
        raise DeepCError(f"replaying view {run.views[i].name} does not give the run's depth map (the run was made "
                         "with other code or numba builds); re-run it to probe it", run.run_dir)
    rep = _Replay(states, iterations, kept["images"], kept["cameras"])
    if keep:
        store_key = _store_key(run, i)
        if store_key is not None:
            try:
                _store(run).save(i, store_key, ViewStates(states, iterations))
            except OSError:  # a read-only or full run folder: later probes replay whole, as without the store
                pass
    return _remember(_memory_key(run, i), rep)


def _traced_from_states(run: _Run, i: int, probe: PixelProbe) -> bool:
    """Trace ``probe``'s pixels from view ``i``'s kept states (``probe.partial``); False (the probe's traces
    left empty) when none are kept or the traces do not end on the run's depth (a stale store)."""
    rep = _stored_replay(run, i)
    if rep is None:
        return False
    trace_from_states(run.views, i, rep.states, rep.iterations, run.load_snapshot, run.options.patchmatch, probe,
                      (rep.images, rep.cameras), rep.regions)
    stored = _stored_maps(run, i)[0][i]  # (zeros without a depth map: no trace ends on them)
    for t in probe.traces():
        if not t["iterations"] or t["iterations"][-1]["after"]["depth"] != float(
                stored[t["y"], t["x"]]):
            _replays.pop(_memory_key(run, i), None)
            return False
    return True


def _stored_maps(run: _Run, i: int) -> tuple[list[np.ndarray], dict[str, np.ndarray | None]]:
    """Every view's written depth (zeros where none) and view ``i``'s other maps, each read once per run (a
    re-run rewrites metrics.json, which opens the run anew)."""
    if run.final_depths is None:
        depths = []
        for v in run.views:
            d = read_map(run.run_dir, "depth", v.name)
            depths.append(d if d is not None else np.zeros((v.camera.height, v.camera.width), np.float32))
        run.final_depths = depths
    if i not in run.final_maps:
        name = run.views[i].name
        run.final_maps[i] = {kind: read_map(run.run_dir, kind, name)
                             for kind in ("normal", "cost", "counter", "confidence")}
    return run.final_depths, run.final_maps[i]


def _final_region(run: _Run, i: int, depths: list[np.ndarray], normal: np.ndarray | None) -> np.ndarray | None:
    """View ``i``'s ``final_region`` (for the counter verdicts), made once per run; None without a normal map."""
    if normal is None:
        return None
    if i not in run.final_regions:
        run.final_regions[i] = final_region(depths[i], normal, run.views[i])
    return run.final_regions[i]


def probe_run(run_dir: str | Path, view: str | int, pixels: list[tuple[int, int]],
              progress: ProgressFn | None = None, stored_states: bool = True) -> list[dict[str, Any]]:
    """Traces of ``pixels`` ((x, y) at full resolution, at most 64) of ``view`` (name or index) in the finished
    run ``run_dir``, as ``deepc run --probe`` would have written them: written to
    ``OUT/probes/<view>/<x>_<y>.json`` (atomically) and returned. ``progress(description, done, total)`` per
    pass of a whole replay. The first probe of a view replays it whole and keeps its pass-start states;
    later ones trace from them (the same traces; ``stored_states`` False: always replay whole and keep nothing
    on disk). Bad views or pixels and runs without a usable history raise a one-line :class:`DeepCError`."""
    run = _open_run(run_dir)
    i = resolve_view([u.name for u in run.views], view)
    probe = PixelProbe(i, pixels)
    probe.bind([v.name for v in run.views], [(v.camera.width, v.camera.height) for v in run.views],
               [list(v.source_views) for v in run.views])  # bad pixels fail before the replay
    if not (stored_states and _traced_from_states(run, i, probe)):
        _replay(run, i, probe, progress, keep=stored_states)
    depths, maps = _stored_maps(run, i)
    finals = final_entries(run.scene, i, run.views, depths, maps["normal"], maps["cost"], maps["counter"],
                           maps["confidence"], probe.pixels, run.options.counter, run.gt_depth(i, depths[i].shape),
                           _final_region(run, i, depths, maps["normal"]))
    for p, f in zip(probe.pixels, finals, strict=True):
        probe.set_final(p, f)
    traces = probe.traces()
    write_traces(run.run_dir, traces)
    return traces


def _margin(options: PatchMatchOptions) -> int:
    """Pixels around a crop that its pixels read in one half-step: the farthest pattern sample and half the
    larger matching window."""
    offsets, _ = sampling_pattern(options.pattern)
    window = max(options.window, options.fine_window)
    return int(np.abs(offsets).max()) + window // 2 + 1


def _crop_camera(cam: Camera, x0: int, y0: int, w: int, h: int) -> Camera:
    """The camera of the (w, h) crop at (x0, y0) of ``cam``'s image (principal point moved)."""
    K = cam.K.copy()
    K[0, 2] -= x0
    K[1, 2] -= y0
    return Camera(w, h, K, cam.R, cam.t)


def _options_with(options: PatchMatchOptions, overrides: dict[str, object] | None) -> PatchMatchOptions:
    overrides = dict(overrides or {})
    for name in overrides:
        if PatchMatchOptions.field_name(name) is None:
            raise DeepCError(f"region re-run: unknown PatchMatch option {name!r}")
        if PatchMatchOptions.field_name(name) in FIXED_OPTIONS:
            raise DeepCError(f"region re-run: {name} cannot change (the stored states belong to the run's "
                             f"{', '.join(FIXED_OPTIONS)})")
    return PatchMatchOptions.from_dict({**options.to_dict(), **overrides})


def rerun_region(run_dir: str | Path, view: str | int, box: tuple[int, int, int, int], level: int = 0,
                 pass_index: int = 0, overrides: dict[str, object] | None = None,
                 probe_pixels: list[tuple[int, int]] | tuple = ()) -> RegionResult:
    """Re-run PatchMatch on ``box`` = (x0, y0, width, height) (full resolution) of ``view`` of the finished run
    ``run_dir``, from the state pass ``pass_index`` of ``level`` started from, with the PatchMatch options
    changed by ``overrides`` (field names -> values; not levels, min_level_size, geom_passes), through the
    remaining passes of that level and all finer levels; ``probe_pixels`` (inside the box) are traced.

    At each level the crop is the box plus a margin (the farthest pattern sample and half the window) and has
    its own random streams; geometric passes read the run's source depth maps of that pass. Between levels the
    view's map of the run, with the box replaced by the re-run's, is upsampled as in the run. The first call for
    a view replays it once (then kept in memory)."""
    start = time.perf_counter()
    run = _open_run(run_dir)
    i = resolve_view([u.name for u in run.views], view)
    v = run.views[i]
    W, H = v.camera.width, v.camera.height
    try:
        x0, y0, bw, bh = (int(c) for c in box)
    except (TypeError, ValueError):
        raise DeepCError(f"region re-run: box must be (x0, y0, width, height), got {box!r}") from None
    if bw < 1 or bh < 1 or x0 < 0 or y0 < 0 or x0 + bw > W or y0 + bh > H:
        raise DeepCError(f"region re-run: box {(x0, y0, bw, bh)} is not inside view {v.name} ({W}x{H})")
    pm = run.options.patchmatch
    if not 0 <= level < run.n_levels:
        raise DeepCError(f"region re-run: level {level} does not exist (the run has levels 0-{run.n_levels - 1})")
    if not 0 <= pass_index <= pm.geom_passes:
        raise DeepCError(f"region re-run: pass {pass_index} does not exist (passes 0-{pm.geom_passes})")
    options = _options_with(pm, overrides)
    probe = None
    if probe_pixels:
        probe = PixelProbe(i, list(probe_pixels))
        probe.bind([u.name for u in run.views], [(u.camera.width, u.camera.height) for u in run.views],
                   [list(u.source_views) for u in run.views])
        outside = [p for p in probe.pixels if not (x0 <= p[0] < x0 + bw and y0 <= p[1] < y0 + bh)]
        if outside:
            raise DeepCError(f"region re-run: probe pixel {outside[0]} is outside the box {(x0, y0, bw, bh)}")
    rep = _replay(run, i)
    margin = _margin(options)
    done = sum(pm.pass_iterations(p) for lv in range(run.n_levels - 1, level, -1) for p in range(1 + pm.geom_passes))
    done += sum(pm.pass_iterations(p) for p in range(pass_index))
    full: ViewState | None = None
    crop_result = None
    for lv in range(level, -1, -1):
        lw, lh = level_size(W, H, lv)
        bx0, by0 = level_pixel(x0, y0, W, H, lw, lh)
        bx1, by1 = (c + 1 for c in level_pixel(x0 + bw - 1, y0 + bh - 1, W, H, lw, lh))
        cx0, cy0 = max(0, bx0 - margin), max(0, by0 - margin)
        cx1, cy1 = min(lw, bx1 + margin), min(lh, by1 + margin)
        if (cx0 + cy0) % 2:  # an even origin: every crop pixel keeps its red-black colour of the full level
            cx0, cy0 = (cx0 - 1, cy0) if cx0 > 0 else (cx0, cy0 - 1)
        if lv == level:
            depth, normal = rep.states[(level, pass_index)]
            full = ViewState(depth.copy(), normal.copy(), np.zeros((lh, lw), np.float32), np.zeros((lh, lw), np.uint32))
            first = pass_index
        else:
            full = level_start(run.views, i, full, rep.images, rep.cameras, lv, options)
            first = 0
        st = ViewState(np.ascontiguousarray(full.depth[cy0:cy1, cx0:cx1]),
                       np.ascontiguousarray(full.normal[cy0:cy1, cx0:cx1]),
                       np.zeros((cy1 - cy0, cx1 - cx0), np.float32), np.zeros((cy1 - cy0, cx1 - cx0), np.uint32))
        images = list(rep.images)
        cameras = list(rep.cameras)
        images[i] = list(images[i])
        cameras[i] = list(cameras[i])
        images[i][lv] = np.ascontiguousarray(rep.images[i][lv][cy0:cy1, cx0:cx1])
        cameras[i][lv] = _crop_camera(rep.cameras[i][lv], cx0, cy0, cx1 - cx0, cy1 - cy0)
        for p in range(first, 1 + pm.geom_passes):
            snapshot = None
            if p > 0:
                got = run.load_snapshot(lv, p, list(v.source_views))
                snapshot = [got.get(j) for j in range(len(run.views))]
            run_view_pass(run.views, i, st, images, cameras, snapshot, lv, p, run.n_levels, options, done, probe,
                          origin=(cx0, cy0))
            done += options.pass_iterations(p)
        # the level's end: the run's map with the box replaced by the re-run's
        end_depth, end_normal = rep.states[(lv, "end")]
        full = ViewState(end_depth.copy(), end_normal.copy(), np.zeros((lh, lw), np.float32),
                         np.zeros((lh, lw), np.uint32))
        ix0, iy0, ix1, iy1 = bx0 - cx0, by0 - cy0, bx1 - cx0, by1 - cy0
        full.depth[by0:by1, bx0:bx1] = st.depth[iy0:iy1, ix0:ix1]
        full.normal[by0:by1, bx0:bx1] = st.normal[iy0:iy1, ix0:ix1]
        crop_result = st, (ix0, iy0)
    st, (ix0, iy0) = crop_result
    depth_after = np.array(st.depth[iy0:iy0 + bh, ix0:ix0 + bw], np.float32)
    stored = read_map(run.run_dir, "depth", v.name)
    depth_before = np.array(stored[y0:y0 + bh, x0:x0 + bw], np.float32)
    gt = run.gt_depth(i, stored.shape)
    gt_box = None if gt is None else np.asarray(gt, np.float32)[y0:y0 + bh, x0:x0 + bw]
    err_b, pct_b = _errors(depth_before, gt_box)
    err_a, pct_a = _errors(depth_after, gt_box)
    traces: list[dict[str, Any]] = []
    if probe is not None:
        for p in probe.pixels:
            lx, ly = p[0] - x0 + ix0, p[1] - y0 + iy0
            z = float(st.depth[ly, lx])
            g = float(gt_box[p[1] - y0, p[0] - x0]) if gt_box is not None else math.nan
            g = g if math.isfinite(g) and g > 0 else None
            probe.set_final(p, {"depth": z, "normal": [float(c) for c in st.normal[ly, lx]],
                                "cost": float(st.cost[ly, lx]), "counter_verdicts": None, "confidence": None,
                                "gt_depth": g, "label": None,
                                "error": abs(z - g) / g if g is not None and z > 0 else None})
        traces = probe.traces()
    return RegionResult((x0, y0, bw, bh), depth_before, depth_after, err_b, err_a, pct_b, pct_a, traces,
                        time.perf_counter() - start)


def _errors(depth: np.ndarray, gt: np.ndarray | None) -> tuple[np.ndarray | None, float | None]:
    """Relative error map (NaN where either is missing) and % of the pixels with both within 1 %
    (``metrics.depth_metrics``'s within_1pct; None without GT or without such pixels)."""
    if gt is None:
        return None, None
    both = np.isfinite(gt) & (gt > 0) & (depth > 0)
    err = np.full(depth.shape, np.nan, np.float32)
    err[both] = np.abs(depth[both].astype(np.float64) - gt[both]) / gt[both]
    return err, (100.0 * float((err[both] < 0.01).mean()) if both.any() else None)
