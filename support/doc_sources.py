"""Every measured number in a hand-written page cites the result JSON key that holds it; this checks it.

The convention (docs/decisions.md states it at its top):

- A **source** is written ``[NAME.json: KEY/PATH, KEY/PATH ...]``: a file of benchmarks/results and one or
  more paths into it, keys (and list indices) joined by ``/``. A path may end at an object or a list: it then
  cites every number under it.
- A **block** is a paragraph, a list item, or a table with the lines directly under it (its source). Every
  checked number of a block must be found under one of the block's sources: some number there (a value, or a
  number inside a key such as ``f1@0.02``) equals it rounded as written (``93.05`` matches 93.0498; a share
  stored as a fraction may be written as a percentage). Signs are prose (``−0.06`` matches -0.06 and 0.06).
- **Checked numbers**: those with a decimal point, those followed by ``%`` or a unit of time, size or work
  (``s``, ``ms``, ``CPU-s``, ``minutes``, ``MB``, ``MiB``, ``GB``, ``GiB``, ``kB``, ``points``), both ends of a
  range with such a unit (``4-5 s``), and counts written with thousands separators (``191,792``); not a
  tolerance written "within N %" nor a section of a paper (``§3.2``). Plain integers (views, pixels, iterations,
  seeds, sizes) are descriptions, not measurements. Not checked: headings, code (option
  values and their defaults are written as code: ``confidence.tau = 0.1``), a paper's numbers, in the part
  of a block that starts with ``**Paper**`` (up to ``**Ours**``), and arithmetic from stated formulas, in the part
  of a block that starts with ``**Estimate**`` (up to ``**Measured**``): projections, not measurements.
- A block citing a result marked stale (benchmarks/mark_stale.py) says "stale".
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

SOURCE = re.compile(r"\[([\w.-]+\.json):\s*([^\]]+)\]")
CODE = re.compile(r"`[^`]*`")
UNITS = r"(?:\s?%|\s(?:s|ms|CPU-s|minutes|MB|MiB|GB|GiB|kB|points)\b)"
NUMBER = re.compile(r"(?<![\w.^/@§-])[−+-]?(\d{1,3}(?:,\d{3})+|\d+\.\d+|\d+)(?=(" + UNITS + r")?)(?![\w.]\d)")
# a range with a unit ("4-5 s", "270–290 MiB", "20..30 %"): both ends are measurements
RANGE = re.compile(r"(?<![\w.^/@-])(\d+(?:\.\d+)?)\s?(?:-|–|\.\.)\s?(\d+(?:\.\d+)?)(?=" + UNITS + r")")
PAPER = re.compile(r"\*\*Paper\*\*.*?(?=\*\*Ours\*\*|$)", re.S)
ESTIMATE = re.compile(r"\*\*Estimate\*\*.*?(?=\*\*Measured\*\*|$)", re.S)


def blocks(text: str) -> list[tuple[int, str]]:
    """(first line number, text) of each paragraph, list item and table; code fences and headings dropped."""
    found: list[tuple[int, str]] = []
    current: list[str] = []
    start, fenced = 0, False

    def flush() -> None:
        if current:
            found.append((start, "\n".join(current)))
        current.clear()

    for number, line in enumerate(text.splitlines(), 1):
        if line.startswith("```"):
            fenced = not fenced
            flush()
            continue
        if fenced or line.startswith("#") or not line.strip():
            flush()
            continue
        table = line.startswith("|")
        if re.match(r"\s{0,2}[-*] ", line) or (current and table and not current[-1].startswith("|")):
            flush()
        if not current:
            start = number
        current.append(line)
    flush()
    return found


def checked_numbers(block: str) -> list[str]:
    """The numbers of a block that need a source (see the module's docstring)."""
    text = ESTIMATE.sub(" ", PAPER.sub(" ", SOURCE.sub(" ", CODE.sub(" ", block))))
    numbers = []
    for m in NUMBER.finditer(text):
        token, unit = m.group(1), m.group(2)
        if unit and unit.strip() == "%" and text[:m.start()].endswith("within "):
            continue  # a tolerance, "within 1 %"
        if "." in token or "," in token or unit:
            numbers.append(token)
    for m in RANGE.finditer(text):
        numbers += [t for t in m.groups() if t not in numbers]
    return numbers


def _resolve(data: Any, path: str) -> Any:
    node = data
    for part in path.strip().split("/"):
        if isinstance(node, list) and part.isdigit() and int(part) < len(node):
            node = node[int(part)]
        elif isinstance(node, dict) and part in node:
            node = node[part]
        else:
            raise KeyError(part)
    return node


def _numbers(node: Any) -> list[float]:
    if isinstance(node, bool):
        return []
    if isinstance(node, (int, float)):
        return [float(node)]
    if isinstance(node, str):
        return [float(x) for x in re.findall(r"\d+(?:\.\d+)?", node)]
    if isinstance(node, dict):
        return [x for k, v in node.items() for x in (*_numbers(str(k)), *_numbers(v))]
    if isinstance(node, list):
        return [x for v in node for x in _numbers(v)]
    return []


def matches(written: str, values: list[float]) -> bool:
    """Whether ``written`` is one of ``values`` (or 100 × one) rounded as written."""
    digits = len(written.split(".")[1]) if "." in written else 0
    x = float(written.replace(",", ""))
    half = 0.5 * 10 ** -digits + 1e-9
    return any(abs(abs(v) - x) <= half or abs(abs(100 * v) - x) <= half for v in values)


def check(page: Path, results: Path) -> list[str]:
    """Every breach of the convention in ``page``, as ``line N: what``."""
    found = []
    cache: dict[str, Any] = {}
    for line, block in blocks(page.read_text()):
        numbers = checked_numbers(block)
        sources = SOURCE.findall(CODE.sub(" ", block))
        if not numbers and not sources:
            continue
        if numbers and not sources:
            found.append(f"line {line}: {', '.join(numbers[:6])} without a source")
            continue
        values: list[float] = []
        stale = False
        for name, paths in sources:
            if name not in cache:
                path = results / name
                cache[name] = json.loads(path.read_text()) if path.is_file() else None
            data = cache[name]
            if data is None:
                found.append(f"line {line}: source {name} is not in {results.name}/")
                continue
            stale = stale or bool(data.get("stale"))
            for key in paths.split(","):
                try:
                    values += _numbers(_resolve(data, key))
                except KeyError:
                    found.append(f"line {line}: {name} has no key {key.strip()!r}")
        missing = [n for n in numbers if not matches(n, values)]
        if missing:
            found.append(f"line {line}: {', '.join(missing[:8])} not found under the block's sources")
        if stale and "stale" not in block.lower():
            found.append(f"line {line}: cites a result marked stale without saying so")
    return found
