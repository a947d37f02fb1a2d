"""``deepc regress``: a suite of scenes × pipelines run headless, compared with baselines.

A suite is a TOML file::

    baseline = "../tests/baselines"     # baseline folder, relative to the suite file (default: baselines/)
    thumbnail_views = 4                 # views per run shown as map thumbnails in the report

    [defaults]                          # `deepc run` flags for every run (names as on the command line)
    schedule = "acmm"
    seed = 0

    [tolerances]                        # allowed worsening per metric; false = report only
    f1 = 0.5                            # points, at every evaluation tolerance the run reports
    time = 0.5                          # fraction: more than 50 % slower regresses

    [[scene]]                           # a COLMAP workspace, relative to the suite file
    path = "tiny"
    max-image-size = 160                # flags here apply to this scene's runs

    [[pipeline]]                        # every pipeline runs on every scene (or on `scenes = [...]`)
    name = "vanilla"
    pipeline = "vanilla"
    set = ["patchmatch.tau0=0.7"]       # --set STAGE.NAME=VALUE items

Flags merge in the order defaults < scene < pipeline. A run's outputs go to ``REPORT/<scene>/<pipeline>/``
exactly as ``deepc run --headless`` writes them; its baseline is ``BASELINE/<scene>/<pipeline>.json``.

Comparison: every metric with a tolerance is compared with the baseline; it regresses when it is worse
by more than the tolerance (higher is better except ``abs_rel`` and ``time``). F1, accuracy and
completeness are compared at *every* tolerance of the evaluation, not only at the 2 cm / 5 cm headline
ones: the runs are deterministic for a seed, so each of them is exact and a loss at a fine tolerance
(precision) is a real regression even when the coarse ones hide it. ``time`` is the wall-clock total of
the run and ``cpu_time`` its CPU seconds over all threads (``seconds_cpu``, added to metrics.json by regress:
on a shared machine the wall clock follows the other jobs' load, CPU time hardly does); both are measured
after an untimed warm-up that compiles the numba kernels, and only slower regresses. A run without a
baseline fails too (a suite entry nobody has checked is not a passed check).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import importlib.metadata
import json
import math
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

from engine import __version__
from engine.errors import DeepCError
from engine.io.atomic import write_json
from engine.run_folder import write_metrics

REPO_ROOT = Path(__file__).resolve().parent.parent
DEFAULT_SUITE = REPO_ROOT / "sample_scenes" / "suite.toml"
DEFAULT_REPORT = Path("runs/regress")
SUITE_KEYS = ("name", "baseline", "thumbnail_views", "defaults", "tolerances", "scene", "pipeline")
SCENE_KEYS = ("path", "name", "tolerances")
PIPELINE_KEYS = ("name", "scenes", "tolerances")
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
_WARM_UP_SIZE = 64  # px: quick, and still two pyramid levels, so every kernel (upsampling too) is compiled


# ---- metrics -------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class MetricSpec:
    """A compared metric: how to read it from metrics.json and which direction is worse.

    ``relative``: the tolerance is a fraction of the baseline value (time) instead of points.
    ``values(metrics)`` returns (row label, value) pairs; several for per-tolerance scores.
    """

    name: str
    description: str
    higher_is_better: bool
    relative: bool
    default_tolerance: float | None
    values: Callable[[dict[str, Any]], list[tuple[str, float | None]]]


def _eval_values(key: str) -> Callable[[dict[str, Any]], list[tuple[str, float | None]]]:
    def values(metrics: dict[str, Any]) -> list[tuple[str, float | None]]:
        block = metrics.get("eval") or {}
        return [(f"{key}@{t:g}", v) for t, v in zip(block.get("tolerances", []), block.get(key, []), strict=True)]
    return values


def _nested_value(label: str, *keys: str) -> Callable[[dict[str, Any]], list[tuple[str, float | None]]]:
    def values(metrics: dict[str, Any]) -> list[tuple[str, float | None]]:
        value: Any = metrics
        for key in keys:
            if not isinstance(value, dict) or key not in value:
                return []
            value = value[key]
        return [(label, value)]
    return values


METRICS: tuple[MetricSpec, ...] = (
    MetricSpec("f1", "F1 of the fused cloud (%, per evaluation tolerance)", True, False, 0.5, _eval_values("f1")),
    MetricSpec("accuracy", "accuracy of the fused cloud (%)", True, False, 0.5, _eval_values("accuracy")),
    MetricSpec("completeness", "completeness of the fused cloud (%)", True, False, 0.5,
               _eval_values("completeness")),
    MetricSpec("within_1pct", "PatchMatch depth within 1 % of GT (%)", True, False, 0.5,
               _nested_value("within_1pct", "depth", "within_1pct")),
    MetricSpec("within_5pct", "PatchMatch depth within 5 % of GT (%)", True, False, None,
               _nested_value("within_5pct", "depth", "within_5pct")),
    MetricSpec("valid_fraction", "GT pixels with a depth estimate (%)", True, False, None,
               _nested_value("valid_fraction", "depth", "valid_fraction")),
    MetricSpec("abs_rel", "mean relative depth error", False, False, None,
               _nested_value("abs_rel", "depth", "abs_rel")),
    MetricSpec("auc", "confidence ROC-AUC × 100", True, False, 0.5, _nested_value("auc", "confidence_auc")),
    MetricSpec("time", "wall-clock seconds of the run", False, True, 0.5, _nested_value("time", "seconds", "total")),
    MetricSpec("cpu_time", "CPU seconds of the run, all threads (hardly depends on the machine's load)", False, True,
               0.5, _nested_value("cpu_time", "seconds_cpu")),
)
METRIC_BY_NAME = {m.name: m for m in METRICS}
DEFAULT_TOLERANCES: dict[str, float | None] = {m.name: m.default_tolerance for m in METRICS}

OK, IMPROVED, REGRESSED, NEW, MISSING, INFO = "ok", "improved", "REGRESSED", "new", "MISSING", "info"
FAILED = (REGRESSED, MISSING)


@dataclasses.dataclass
class Delta:
    """One metric of one run against its baseline."""

    run: str
    metric: str
    label: str
    baseline: float | None
    current: float | None
    tolerance: float | None
    status: str

    @property
    def spec(self) -> MetricSpec:
        return METRIC_BY_NAME[self.metric]

    def change(self) -> float | None:
        """current - baseline (points), or the relative change for relative metrics."""
        if self.baseline is None or self.current is None:
            return None
        if self.spec.relative:
            return self.current / self.baseline - 1.0 if self.baseline > 0 else 0.0
        return self.current - self.baseline

    def explain(self) -> str:
        """e.g. 'tiny/vanilla f1@0.02 47.60 -> 45.70 (-1.90, allowed -0.5)'."""
        if self.status == MISSING:
            return f"{self.run} {self.label}: missing (baseline {_fmt(self, self.baseline)})"
        return (f"{self.run} {self.label} {_fmt(self, self.baseline)} -> {_fmt(self, self.current)} "
                f"({_fmt_change(self)}, allowed {_fmt_allowed(self)})")


def _number(value: Any) -> float | None:
    return float(value) if isinstance(value, (int, float)) and math.isfinite(value) else None


def compare(run: str, current: dict[str, Any], baseline: dict[str, Any] | None,
            tolerances: dict[str, float | None]) -> list[Delta]:
    """Deltas of every metric the current run or its baseline reports."""
    deltas = []
    for spec in METRICS:
        tol = tolerances.get(spec.name)
        now = {label: _number(v) for label, v in spec.values(current)}
        before = {label: _number(v) for label, v in spec.values(baseline or {})}
        for label in list(now) + [k for k in before if k not in now]:
            b, c = before.get(label), now.get(label)
            delta = Delta(run, spec.name, label, b, c, tol, INFO)
            if tol is None:
                pass
            elif b is None:
                delta.status = NEW if c is not None else INFO
            elif c is None:
                delta.status = MISSING
            else:
                change = delta.change()
                worse = change if not spec.higher_is_better else -change
                # the small slack absorbs float noise in values that only went through JSON
                delta.status = REGRESSED if worse > tol + 1e-9 else IMPROVED if -worse > tol + 1e-9 else OK
            deltas.append(delta)
    return deltas


def _fmt(delta: Delta, value: float | None) -> str:
    if value is None:
        return "-"
    if delta.spec.relative:
        return f"{value:.1f} s"
    if delta.metric == "abs_rel":
        return f"{value:.4f}"
    return f"{value:.2f}"


def _fmt_change(delta: Delta) -> str:
    change = delta.change()
    if change is None:
        return "-"
    if delta.spec.relative:
        return f"{change * 100:+.0f}%"
    return f"{change:+.4f}" if delta.metric == "abs_rel" else f"{change:+.2f}"


def _fmt_allowed(delta: Delta) -> str:
    if delta.tolerance is None:
        return "-"
    sign = "-" if delta.spec.higher_is_better else "+"
    if delta.spec.relative:
        return f"{sign}{delta.tolerance * 100:g}%"
    return f"{sign}{delta.tolerance:g}"


def format_table(deltas: list[Delta]) -> str:
    """The compared metrics as a fixed-width table (metrics without a tolerance are left out)."""
    rows = [("run", "metric", "baseline", "current", "delta", "allowed", "status")]
    rows += [(d.run, d.label, _fmt(d, d.baseline), _fmt(d, d.current), _fmt_change(d), _fmt_allowed(d), d.status)
             for d in deltas if d.status != INFO]
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    align = ["<", "<", ">", ">", ">", ">", "<"]
    return "\n".join("  ".join(f"{cell:{a}{w}}" for cell, a, w in zip(row, align, widths, strict=True)).rstrip()
                     for row in rows)


# ---- suite file ----------------------------------------------------------------------------------

@dataclasses.dataclass
class RunSpec:
    """One scene × pipeline of a suite, with the options parsed exactly as ``deepc run`` parses them."""

    scene: str
    pipeline: str
    scene_path: Path
    flags: list[str]
    scene_options: Any
    options: Any
    stream_options: Any
    tolerances: dict[str, float | None]

    @property
    def key(self) -> str:
        return f"{self.scene}/{self.pipeline}"


@dataclasses.dataclass
class Suite:
    path: Path
    name: str
    baseline_dir: Path
    thumbnail_views: int
    runs: list[RunSpec]


class _FlagParser(argparse.ArgumentParser):
    """argparse that raises instead of printing usage and exiting."""

    def error(self, message: str):
        raise DeepCError(message)


def _flag_parser() -> _FlagParser:
    from workbench.cli import add_run_option_flags

    parser = _FlagParser(prog="suite entry", add_help=False, allow_abbrev=False)
    add_run_option_flags(parser)
    return parser


def entry_flags(entry: dict[str, Any], reserved: tuple[str, ...], known: set[str] | None = None) -> list[str]:
    """The ``deepc run`` flags of a suite table: ``max-image-size = 160`` -> ``--max-image-size 160``,
    ``plane-propagation = false`` -> ``--no-plane-propagation``, ``set = [...]`` -> ``--set`` items.
    Keys in ``reserved`` are skipped; with ``known`` (the valid flags) any other key must be a flag."""
    flags: list[str] = []
    for key, value in entry.items():
        if key in reserved:
            continue
        if key == "set":
            items = value if isinstance(value, list) else [value]
            if not all(isinstance(item, str) for item in items):
                raise DeepCError("'set' takes STAGE.NAME=VALUE strings")
            for item in items:
                flags += ["--set", item]
            continue
        flag = key.replace("_", "-")
        if known is not None and f"--{flag}" not in known:
            raise DeepCError(f"unknown key {key!r} (neither {', '.join(reserved) or 'a suite key'} nor a flag of "
                             "deepc run)")
        if isinstance(value, bool):
            flags.append(f"--{flag}" if value else f"--no-{flag}")
        elif isinstance(value, list) and all(isinstance(v, (int, float)) for v in value):
            flags += [f"--{flag}", ",".join(map(str, value))]
        elif isinstance(value, (int, float, str)):
            flags += [f"--{flag}", str(value)]
        else:
            raise DeepCError(f"option {key!r}: unsupported value {value!r}")
    return flags


def _tolerances(table: Any, where: str) -> dict[str, float | None]:
    if not isinstance(table, dict):
        raise DeepCError(f"{where}: tolerances must be a table of metric = number (or false)")
    out: dict[str, float | None] = {}
    for name, value in table.items():
        if name not in METRIC_BY_NAME:
            raise DeepCError(f"{where}: unknown metric {name!r} in tolerances (one of {', '.join(METRIC_BY_NAME)})")
        if value is False:
            out[name] = None
        elif isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value >= 0:
            out[name] = float(value)
        else:
            raise DeepCError(f"{where}: tolerance {name} = {value!r} must be a number >= 0 (or false to report only)")
    return out


def _table(table: Any, where: str) -> dict[str, Any]:
    if not isinstance(table, dict):
        raise DeepCError(f"{where} must be a table")
    return table


def _entry_name(table: dict[str, Any], default: str, where: str) -> str:
    name = table.get("name", default)
    if not isinstance(name, str) or not _NAME.match(name):
        raise DeepCError(f"{where}: name {name!r} must be letters, digits, '.', '_' or '-'")
    return name


def load_suite(path: str | Path) -> Suite:
    """Read and check a suite file; every problem is a :class:`DeepCError` naming the file."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DeepCError("no such suite file", path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DeepCError(f"cannot read the suite file: {exc}", path) from None
    except tomllib.TOMLDecodeError as exc:
        raise DeepCError(f"not valid TOML: {exc}", path) from None
    try:
        return _parse_suite(path, data)
    except DeepCError as exc:
        if exc.path is not None:
            raise
        raise DeepCError(str(exc), path) from None


