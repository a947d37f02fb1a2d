"""The benchmark harness: timing, where a result was measured, and the one writer of result JSONs.

Every benchmark script writes its JSON through :func:`write_result`, which puts in front of the numbers
the script (repository-relative path), its arguments, the git revision and a ``dirty`` flag (the tracked
files differ from it), the environment (versions, CPU model and count, load; never a host name) and its
inputs (sha256 of the weights files used, digests of the input scenes), checks the numbers against the
script's declared ``SCHEMA`` (:mod:`support.schema`), replaces absolute paths by machine-independent ones
(:func:`scrub`) and writes atomically. Default
outputs are ``benchmarks/results/<script>[_<variant>].json`` (:func:`results_path`), so a result's file
name always says which script made it.
"""

from __future__ import annotations

import hashlib
import importlib.util
import re
import resource
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

from engine.io.atomic import write_json
from engine.run.folder import file_sha256

REPO_ROOT = Path(__file__).resolve().parent.parent
BENCHMARKS = REPO_ROOT / "benchmarks"
RESULTS = BENCHMARKS / "results"
SHARED_DATA = REPO_ROOT.parent / "shared" / "data"  # the data sets beside the checkout (not in the repository)
METADATA_KEYS = ("script", "argv", "git", "dirty", "environment", "inputs")
# The shipped networks: a script that runs them by default names them in its module-level WEIGHTS.
SHIPPED_WEIGHTS = {"deepc_middle.pt": "engine/confidence/weights/deepc_middle.pt",
                   "deepc_refined.pt": "engine/confidence/weights/deepc_refined.pt"}
# benchmarks/<folder>/<script>.py, by purpose: the paper's tables, speed and memory, robustness, the studies
# behind default choices
FOLDERS = ("paper", "performance", "reliability", "experiments")


# ---- timing --------------------------------------------------------------------------------------

class Stopwatch:
    """Wall and CPU seconds (all threads of this process) of a ``with`` block."""

    wall: float = 0.0
    cpu: float = 0.0

    def __enter__(self) -> Stopwatch:
        self._wall, self._cpu = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc: object) -> None:
        self.wall = time.perf_counter() - self._wall
        self.cpu = time.process_time() - self._cpu


