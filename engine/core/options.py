"""Options dataclasses: one per pipeline stage, plain data, validated, serialisable.

Each stage declares its options as a dataclass deriving from :class:`Options`, one :func:`option` per
field: its default, one line of help, its unit, where the default comes from (``source``) and the
constraints its value must meet (range, choices, odd, ...). :meth:`Options.validate` checks the declared
constraints; a class overrides it only for rules that involve several fields (:func:`check`). The command
line is generated from the fields (``workbench/flags/options.py``), and ``metrics.json`` and recordings carry
``to_dict()`` of the options used. Why a default departs from the paper, with the measurements, is written
in ``docs/decisions.md``, not in the help.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
import numbers
import typing
from typing import Any, TypeVar

from engine.core.errors import OptionsError

T = TypeVar("T", bound="Options")

#: Where a default comes from: the DeepC-MVS paper (Kuhn et al., 3DV 2020), the code of ACMM or COLMAP that
#: the paper builds on, Rossi et al.'s refinement code (the paper's refinement), the ETH3D evaluation
#: program, or this project ("ours": an engineering setting, or a departure explained in docs/decisions.md).
SOURCES = ("paper", "ACMM", "COLMAP", "OpenMVS", "Rossi", "ETH3D", "ours")
ORDERS = ("<", "<=")


@dataclasses.dataclass(frozen=True)
class Constraint:
    """What a value must satisfy; a tuple value must satisfy it entry by entry (plus ``ordered``/``nonempty``).

    ``low``/``high`` are inclusive bounds, ``above``/``below`` exclusive ones; ``off`` is a value that
    switches the option off and is accepted whatever the other constraints say.
    """

    low: float | None = None
    high: float | None = None
    above: float | None = None
    below: float | None = None
    odd: bool = False
    multiple_of: int | None = None
    choices: tuple | None = None
    off: Any = None
    ordered: str | None = None
    nonempty: bool = False

    def numeric(self) -> bool:
        return any(v is not None for v in (self.low, self.high, self.above, self.below, self.multiple_of)) \
            or self.odd

    def _entry_ok(self, v: Any, integer: bool) -> bool:
        if self.choices is not None:
            return v in self.choices
        if not self.numeric():
            return True
        if not isinstance(v, numbers.Real) or isinstance(v, bool) or (integer and not isinstance(v, numbers.Integral)):
            return False
        return ((self.low is None or v >= self.low) and (self.high is None or v <= self.high)
                and (self.above is None or v > self.above) and (self.below is None or v < self.below)
                and (not self.odd or v % 2 == 1) and (self.multiple_of is None or v % self.multiple_of == 0))

    def holds(self, value: Any, integer: bool = False) -> bool:
        """Whether ``value`` meets the constraint (``integer``: entries must be integers)."""
        if self.off is not None and value == self.off:
            return True
        if isinstance(value, (tuple, list)):
            return ((not self.nonempty or len(value) > 0) and all(self._entry_ok(v, integer) for v in value)
                    and (self.ordered is None or all(a < b if self.ordered == "<" else a <= b
                                                     for a, b in itertools.pairwise(value))))
        return self._entry_ok(value, integer)

    def requirement(self, integer: bool = False, entries: bool = False) -> str:
        """The constraint in words: 'must be odd and >= 3', 'must be in [0, 1]', ..."""
        parts = []
        if self.odd:
            parts.append("odd")
        if self.multiple_of is not None:
            parts.append(f"a multiple of {self.multiple_of}")
        lo, lo_open = (self.above, True) if self.above is not None else (self.low, False)
        hi, hi_open = (self.below, True) if self.below is not None else (self.high, False)
        if lo is not None and hi is not None:
            if integer and not lo_open and not hi_open:
                parts.append(f"in {_fmt(lo)}..{_fmt(hi)}")
            else:
                parts.append(f"in {'(' if lo_open else '['}{_fmt(lo)}, {_fmt(hi)}{')' if hi_open else ']'}")
        elif lo is not None:
            parts.append(f"{'>' if lo_open else '>='} {_fmt(lo)}")
        elif hi is not None:
            parts.append(f"{'<' if hi_open else '<='} {_fmt(hi)}")
        if integer and parts and not self.odd and self.multiple_of is None:
            parts[0] = f"an integer {parts[0]}"
        if self.choices is not None:
            parts.append(f"one of {', '.join(map(str, self.choices))}")
        text = " and ".join(parts)
        if entries:
            order = {"<": "increasing", "<=": "in non-decreasing order"}.get(self.ordered or "")
            text = "; ".join(t for t in (f"every entry must be {text}" if text else "",
                                         "at least one entry" if self.nonempty else "",
                                         f"entries {order}" if order else "") if t)
        else:
            text = f"must be {text}"
        if self.off is not None:
            text = f"must be {self.off!r} (off) or {text.removeprefix('must be ')}"
        return text


def _fmt(x: float) -> str:
    return str(x) if isinstance(x, int) else f"{x:g}"


_UNSET = object()  # ``option(absent=...)`` not given


def option(default: Any, help: str, *, source: str | None = None, unit: str | None = None,
           low: float | None = None, high: float | None = None, above: float | None = None,
           below: float | None = None, odd: bool = False, multiple_of: int | None = None,
           choices: tuple | None = None, off: Any = None, ordered: str | None = None, nonempty: bool = False,
           aliases: tuple[str, ...] = (), cli: bool = True, metavar: str | None = None,
           absent: Any = _UNSET) -> Any:
    """A dataclass field: default, one line of help, unit, source of the default and declared constraints.

    ``aliases`` are former names that :meth:`Options.from_dict` and ``--set`` still accept (saved runs);
    ``absent`` is the value that reproduces a run saved before the option existed (``from_dict(saved=True)``
    gives it to such a run; the default when unset); ``cli=False`` keeps the field off the command line. Nested
    options (an :class:`Options` default) need no source: their own fields carry one.
    """
    nested = isinstance(default, Options)
    if "\n" in help:
        raise ValueError(f"option help must be one line: {help!r}")
    if not nested and source not in SOURCES:
        raise ValueError(f"option source={source!r}: must be one of {', '.join(SOURCES)} ({help!r})")
    if ordered is not None and ordered not in ORDERS:
        raise ValueError(f"option ordered={ordered!r}: must be one of {ORDERS}")
    constraint = Constraint(low, high, above, below, odd, multiple_of, choices and tuple(choices), off, ordered,
                            nonempty)
    meta = {"help": help, "source": source, "unit": unit, "constraint": constraint, "choices": choices,
            "aliases": tuple(aliases), "cli": cli, "metavar": metavar, "absent": absent}
    if isinstance(default, (list, dict, set)):
        return dataclasses.field(default_factory=lambda: type(default)(default), metadata=meta)
    if nested:  # each instance gets its own copy
        return dataclasses.field(default_factory=lambda: dataclasses.replace(default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def describe(f: dataclasses.Field, default: str | None = None) -> str:
    """One line of help for field ``f``: 'help [unit] (default from: source)', or with ``default`` (its
    value as text) 'help [unit] (default: value, from: source)'."""
    text = f.metadata.get("help", "")
    unit, source = f.metadata.get("unit"), f.metadata.get("source")
    if unit:
        text += f" [{unit}]"
    if default is not None and source:
        text += f" (default: {default}, from: {source})"
    elif default is not None:
        text += f" (default: {default})"
    elif source:
        text += f" (default from: {source})"
    return text


@dataclasses.dataclass
class Options:
    """Base class: ``validate()``, ``to_dict()``, ``from_dict()`` and ``replace()``."""

    def validate(self: T) -> T:
        """Check every declared constraint; raise :class:`OptionsError` naming the option. Returns self.

        Subclasses override this (calling it first) only for rules that involve several fields."""
        hints = _hints(type(self))
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, Options):  # a stage of a pipeline: its own fields, its own rules
                value.validate()
                continue
            hint = hints.get(f.name)
            if value is None and _allows_none(hint):
                continue
            entries = value if isinstance(value, (tuple, list)) else (value,)
            if any(isinstance(v, float) and not math.isfinite(v) for v in entries):
                raise OptionsError(f"option {f.name}={value!r}: must be a finite number")
            length = _fixed_length(hint)
            if length is not None and (not isinstance(value, (tuple, list)) or len(value) != length):
                raise OptionsError(f"option {f.name}={value!r}: needs {length} values")
            constraint: Constraint | None = f.metadata.get("constraint")
            if constraint is None:
                continue
            integer = _base_scalar(hint) is int
            if not constraint.holds(value, integer):
                raise OptionsError(f"option {f.name}={value!r}: "
                                   f"{constraint.requirement(integer, isinstance(value, (tuple, list)))}")
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
    def field_name(cls, name: str) -> str | None:
        """The field called ``name`` or formerly called so (an alias); None when there is none."""
        for f in dataclasses.fields(cls):
            if name == f.name or name in f.metadata.get("aliases", ()):
                return f.name
        return None

    @classmethod
    def from_dict(cls: type[T], data: dict[str, Any], saved: bool = False) -> T:
        """Inverse of :meth:`to_dict`; former names (aliases) are accepted, unknown keys are an error,
        missing keys take defaults, or with ``saved`` (the options a run saved: they re-run it) the value that
        reproduces a run made before the option existed (``option(absent=...)``), in nested options too."""
        renamed = {key: cls.field_name(key) for key in data}
        unknown = sorted(key for key, name in renamed.items() if name is None)
        if unknown:
            raise OptionsError(f"{cls.__name__}: unknown option(s) {', '.join(unknown)}")
        hints = _hints(cls)
        kwargs = {}
        for key, value in data.items():
            name = renamed[key]
            if name in kwargs:
                raise OptionsError(f"{cls.__name__}: option {name} given twice (also as its former name {key})")
            hint = hints.get(name)
            origin = typing.get_origin(hint)
            if isinstance(value, list) and (origin is tuple or _optional_of(hint, tuple)):
                value = tuple(value)
            elif isinstance(hint, type) and issubclass(hint, Options) and isinstance(value, dict):
                value = hint.from_dict(value, saved)
            kwargs[name] = value
        if saved:
            for f in dataclasses.fields(cls):
                if f.name not in kwargs and f.metadata.get("absent", _UNSET) is not _UNSET:
                    kwargs[f.name] = f.metadata["absent"]
        return cls(**kwargs).validate()

    @classmethod
    def current_names(cls, data: dict[str, Any]) -> dict[str, Any]:
        """``data`` (a :meth:`to_dict`, perhaps saved by an older run) with former option names (aliases) replaced by
        today's, in nested options too; values untouched, keys this class does not know kept as they are."""
        hints = _hints(cls)
        out = {}
        for key, value in data.items():
            name = cls.field_name(key) or key
            hint = hints.get(name)
            if isinstance(hint, type) and issubclass(hint, Options) and isinstance(value, dict):
                value = hint.current_names(value)
            out[name] = value
        return out

    def replace(self: T, **changes: Any) -> T:
        """A validated copy with some fields changed."""
        return dataclasses.replace(self, **changes).validate()


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _optional_of(hint: Any, kind: type) -> bool:
    args = typing.get_args(hint)
    return any(typing.get_origin(a) is kind or a is kind for a in args)


def _allows_none(hint: Any) -> bool:
    return hint is None or type(None) in typing.get_args(hint)


def _without_none(hint: Any) -> Any:
    args = [a for a in typing.get_args(hint) if a is not type(None)]
    return args[0] if type(None) in typing.get_args(hint) and len(args) == 1 else hint


def _base_scalar(hint: Any) -> Any:
    """int / float / ... of a scalar field, or of the entries of a tuple field."""
    hint = _without_none(hint)
    if typing.get_origin(hint) is tuple:
        kinds = {a for a in typing.get_args(hint) if a is not Ellipsis}
        return kinds.pop() if len(kinds) == 1 else None
    return hint


def _fixed_length(hint: Any) -> int | None:
    """n for a ``tuple[X, Y, ...]`` of n named entries; None for any other type (``tuple[X, ...]`` included)."""
    hint = _without_none(hint)
    args = typing.get_args(hint)
    if typing.get_origin(hint) is not tuple or not args or Ellipsis in args:
        return None
    return len(args)


def check(condition: bool, name: str, value: Any, requirement: str) -> None:
    """Raise :class:`OptionsError` for option ``name`` unless ``condition`` holds (rules across fields)."""
    if not condition:
        raise OptionsError(f"option {name}={value!r}: {requirement}")