def _parse_suite(path: Path, data: dict[str, Any]) -> Suite:
    unknown = [k for k in data if k not in SUITE_KEYS]
    if unknown:
        raise DeepCError(f"unknown key {unknown[0]!r} (allowed: {', '.join(SUITE_KEYS)})")
    base = path.parent
    name = _entry_name(data, path.stem, "the suite")
    baseline = data.get("baseline", "baselines")
    if not isinstance(baseline, str) or not baseline:
        raise DeepCError("baseline must be a folder name")
    thumbnail_views = data.get("thumbnail_views", 4)
    if not isinstance(thumbnail_views, int) or isinstance(thumbnail_views, bool) or not 0 <= thumbnail_views <= 64:
        raise DeepCError(f"thumbnail_views = {thumbnail_views!r} must be an integer in 0..64")
    defaults = _table(data.get("defaults", {}), "[defaults]")
    for key in ("name", "path", "scenes", "tolerances"):
        if key in defaults:
            raise DeepCError(f"[defaults] holds run options only, not {key!r}")
    tolerances = {**DEFAULT_TOLERANCES, **_tolerances(data.get("tolerances", {}), "[tolerances]")}

    scenes = data.get("scene")
    if not isinstance(scenes, list) or not scenes:
        raise DeepCError("no scenes: add at least one [[scene]] with a path")
    scene_entries: list[tuple[str, Path, dict[str, Any]]] = []
    for i, table in enumerate(scenes):
        where = f"[[scene]] #{i + 1}"
        _table(table, where)
        rel = table.get("path")
        if not isinstance(rel, str) or not rel:
            raise DeepCError(f"{where}: needs path = \"SCENE_FOLDER\"")
        scene_path = (base / rel).resolve()
        if not ((scene_path / "sparse").is_dir() or (scene_path / "sparse" / "0").is_dir()):
            raise DeepCError(f"{where}: scene {rel!r} is not a COLMAP workspace ({scene_path} has no sparse/)")
        scene_name = _entry_name(table, scene_path.name, where)
        if any(scene_name == s[0] for s in scene_entries):
            raise DeepCError(f"{where}: scene name {scene_name!r} is used twice (give one a name = ...)")
        scene_entries.append((scene_name, scene_path, table))

    pipelines = data.get("pipeline", [{"pipeline": "vanilla"}])
    if not isinstance(pipelines, list) or not pipelines:
        raise DeepCError("[[pipeline]] must list at least one pipeline")
    parser = _flag_parser()
    runs: list[RunSpec] = []
    seen: set[str] = set()
    for i, table in enumerate(pipelines):
        where = f"[[pipeline]] #{i + 1}"
        _table(table, where)
        pipeline_name = _entry_name(table, str(table.get("pipeline", "vanilla")), where)
        if pipeline_name in seen:
            raise DeepCError(f"{where}: pipeline name {pipeline_name!r} is used twice")
        seen.add(pipeline_name)
        only = table.get("scenes")
        known = [s[0] for s in scene_entries]
        if only is not None and (not isinstance(only, list) or any(s not in known for s in only)):
            raise DeepCError(f"{where}: scenes = {only!r} must list scene names of this suite ({', '.join(known)})")
        for scene_name, scene_path, scene_table in scene_entries:
            if only is not None and scene_name not in only:
                continue
            runs.append(_run_spec(parser, defaults, scene_name, scene_path, scene_table, pipeline_name, table,
                                  tolerances))
    return Suite(path, name, (base / baseline).resolve(), thumbnail_views, runs)


