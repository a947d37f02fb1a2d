"""The suite file of ``deepc regress``: scenes × pipelines, each run's flags and tolerances, checked.

A suite is a TOML file::

    baseline = "../tests/baselines"     # baseline folder, relative to the suite file (default: baselines/)
    thumbnail_views = 4                 # views per run shown as map thumbnails in the report

    [defaults]                          # `deepc run` flags for every run (names as on the command line)
    schedule = "acmm"
    seed = 0

    [tolerances]                        # allowed change per metric, either way; false = report only
    f1 = 0.5                            # points, at every evaluation tolerance the run reports
    time = 0.5                          # never fails: a calibrated ratio above 1.5x is only noted as slower

    [[scene]]                           # a COLMAP workspace, relative to the suite file
    path = "tiny"
    max-image-size = 160                # flags here apply to this scene's runs

    [[pipeline]]                        # every pipeline runs on every scene (or on `scenes = [...]`)
    name = "vanilla"
    pipeline = "vanilla"
    set = ["patchmatch.tau0=0.7"]       # --set STAGE.NAME=VALUE items

Flags merge in the order defaults < scene < pipeline and are parsed by the parser of ``deepc run``
(``workbench/flags/run.py``), so a run's options are exactly those of ``deepc run`` with the same flags.
A quality metric that moves beyond its tolerance, better or worse, fails the suite until the baselines are
remade (``--update-baseline --reason``); times are information only (``workbench/regress/comparison.py``):
speed regressions are caught by the scripts of ``benchmarks/performance/``, not by CI's wall clock.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import re
import tomllib
from pathlib import Path
from typing import Any

from engine.core.errors import DeepCError
from engine.run.pipeline import PipelineOptions
from engine.scene import SceneOptions
from workbench.flags.run import add_run_option_flags
from workbench.flags.run_options import run_options_from_args
from workbench.regress.comparison import DEFAULT_TOLERANCES, METRIC_BY_NAME
from workbench.rerun.options import StreamOptions

DEFAULT_SUITE = Path(__file__).resolve().parents[2] / "sample_scenes" / "suite.toml"
SUITE_KEYS = ("name", "baseline", "thumbnail_views", "defaults", "tolerances", "scene", "pipeline")
SCENE_KEYS = ("path", "name", "tolerances")
PIPELINE_KEYS = ("name", "scenes", "tolerances")
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


@dataclasses.dataclass
class RunSpec:
    """One scene × pipeline of a suite, with the options parsed exactly as ``deepc run`` parses them."""

    scene: str
    pipeline: str
    scene_path: Path
    flags: list[str]
    scene_options: SceneOptions
    options: PipelineOptions
    stream_options: StreamOptions
    tolerances: dict[str, float | None]

    @property
    def key(self) -> str:
        return f"{self.scene}/{self.pipeline}"


@dataclasses.dataclass
class Suite:
    """A suite file, read and checked: its runs in order (pipelines outer, scenes inner)."""

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
