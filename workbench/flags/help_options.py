"""``deepc run --help-options``: every ``--set STAGE.NAME=VALUE`` option, one line each, read from the options
dataclasses (``option(...)`` metadata: help, unit, source, constraints), so the list cannot fall behind them."""

from __future__ import annotations

import argparse
import dataclasses
import typing
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

from engine.core.options import SOURCES, Options
from workbench.flags.options import base_type

HEADER = ("--set STAGE.NAME=VALUE options: name, type, default [unit], where the default comes from "
          f"({', '.join(SOURCES)}; docs/decisions.md says why where it departs from the paper), what it does")


def type_text(hint: Any, choices: Sequence | None) -> str:
    """'int', 'float,float', 'int,...', 'adam|fast', with '|none' where the option may be unset."""
    base = base_type(hint)
    if choices:
        text = "|".join(map(str, choices))
    elif typing.get_origin(base) is tuple:
        text = ",".join("..." if k is Ellipsis else getattr(k, "__name__", str(k)) for k in typing.get_args(base))
    else:
        text = getattr(base, "__name__", str(base))
    return text + ("|none" if base is not hint and type(None) in typing.get_args(hint) else "")


def value_text(value: Any) -> str:
    """A value as ``--set`` takes it: true/false, none, A,B."""
    if isinstance(value, bool):
        return str(value).lower()
    if value is None:
        return "none"
    if isinstance(value, tuple | list):
        return ",".join(map(str, value))
    return str(value) if value != "" else '""'


def option_rows(prefix: str, options: Options) -> Iterator[tuple[str, str, str, str, str]]:
    """(name, type, default, source, help) of every field of ``options`` (its values are the defaults shown),
    nested options flattened to ``prefix.group.name``."""
    hints = typing.get_type_hints(type(options))
    for f in dataclasses.fields(options):
        value = getattr(options, f.name)
        if isinstance(value, Options):
            yield from option_rows(f"{prefix}.{f.name}", value)
            continue
        meta = f.metadata
        unit = f" {meta['unit']}" if meta.get("unit") else ""
        source, text = meta.get("source") or "", meta.get("help", "")
        constraint = meta.get("constraint")
        if constraint is not None and not meta.get("choices"):
            integer = base_type(hints[f.name]) is int
            requirement = constraint.requirement(integer, isinstance(value, tuple | list))
            if requirement.strip() not in ("must be", ""):
                text += f"; {requirement}"
        own = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        if own != value:  # the pipeline's default (a preset) differs from the dataclass's
            text += f" (the dataclass's default: {value_text(own)}, from {source})"
            source = "pipeline"
        yield (f"{prefix}.{f.name}", type_text(hints[f.name], meta.get("choices")), value_text(value) + unit,
               source, text)


def option_lines(sections: Mapping[str, Options]) -> list[str]:
    """The listing: a header, then one aligned line per option of every section (name -> its defaults)."""
    rows = [row for name, defaults in sections.items() for row in option_rows(name, defaults)]
    widths = [min(max(len(row[i]) for row in rows), cap) for i, cap in enumerate((40, 24, 24, 8))]
    return [HEADER] + ["  ".join([*(cell.ljust(w) for cell, w in zip(row[:4], widths, strict=True)), row[4]])
                       for row in rows]


class HelpOptionsAction(argparse.Action):
    """``--help-options``: print every ``deepc run --set`` option and exit, like ``--help``."""

    def __init__(self, option_strings: Sequence[str], dest: str = argparse.SUPPRESS,
                 default: Any = argparse.SUPPRESS, help: str | None = None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None) -> None:  # noqa: ARG002
        from workbench.flags.run_options import run_sections  # lazy: the engine pipeline

        print("\n".join(option_lines(run_sections())))
        parser.exit()