def _run_spec(parser: _FlagParser, defaults: dict[str, Any], scene_name: str, scene_path: Path,
              scene_table: dict[str, Any], pipeline_name: str, pipeline_table: dict[str, Any],
              tolerances: dict[str, float | None]) -> RunSpec:
    from workbench.cli import run_options_from_args

    known = {s for action in parser._actions for s in action.option_strings}
    flags: list[str] = []
    for where, table, reserved in (("[defaults]", defaults, ()), (f"[[scene]] {scene_name!r}", scene_table, SCENE_KEYS),
                                   (f"[[pipeline]] {pipeline_name!r}", pipeline_table, PIPELINE_KEYS)):
        try:
            entry = entry_flags(table, reserved, known)
            parser.parse_args(entry)  # each table on its own, so that an error names the table at fault
        except DeepCError as exc:
            raise DeepCError(f"{where}: {exc}") from None
        flags += entry
    try:
        scene_options, options, stream_options = run_options_from_args(parser.parse_args(flags))
    except DeepCError as exc:
        raise DeepCError(f"run {scene_name}/{pipeline_name}: {exc}") from None
    tol = {**tolerances}
    for where, table in ((f"[[scene]] {scene_name!r}", scene_table),
                         (f"[[pipeline]] {pipeline_name!r}", pipeline_table)):
        tol.update(_tolerances(table.get("tolerances", {}), where))
    return RunSpec(scene_name, pipeline_name, scene_path, flags, scene_options, options, stream_options, tol)