def best_of(fn: Callable[[], Any], repeats: int, warmup: int = 1) -> tuple[float, list[float]]:
    """Best and all wall times of ``repeats`` calls of ``fn`` after ``warmup`` untimed ones (JIT, caches)."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        with Stopwatch() as watch:
            fn()
        times.append(watch.wall)
    return min(times), times


def peak_rss_mb(children: bool = False) -> float:
    """Peak resident memory (MiB) of this process, or of its finished child processes."""
    who = resource.RUSAGE_CHILDREN if children else resource.RUSAGE_SELF
    return resource.getrusage(who).ru_maxrss / 1024  # Linux reports KiB


def reset_peak_rss() -> bool:
    """Reset this process's peak resident memory (VmHWM) to its current size, so that the next
    :func:`peak_rss_mb_now` measures one step; False where the kernel does not allow it (not Linux)."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def _status_mb(key: str) -> float | None:
    """A memory line of /proc/self/status (``VmHWM``, ``VmRSS``) in MiB; None where there is none."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(key + ":"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return None


def peak_rss_mb_now() -> float:
    """Peak resident memory (MiB) of this process since start or the last :func:`reset_peak_rss` (getrusage's
    peak ignores the reset)."""
    peak = _status_mb("VmHWM")
    return peak_rss_mb() if peak is None else peak


def rss_mb_now() -> float:
    """Resident memory (MiB) of this process now (Linux; 0 elsewhere)."""
    return _status_mb("VmRSS") or 0.0


# ---- provenance ----------------------------------------------------------------------------------

def _cpu_model() -> str | None:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    import platform

    return platform.processor() or None


def environment() -> dict[str, Any]:
    """Versions, CPU model and count, numba threads, load average and date (no host name, no user)."""
    from workbench.regress import environment as regress_environment

    env = regress_environment()
    env.pop("git", None)  # recorded beside the environment, see run_record
    env["cpu_model"] = _cpu_model()
    return env


def git_revision() -> str | None:
    """``<commit>`` or ``<commit>+dirty`` of this checkout; None outside git."""
    from workbench.regress import git_revision as regress_git_revision

    return regress_git_revision(REPO_ROOT)


def scene_digest(scene: str | Path) -> str:
    """sha256 over a scene folder's files (relative path and bytes of each, in sorted order): two folders with
    the same digest hold the same images, model and ground truth."""
    root = Path(scene)
    digest = hashlib.sha256()
    for path in sorted(p for p in root.rglob("*") if p.is_file()):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0" + file_sha256(path).encode())
    return digest.hexdigest()


def _is_scene(path: Path) -> bool:
    return path.is_dir() and (path / "sparse").is_dir() and (path / "images").is_dir()


def inputs_record(argv: Sequence[str], weights: Sequence[str | Path] = (),
                  scenes: Sequence[str | Path] = ()) -> dict[str, dict[str, str]]:
    """sha256 of every weights file used and digest of every input scene, by scrubbed path: those given, the
    ``.pt`` files and scene folders named in ``argv`` (also as ``NAME=PATH``)."""
    named = [t.split("=", 1)[-1] for t in argv if isinstance(t, str)]
    files = [Path(w) for w in weights] + [Path(t) for t in named if t.endswith(".pt") and Path(t).is_file()]
    folders = [Path(s) for s in scenes] + [Path(t) for t in named if t and _is_scene(Path(t))]
    record = {"weights": {}, "scenes": {}}
    for path in files:
        path = path if path.is_absolute() else (Path.cwd() / path)
        if path.is_file():
            record["weights"][scrub_path(str(path.resolve()))] = file_sha256(path)
    for path in folders:
        path = path if path.is_absolute() else (Path.cwd() / path)
        if path.is_dir():
            record["scenes"][scrub_path(str(path.resolve()))] = scene_digest(path)
    return record


def script_path(script: str | Path) -> str:
    """Repository-relative path of a script (``benchmarks/paper/table2_filters.py``)."""
    path = Path(script).resolve()
    try:
        return path.relative_to(REPO_ROOT).as_posix()
    except ValueError:
        return path.name


def run_record(script: str | Path, argv: Sequence[str] | None = None, weights: Sequence[str | Path] = (),
               scenes: Sequence[str | Path] = ()) -> dict[str, Any]:
    """The metadata every result JSON starts with (keys :data:`METADATA_KEYS`): ``git`` is the commit,
    ``dirty`` whether tracked files differed from it."""
    argv = list(sys.argv[1:] if argv is None else argv)
    revision = git_revision()
    return {"script": script_path(script), "argv": scrub(argv),
            "git": revision.removesuffix("+dirty") if revision else None,
            "dirty": revision.endswith("+dirty") if revision else None, "environment": environment(),
            "inputs": inputs_record(argv, weights, scenes)}


# ---- machine paths -------------------------------------------------------------------------------

# An absolute path of two or more components inside any text; not "1/2", "a / b", URLs or "<tmp>/x".
_ABSOLUTE = re.compile(r"(?<![\w.:/<>~-])/[\w.~+@-]+(?:/[\w.~+@=-]*)+")
_TMP_ROOTS = tuple(dict.fromkeys(str(Path(p).resolve()) for p in (tempfile.gettempdir(), "/tmp", "/var/tmp")))


def _under(path: str, root: str) -> str | None:
    root = root.rstrip("/")
    if path == root:
        return ""
    return path[len(root) + 1:] if path.startswith(root + "/") else None


def scrub_path(path: str) -> str:
    """A machine-independent stand-in for absolute ``path``: relative to the repository, ``../shared/...`` for the
    data beside the checkout, ``<tmp>/name`` for temporary files, ``../x`` for anything else beside the checkout
    (checked after the temporary folders, since a checkout may itself live in one), else the last component."""
    trimmed = path.rstrip("/") or path
    rest = _under(trimmed, str(REPO_ROOT))
    if rest is not None:
        return rest or "."
    beside = _under(trimmed, str(REPO_ROOT.parent)) if REPO_ROOT.parent != Path("/") else None
    if beside and (beside == "shared" or beside.startswith("shared/")):
        return "../" + beside
    for root in _TMP_ROOTS:
        if _under(trimmed, root) is not None:
            return "<tmp>/" + Path(trimmed).name
    if beside:
        return "../" + beside
    return Path(trimmed).name


def scrub(value: Any) -> Any:
    """``value`` (JSON-like) with every absolute path in its strings replaced by :func:`scrub_path`."""
    if isinstance(value, str):
        return _ABSOLUTE.sub(lambda m: scrub_path(m.group(0)), value)
    if isinstance(value, Path):
        return scrub(str(value))
    if isinstance(value, dict):
        return {scrub(k): scrub(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [scrub(v) for v in value]
    return value


# ---- scripts ------------------------------------------------------------------------------------

def scripts() -> list[Path]:
    """Every benchmark script, folder by folder (:data:`FOLDERS`), by name within one."""
    return [p for folder in FOLDERS for p in sorted((BENCHMARKS / folder).glob("*.py"))]


def load_script(path: Path) -> ModuleType:
    """Import a benchmark script as a module (its ``main`` does not run): for its ``summary`` and tests."""
    name = f"benchmark_{path.parent.name}_{path.stem}"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # before running it: dataclasses look their module up while it runs
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module


# ---- results -------------------------------------------------------------------------------------

def results_path(script: str | Path, variant: str = "") -> Path:
    """``benchmarks/results/<script name>[_<variant>].json``."""
    return RESULTS / (Path(script).stem + (f"_{variant}" if variant else "") + ".json")


def _main_script() -> str:
    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    if path is None:
        raise ValueError("write_result: no script given and __main__ has no file")
    return path


def declared(script: str | Path) -> ModuleType:
    """The script's module (``__main__`` when it is the running script): its ``SCHEMA`` and ``WEIGHTS``."""
    main = sys.modules.get("__main__")
    if getattr(main, "__file__", None) and Path(main.__file__).resolve() == Path(script).resolve():
        return main
    return load_script(Path(script).resolve())


