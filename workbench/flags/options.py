"""The one mapping from options dataclasses to command-line flags.

Every field of an :class:`engine.core.options.Options` subclass with ``cli=True`` becomes a flag:
``max_image_size`` -> ``--max-image-size``; booleans get ``--x/--no-x``; ``tuple[float, float]``
fields take ``A,B``. Defaults are *not* given to argparse: a flag that is not passed leaves the
dataclass default in force, so the defaults live in one place only. ``--set STAGE.NAME=VALUE`` is parsed by
``workbench/flags/assignments.py`` with the same types.
"""

from __future__ import annotations

import argparse
import dataclasses
import typing
from collections.abc import Callable
from typing import Any

from engine.core.errors import OptionsError
from engine.core.options import Options, describe


def flag_name(field_name: str) -> str:
    return "--" + field_name.replace("_", "-")


def base_type(hint: Any) -> Any:
    """The type of a field without ``| None``."""
    args = [a for a in typing.get_args(hint) if a is not type(None)]
    if typing.get_origin(hint) in (typing.Union, getattr(__import__("types"), "UnionType", None)) and args:
        return args[0]
    return hint


def tuple_parser(name: str, kinds: tuple) -> Callable[[str], tuple]:
    """An argparse type for a tuple field: ``A,B`` -> a tuple of ``kinds`` (``tuple[int, ...]``: any number)."""
    def parse(text: str):
        parts = text.split(",")
        if len(kinds) == 2 and kinds[1] is Ellipsis:  # tuple[int, ...]: any number of values
            return tuple(tuple_parser(name, (kinds[0],) * len(parts))(text))
        if len(parts) != len(kinds):
            raise argparse.ArgumentTypeError(f"{name} takes {len(kinds)} comma-separated values, got {text!r}")
        try:
            return tuple(k(p) for k, p in zip(kinds, parts, strict=True))
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name}: not numbers: {text!r}") from None
    return parse


def add_options_flags(parser: argparse.ArgumentParser | argparse._ArgumentGroup, cls: type[Options],
                      only: list[str] | None = None, skip: tuple[str, ...] = ()) -> list[str]:
    """Add a flag per CLI field of ``cls``; returns the field names added."""
    hints = typing.get_type_hints(cls)
    added = []
    for f in dataclasses.fields(cls):
        if not f.metadata.get("cli", True) or f.name in skip or (only is not None and f.name not in only):
            continue
        hint = base_type(hints[f.name])
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        if hint is bool:
            shown = "on" if default else "off"
        elif default is not None:
            shown = ",".join(map(str, default)) if isinstance(default, tuple) else str(default)
        else:
            shown = None
        help_text = describe(f, shown).replace("%", "%%")  # argparse formats help with %
        kwargs: dict[str, Any] = {"dest": f"{cls.__name__}.{f.name}", "default": None, "help": help_text}
        if hint is bool:
            kwargs["action"] = argparse.BooleanOptionalAction
        elif typing.get_origin(hint) is tuple:
            kinds = typing.get_args(hint)
            kwargs["type"] = tuple_parser(flag_name(f.name), kinds)
            kwargs["metavar"] = f.metadata.get("metavar") or ",".join(["X"] * len(kinds))
        else:
            kwargs["type"] = hint
            kwargs["metavar"] = f.metadata.get("metavar") or f.name.rsplit("_", 1)[-1].upper()
            if f.metadata.get("choices"):
                kwargs.pop("metavar")
                kwargs["choices"] = f.metadata["choices"]
        parser.add_argument(flag_name(f.name), **kwargs)
        added.append(f.name)
    return added


def given_flags(cls: type[Options], args: argparse.Namespace) -> dict[str, Any]:
    """The fields of ``cls`` whose flags were given on the command line."""
    prefix = f"{cls.__name__}."
    return {key[len(prefix):]: value for key, value in vars(args).items()
            if key.startswith(prefix) and value is not None}


def options_from_args(cls: type[Options], args: argparse.Namespace, base: Options | None = None,
                      **overrides: Any) -> Options:
    """Build ``cls`` from the flags that were given, validated; the others keep the values of
    ``base`` (a preset) or the dataclass defaults."""
    values = {**given_flags(cls, args), **overrides}
    try:
        return base.replace(**values) if base is not None else cls(**values).validate()
    except TypeError as exc:
        raise OptionsError(str(exc)) from None