# ---- running -------------------------------------------------------------------------------------

@dataclasses.dataclass
class RunResult:
    """A finished run: its metrics, its baseline (if any) and the comparison."""

    spec: RunSpec
    out_dir: Path
    metrics: dict[str, Any]
    baseline: dict[str, Any] | None
    deltas: list[Delta]
    load_average: tuple[float, float]  # 1-minute load average before and after the run
    recording: Path | None
    baseline_reason: str | None = None  # why the baseline was last remade (deepc regress --reason)

    @property
    def failures(self) -> list[Delta]:
        return [d for d in self.deltas if d.status in FAILED]


def environment() -> dict[str, Any]:
    """Where the numbers were measured: versions, machine, git revision of the code."""
    packages = {}
    for name in ("numpy", "numba", "scipy", "torch", "pycolmap", "open3d", "matplotlib", "rerun-sdk"):
        try:
            packages[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            packages[name] = None
    return {"deepc": __version__, "git": git_revision(), "python": platform.python_version(),
            "platform": platform.platform(), "cpu_count": os.cpu_count(),
            "numba_threads": _numba_threads(), "load_average": [round(x, 2) for x in os.getloadavg()],
            "packages": packages, "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")}


def _numba_threads() -> int | None:
    try:
        import numba
        return int(numba.config.NUMBA_NUM_THREADS)
    except Exception:  # noqa: BLE001  (only informative)
        return None


