"""The layout's rules, checked on the source: no import cycle (imports inside functions included), stage modules
below the pipeline, the runtime free of test code, and heavy libraries loaded only where a function needs them."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
PACKAGES = ("engine", "workbench", "layouts", "support")
#: modules of one pipeline stage each: they never import the pipeline that strings them together
STAGES = ("engine.patchmatch", "engine.consistency", "engine.confidence", "engine.filtering", "engine.refinement",
          "engine.refinement.sky", "engine.fusion", "engine.evaluation")


def _modules() -> dict[str, Path]:
    mods = {}
    for package in PACKAGES:
        for path in (REPO / package).rglob("*.py"):
            parts = path.relative_to(REPO).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            mods[name] = path
    return mods


MODULES = _modules()


def _imports(name: str, path: Path) -> list[tuple[str, ast.stmt]]:
    """(imported project module, statement) for every import in the file, at any depth."""
    is_package = path.name == "__init__.py"
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = name.split(".") if is_package else name.split(".")[:-1]
                anchor = anchor[: len(anchor) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            targets = [base] + [f"{base}.{a.name}" for a in node.names]
        else:
            continue
        for target in targets:
            while target and target not in MODULES:  # a name imported from a module: the module
                target = target.rpartition(".")[0]
            if target and target != name:
                found.append((target, node))
    return found


GRAPH = {name: sorted({t for t, _ in _imports(name, path)}) for name, path in MODULES.items()}


def _cycles(graph: dict[str, list[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, []):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10 * len(graph)))
    for v in graph:
        if v not in index:
            visit(v)
    return out


def test_cycle_finder_finds_a_cycle():
    assert _cycles({"a": ["b"], "b": ["c"], "c": ["a"], "d": ["a"]}) == [["a", "b", "c"]]
    assert _cycles({"a": ["b"], "b": []}) == []


def test_no_import_cycle():
    assert _cycles(GRAPH) == []


ABOVE_PIPELINE = ("engine.run.pipeline", "engine.run.refine", "engine.training.runs", "engine.run.probe")


def test_stage_modules_never_import_the_pipeline():
    offenders = [f"{m} imports {t}" for m, targets in GRAPH.items() if m.startswith(STAGES)
                 for t in targets if t in ABOVE_PIPELINE]
    assert offenders == []


def test_engine_never_imports_the_workbench_and_the_runtime_never_imports_test_code():
    offenders = [f"{m} imports {t}" for m, targets in GRAPH.items() for t in targets
                 if (m.startswith("engine") and t.startswith("workbench"))
                 or (m.startswith(("engine", "workbench", "layouts")) and t.startswith("support"))]
    assert offenders == []


def test_imports_inside_functions_say_why():
    """Only heavy libraries (torch, viser, rerun, pycolmap, ...) are imported inside functions, to keep them off
    start-up; such an import carries a ``# lazy: <library>`` comment on its line or the line above."""
    unexplained = []
    for name, path in MODULES.items():
        if name.startswith("support"):
            continue
        lines = path.read_text().splitlines()
        for fn in ast.walk(ast.parse("\n".join(lines))):
            if not isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
                continue
            for node in ast.walk(fn):
                if isinstance(node, ast.Import | ast.ImportFrom):
                    context = lines[node.lineno - 1] + (lines[node.lineno - 2] if node.lineno > 1 else "")
                    if "# lazy:" not in context:
                        unexplained.append(f"{path.relative_to(REPO)}:{node.lineno}: {lines[node.lineno - 1].strip()}")
    assert unexplained == []


@pytest.mark.parametrize("module", ["engine.run.pipeline", "workbench.cli.main"])
def test_start_up_leaves_heavy_libraries_unloaded(module):
    code = (f"import sys, {module}; "
            "print(','.join(m for m in ('torch', 'viser', 'rerun', 'open3d', 'matplotlib') if m in sys.modules))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=REPO,
                            check=True).stdout.strip()
    assert loaded == ""


def _private_imports(path: Path) -> list[str]:
    """'module.name' for every ``_name`` that ``path`` imports from a project module (any depth)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module \
                and node.module.split(".")[0] in PACKAGES:
            found += [f"{node.module}.{a.name}" for a in node.names
                      if a.name.startswith("_") and a.name != "__version__"]
    return found


def test_no_private_name_is_imported_from_another_module():
    """A ``_name`` is its module's own: what another module (runtime, support, tests or benchmarks) needs is public."""
    files = [p for d in (*PACKAGES, "tests", "benchmarks") for p in (REPO / d).rglob("*.py")]
    offenders = [f"{p.relative_to(REPO)} imports {name}" for p in files for name in _private_imports(p)]
    assert offenders == []


def test_private_import_finder_finds_one(tmp_path):
    module = tmp_path / "m.py"
    module.write_text("from engine.run.pipeline import _hidden, visible\nfrom engine import __version__\n")
    assert _private_imports(module) == ["engine.run.pipeline._hidden"]


#: most modules one folder of runtime code may hold at one level (a room, not a corridor)
MAX_MODULES_PER_FOLDER = 15


def test_no_runtime_folder_is_a_corridor():
    folders: dict[str, int] = {}
    for name, path in MODULES.items():
        if not name.startswith("support") and path.name != "__init__.py":
            key = str(path.parent.relative_to(REPO))
            folders[key] = folders.get(key, 0) + 1
    assert {k: n for k, n in folders.items() if n > MAX_MODULES_PER_FOLDER} == {}