def schema_errors(data: dict[str, Any], script: str | Path, schema: dict[str, Any] | None = None) -> list[str]:
    """What is wrong with a result of ``script`` against ``schema``, by default the script's ``SCHEMA``
    (:mod:`support.schema`)."""
    from support.schema import errors

    schema = getattr(declared(script), "SCHEMA", None) if schema is None else schema
    if schema is None:
        return [f"{script_path(script)} declares no SCHEMA"]
    return errors(data, schema)


def write_result(data: dict[str, Any], path: str | Path | None = None, *, script: str | Path | None = None,
                 argv: Sequence[str] | None = None, weights: Sequence[str | Path] = (),
                 scenes: Sequence[str | Path] = (), schema: dict[str, Any] | None = None) -> Path:
    """Write ``data`` as a result JSON: :func:`run_record` first, then the numbers, paths scrubbed,
    atomically (a temporary sibling renamed over the target). ``script`` defaults to the running script,
    ``path`` to its :func:`results_path`. A file in benchmarks/results must be named after its script; the
    result must match ``schema``, by default the script's ``SCHEMA``. The weights recorded are ``weights``,
    the script's ``WEIGHTS`` (shipped networks it runs by default) and the ``.pt`` files in ``argv``; the
    scenes, ``scenes`` and the scene folders in ``argv``."""
    script = script or _main_script()
    path = Path(path) if path is not None else results_path(script)
    stem = Path(script).stem
    if path.resolve().parent == RESULTS.resolve() and not path.name.startswith(stem):
        raise ValueError(f"{path.name}: a result of {stem}.py in benchmarks/results must be named {stem}*.json")
    clash = [k for k in METADATA_KEYS if k in data]
    if clash:
        raise ValueError(f"write_result: {clash} are the harness's keys")
    module = declared(script)
    used = [REPO_ROOT / SHIPPED_WEIGHTS.get(w, w) for w in getattr(module, "WEIGHTS", ())] + list(weights)
    record = scrub({**run_record(script, argv, used, scenes), **data})
    problems = schema_errors(record, script, schema)
    if problems:
        raise ValueError(f"write_result: the result does not match {script_path(script)}'s SCHEMA: "
                         + "; ".join(problems))
    write_json(path, record)
    return path


# ---- tables --------------------------------------------------------------------------------------

def _cell(value: Any, digits: int) -> str:
    if value is None:
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        if value != value:  # NaN
            return "–"
        if value != 0 and abs(value) < 0.1:  # small ratios and errors (abs_rel 0.0201) keep 3 figures
            return f"{value:.3g}"
        return f"{value:,.{digits}f}" if abs(value) < 1e6 else f"{value:.3g}"
    if isinstance(value, int):
        return f"{value:,}"
    if isinstance(value, (list, tuple)):
        return " / ".join(_cell(v, digits) for v in value)
    return str(value)


def format_table(rows: Sequence[dict[str, Any]], columns: Sequence[str] | None = None, digits: int = 2,
                 markdown: bool = False) -> str:
    """Rows (dicts) as aligned text or markdown. Columns default to the keys in order of appearance, less
    those that no row has a value for."""
    if columns is None:
        columns = [k for k in dict.fromkeys(k for row in rows for k in row) if any(r.get(k) is not None for r in rows)]
    cells = [[_cell(row.get(c), digits) for c in columns] for row in rows]
    if markdown:
        def line(values: Sequence[str]) -> str:
            return "| " + " | ".join(v.replace("|", "\\|") for v in values) + " |"

        numeric = [all(_is_number(r.get(c)) for r in rows) and rows for c in columns]
        rule = "|" + "|".join("---:" if n else "---" for n in numeric) + "|"
        return "\n".join([line(columns), rule, *(line(c) for c in cells)])
    widths = [max([len(c)] + [len(r[i]) for r in cells]) for i, c in enumerate(columns)]

    def text(values: Sequence[str]) -> str:
        return "  ".join(v.ljust(w) if i == 0 else v.rjust(w) for i, (v, w) in enumerate(zip(values, widths,
                                                                                              strict=True)))

    return "\n".join([text(columns), text(["-" * w for w in widths]), *(text(c) for c in cells)])


def _is_number(value: Any) -> bool:
    return value is None or (isinstance(value, (int, float)) and not isinstance(value, bool))


def print_table(rows: Sequence[dict[str, Any]], columns: Sequence[str] | None = None, digits: int = 2,
                title: str | None = None) -> None:
    """Print :func:`format_table` (a benchmark's summary table)."""
    if title:
        print(f"\n{title}")
    print(format_table(rows, columns, digits))