def git_revision(root: Path = REPO_ROOT) -> str | None:
    """``<commit>`` or ``<commit>+dirty`` of the code being tested; None outside a git checkout."""
    try:
        rev = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True,
                             timeout=10, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return rev + ("+dirty" if dirty else "")


def _prepare_out_dir(out_dir: Path) -> None:
    """A run starts from an empty folder (no stale maps of an earlier run), but only a folder that
    holds a deepc output (or nothing) is ever removed."""
    if out_dir.exists():
        if not out_dir.is_dir() or (any(out_dir.iterdir()) and not (out_dir / "metrics.json").is_file()):
            raise DeepCError("exists and is not the output of an earlier run; not overwriting it", out_dir)


def warm_up(runs: list[RunSpec]) -> float:
    """Run each pipeline once on a small copy of its first scene, untimed, so that numba compilation
    (or loading its cache) is never counted in a run's time. Returns the seconds spent."""
    from engine.pipeline import run_pipeline
    from engine.scene import load_scene

    start = time.perf_counter()
    done: set[str] = set()
    with tempfile.TemporaryDirectory(prefix="deepc-warm-up-") as tmp:
        for spec in runs:
            if spec.pipeline in done:
                continue
            done.add(spec.pipeline)
            size = spec.scene_options.max_image_size
            scene = load_scene(spec.scene_path, spec.scene_options.replace(
                max_image_size=min(size, _WARM_UP_SIZE) if size else _WARM_UP_SIZE))
            options = spec.options.replace(patchmatch=spec.options.patchmatch.replace(iterations=1))
            with warnings.catch_warnings():  # e.g. "too small for 3 levels": true, and beside the point here
                warnings.simplefilter("ignore")
                run_pipeline(scene, Path(tmp) / spec.pipeline, options)
    return time.perf_counter() - start


