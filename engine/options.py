"""Options dataclasses: one per pipeline stage, plain data, validated, serialisable.

Each stage declares its options as a dataclass deriving from :class:`Options`, with the paper's
defaults (SPEC.md §12) and a ``help`` text in the field metadata. The command line and the viewer
GUI are generated from these fields (``workbench/cli.py``), and ``metrics.json`` and recordings
carry ``to_dict()`` of the options used.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from typing import Any, TypeVar

from engine.errors import OptionsError

T = TypeVar("T", bound="Options")


def option(default: Any, help: str, *, cli: bool = True, choices: tuple | None = None,
           metavar: str | None = None) -> Any:
    """A dataclass field with a help text; ``cli=False`` keeps it off the command line."""
    meta = {"help": help, "cli": cli, "choices": choices, "metavar": metavar}
    if isinstance(default, (list, dict, set)):
        return dataclasses.field(default_factory=lambda: type(default)(default), metadata=meta)
    if dataclasses.is_dataclass(default):  # nested options: each instance gets its own copy
        return dataclasses.field(default_factory=lambda: dataclasses.replace(default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


@dataclasses.dataclass
class Options:
    """Base class: ``validate()``, ``to_dict()``, ``from_dict()`` and ``replace()``."""

    def validate(self: T) -> T:
        """Check every value; raise :class:`OptionsError` naming the option. Returns self."""
        for f in dataclasses.fields(self):
            choices = f.metadata.get("choices")
            value = getattr(self, f.name)
            if choices is not None and value not in choices:
                raise OptionsError(f"option {f.name}={value!r}: must be one of {', '.join(map(str, choices))}")
            if isinstance(value, float) and not math.isfinite(value):
                raise OptionsError(f"option {f.name}={value!r}: must be a finite number")
        return self

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (tuples become lists)."""
        out = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, Options):
                value = value.to_dict()
            elif isinstance(value, tuple):
                value = list(value)
            out[f.name] = value
        return out

    @classmethod
    def from_dict(cls: type[T], data: dict[str, Any]) -> T:
        """Inverse of :meth:`to_dict`; unknown keys are an error, missing keys take defaults."""
        names = {f.name: f for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - set(names))
        if unknown:
            raise OptionsError(f"{cls.__name__}: unknown option(s) {', '.join(unknown)}")
        hints = typing.get_type_hints(cls)
        kwargs = {}
        for key, value in data.items():
            hint = hints.get(key)
            origin = typing.get_origin(hint)
            if isinstance(value, list) and (origin is tuple or _optional_of(hint, tuple)):
                value = tuple(value)
            elif isinstance(hint, type) and issubclass(hint, Options) and isinstance(value, dict):
                value = hint.from_dict(value)
            kwargs[key] = value
        return cls(**kwargs).validate()

    def replace(self: T, **changes: Any) -> T:
        """A validated copy with some fields changed."""
        return dataclasses.replace(self, **changes).validate()


def _optional_of(hint: Any, kind: type) -> bool:
    args = typing.get_args(hint)
    return any(typing.get_origin(a) is kind or a is kind for a in args)


def check(condition: bool, name: str, value: Any, requirement: str) -> None:
    """Raise :class:`OptionsError` for option ``name`` unless ``condition`` holds."""
    if not condition:
        raise OptionsError(f"option {name}={value!r}: {requirement}")