def execute(spec: RunSpec, out_dir: Path, record: bool) -> tuple[dict[str, Any], Path | None]:
    """Run one suite entry exactly as ``deepc run --headless`` would; returns metrics and the recording."""
    from engine.pipeline import run_pipeline
    from engine.scene import load_scene
    from workbench.cli import _open_recording

    scene = load_scene(spec.scene_path, spec.scene_options)
    if out_dir.exists():
        shutil.rmtree(out_dir)
    recording = _open_recording(str(out_dir / "recording.rrd"), scene, spec.options, spec.stream_options) \
        if record else None
    try:
        result = run_pipeline(scene, out_dir, spec.options, observer=recording.stream if recording else None)
    except BaseException:
        if recording:
            recording.abandon()
        raise
    path = recording.finish() if recording else None
    return result.metrics, path


# ---- baselines -------------------------------------------------------------------------------------

def baseline_path(baseline_dir: Path, spec: RunSpec) -> Path:
    return baseline_dir / spec.scene / f"{spec.pipeline}.json"


def read_baseline(path: Path) -> dict[str, Any] | None:
    """The metrics stored in a baseline file, or None when there is none."""
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
        return dict(data["metrics"])
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError, ValueError) as exc:
        raise DeepCError(f"malformed baseline file ({exc}); remake it with --update-baseline", path) from None


def write_baseline(path: Path, spec: RunSpec, metrics: dict[str, Any], env: dict[str, Any],
                   load_average: tuple[float, float], reason: str | None = None) -> None:
    stored = {k: v for k, v in metrics.items() if k != "scene_path"}  # machine-specific
    write_json(path, {"run": spec.key, "flags": spec.flags, "metrics": stored,
                      "measured": {**env, "load_average_during_run": list(load_average)},
                      **({"reason": reason} if reason else {})})


def read_baseline_reason(path: Path) -> str | None:
    """Why the baseline at ``path`` was remade, with its date and git revision; None when it does not say."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or not data.get("reason"):
        return None
    measured = data.get("measured") or {}
    return f"{data['reason']} ({measured.get('date', 'date unknown')}, git {measured.get('git', 'unknown')})"


def _flatten(value: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(value, dict):
        out: dict[str, Any] = {}
        for k, v in value.items():
            out.update(_flatten(v, f"{prefix}{k}."))
        return out
    return {prefix[:-1]: value}


def option_changes(current: dict[str, Any], baseline: dict[str, Any] | None) -> list[str]:
    """'patchmatch.iterations: None -> 1' for every option that differs from the baseline's."""
    if not baseline:
        return []
    now, before = _flatten(current.get("options", {})), _flatten(baseline.get("options", {}))
    return [f"{k}: {before.get(k, '(absent)')} -> {now.get(k, '(absent)')}"
            for k in sorted(set(now) | set(before)) if now.get(k) != before.get(k)]


def _changes(result: RunResult) -> str:
    """What --update-baseline changes for one run, in one line."""
    if result.baseline is None:
        return f"{result.spec.key}: new baseline"
    parts = []
    for d in result.deltas:
        change = d.change()
        if d.spec.relative:  # times always differ a little; they are shown below
            continue
        if d.baseline is None and d.current is not None:
            parts.append(f"{d.label} new {_fmt(d, d.current)}")
        elif d.current is None and d.baseline is not None:
            parts.append(f"{d.label} removed")
        elif change is not None and abs(change) > 1e-9:
            parts.append(f"{d.label} {_fmt(d, d.baseline)} -> {_fmt(d, d.current)} ({_fmt_change(d)})")
    timing = [f"{d.label} {_fmt(d, d.baseline)} -> {_fmt(d, d.current)}" for d in result.deltas
              if d.spec.relative and d.baseline is not None and d.current is not None]
    return f"{result.spec.key}: " + "; ".join((parts or ["metrics unchanged"]) + timing)


# ---- the command -------------------------------------------------------------------------------------

def cmd_regress(args: argparse.Namespace) -> int:
    if getattr(args, "reason", None) and not args.update_baseline:
        raise DeepCError("deepc regress: --reason says why baselines are remade; it needs --update-baseline")
    suite = load_suite(args.suite or DEFAULT_SUITE)
    baseline_dir = Path(args.baseline).resolve() if args.baseline else suite.baseline_dir
    report_dir = Path(args.report) if args.report else DEFAULT_REPORT
    for spec in suite.runs:  # refuse what would fail before spending minutes on the runs
        _prepare_out_dir(report_dir / spec.scene / spec.pipeline)
        read_baseline(baseline_path(baseline_dir, spec))
    env = environment()
    print(f"suite {suite.name} ({suite.path}): {len(suite.runs)} runs, baselines in {baseline_dir}", file=sys.stderr)
    print(f"warm-up (numba compilation, not timed): {warm_up(suite.runs):.1f} s", file=sys.stderr)
    if args.record:
        print("--record: times are reported but not compared (recording slows the runs down)", file=sys.stderr)
    results = [_run_and_compare(i, suite, spec, baseline_dir, report_dir, args.record)
               for i, spec in enumerate(suite.runs, 1)]

    deltas = [d for r in results for d in r.deltas]
    print(format_table(deltas))
    for result in results:
        changed = option_changes(result.metrics, result.baseline)
        if changed:
            print(f"note: {result.spec.key} ran with options that differ from its baseline's: {'; '.join(changed)}")
    if args.update_baseline:
        _update_baselines(results, baseline_dir, env, getattr(args, "reason", None))

    from workbench.report import write_report
    summary = write_json(report_dir / "summary.json", {
        "suite": str(suite.path), "baseline_dir": str(baseline_dir), "updated_baseline": bool(args.update_baseline),
        "environment": env, "runs": [{"run": r.spec.key, "out_dir": str(r.out_dir), "flags": r.spec.flags,
                                      "has_baseline": r.baseline is not None,
                                      "deltas": [dataclasses.asdict(d) for d in r.deltas]} for r in results]})
    report = write_report(report_dir / "report.html", suite, results, env, baseline_dir, args.update_baseline)
    print(f"report: {report} (summary: {summary})")
    return 0 if args.update_baseline else _verdict(results)


def _run_and_compare(i: int, suite: Suite, spec: RunSpec, baseline_dir: Path, report_dir: Path,
                     record: bool) -> RunResult:
    print(f"[{i}/{len(suite.runs)}] {spec.key} ...", file=sys.stderr, flush=True)
    load_before, cpu_before = os.getloadavg()[0], time.process_time()
    out_dir = report_dir / spec.scene / spec.pipeline
    metrics, recording = execute(spec, out_dir, record)
    metrics["seconds_cpu"] = time.process_time() - cpu_before
    write_metrics(out_dir, metrics)
    baseline = read_baseline(baseline_path(baseline_dir, spec))
    tolerances = spec.tolerances
    if record:  # logging every iteration costs time that the baseline's run did not spend
        tolerances = {k: None if METRIC_BY_NAME[k].relative else v for k, v in tolerances.items()}
    result = RunResult(spec, out_dir, metrics, baseline, compare(spec.key, metrics, baseline, tolerances),
                       (round(load_before, 2), round(os.getloadavg()[0], 2)), recording,
                       read_baseline_reason(baseline_path(baseline_dir, spec)))
    print(f"[{i}/{len(suite.runs)}] {spec.key}: {metrics['seconds']['total']:.1f} s "
          f"({metrics['seconds_cpu']:.1f} s CPU), {len(result.failures)} regressed", file=sys.stderr, flush=True)
    return result


def _update_baselines(results: list[RunResult], baseline_dir: Path, env: dict[str, Any],
                      reason: str | None = None) -> None:
    for result in results:
        write_baseline(baseline_path(baseline_dir, result.spec), result.spec, result.metrics, env,
                       result.load_average, reason)
        result.baseline_reason = read_baseline_reason(baseline_path(baseline_dir, result.spec))
    print(f"baselines rewritten in {baseline_dir}:")
    for result in results:
        print(f"  {_changes(result)}")
    current = {baseline_path(baseline_dir, r.spec) for r in results}
    for stale in sorted(set(baseline_dir.glob("*/*.json")) - current):
        print(f"  {stale.parent.name}/{stale.stem}: not in this suite, left as it was ({stale})")


def _verdict(results: list[RunResult]) -> int:
    """Print what regressed (and which runs have no baseline); the exit status."""
    missing = [r.spec.key for r in results if r.baseline is None]
    failures = [d for r in results for d in r.failures]
    if missing or failures:
        for key in missing:
            print(f"no baseline: {key} (make one with deepc regress --update-baseline)")
        for d in failures:
            print(f"regressed: {d.explain()}")
        print(f"REGRESSION: {len(failures)} metric(s) regressed"
              + (f", {len(missing)} run(s) without a baseline" if missing else ""))
        return 1
    compared = sum(d.status != INFO for r in results for d in r.deltas)
    print(f"nothing regressed ({len(results)} runs, {compared} metrics compared)")
    return 0
