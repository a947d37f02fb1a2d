"""``--set STAGE.NAME=VALUE``: the one parser of typed option values, for every command that takes ``--set``.

A STAGE is a nested options dataclass of a parent (:func:`nested_options`: the fields of ``PipelineOptions``
whose type is an :class:`Options`), so an options dataclass added to the pipeline is reachable without touching
the command line; NAME may itself go down a nested dataclass (``refinement.sky.far_factor=1.4``). A value is
parsed by the field's type: ``true/false/on/off/yes/no/1/0`` for booleans, ``A,B`` for tuples, ``none`` for an
unset optional value. Former names (aliases) still work.
"""

from __future__ import annotations

import argparse
import dataclasses
import typing
from collections.abc import Mapping
from typing import Any

from engine.core.errors import OptionsError
from engine.core.options import Options
from workbench.flags.options import base_type, tuple_parser

TRUE, FALSE = ("true", "1", "yes", "on"), ("false", "0", "no", "off")


def nested_options(cls: type[Options]) -> dict[str, type[Options]]:
    """The fields of ``cls`` that are options dataclasses themselves, by name (the stages of a pipeline)."""
    hints = typing.get_type_hints(cls)
    return {f.name: hints[f.name] for f in dataclasses.fields(cls)
            if isinstance(hints[f.name], type) and issubclass(hints[f.name], Options)}


def split_item(item: str, unprefixed: str | None = None) -> tuple[str, str, str]:
    """``STAGE.NAME=VALUE`` -> (STAGE, NAME, VALUE); NAME may hold dots (nested options). With ``unprefixed``,
    ``NAME=VALUE`` means ``unprefixed.NAME=VALUE`` (``deepc probe --set window=7``)."""
    key, sep, text = item.partition("=")
    stage, dot, name = key.partition(".")
    if unprefixed is not None and sep and not dot:
        stage, dot, name = unprefixed, ".", key
    if not sep or not dot or not stage or not name:
        form = "NAME=VALUE" if unprefixed is not None else "STAGE.NAME=VALUE"
        raise OptionsError(f"--set {item!r}: expected {form}")
    return stage, name, text


def check_stages(assignments: list[str], stages: Mapping[str, Any] | tuple[str, ...],
                 unprefixed: str | None = None) -> None:
    """Refuse an item whose STAGE is none of ``stages``, naming them (``unprefixed``: :func:`split_item`)."""
    for item in assignments:
        stage = split_item(item, unprefixed)[0]
        if stage not in stages:
            raise OptionsError(f"--set {item!r}: unknown stage {stage!r} (one of {', '.join(stages)})")


def parse_value(cls: type[Options], name: str, text: str, item: str) -> tuple[str, Any]:
    """(field name, typed value) of ``NAME=text`` for ``cls``; ``name`` may go down nested options (``sky.x``),
    whose value is then a dict of its own changes."""
    head, dot, rest = name.partition(".")
    field = cls.field_name(head)  # a former name (alias) still works
    if field is None:
        raise OptionsError(f"--set {item!r}: {cls.__name__} has no option {head!r}")
    hint = base_type(typing.get_type_hints(cls)[field])
    nested = isinstance(hint, type) and issubclass(hint, Options)
    if nested != bool(dot):
        raise OptionsError(f"--set {item!r}: {head} is a group of options; set {head}.NAME=VALUE" if nested
                           else f"--set {item!r}: {head} has no options of its own")
    if nested:
        sub, value = parse_value(hint, rest, text, item)
        return field, {sub: value}
    try:
        if hint is bool:
            if text.lower() not in TRUE + FALSE:
                raise ValueError
            return field, text.lower() in TRUE
        if typing.get_origin(hint) is tuple:
            return field, tuple_parser(field, typing.get_args(hint))(text)
        if text.lower() == "none" and hint is not str:
            return field, None
        return field, hint(text)
    except argparse.ArgumentTypeError as exc:  # a tuple: the parser says what is wrong
        raise OptionsError(f"--set {item!r}: {exc}") from None
    except ValueError:
        raise OptionsError(f"--set {item!r}: not a valid {getattr(hint, '__name__', hint)}") from None


def section_overrides(assignments: list[str], section: str, cls: type[Options],
                      unprefixed: str | None = None) -> dict[str, Any]:
    """The ``--set`` items of ``section`` as typed values for ``cls`` (field name -> value; a dict of changes for
    a nested options field; :func:`with_overrides` applies them); ``unprefixed``: :func:`split_item`."""
    values: dict[str, Any] = {}
    for item in assignments:
        stage, name, text = split_item(item, unprefixed)
        if stage == section:
            field, value = parse_value(cls, name, text, item)
            values[field] = merged(values.get(field), value)
    return values


def merged(old: Any, new: Any) -> Any:
    """``new`` over ``old``; two dicts of changes (nested options) merge."""
    if isinstance(old, dict) and isinstance(new, dict):
        return {**old, **{k: merged(old.get(k), v) for k, v in new.items()}}
    return new


def with_overrides(options: Options, values: Mapping[str, Any]) -> Options:
    """A copy of ``options`` with ``values`` (from :func:`section_overrides`; a dict of changes for a nested options
    field) changed, validated once as a whole (so that changes that are only valid together are)."""
    return _replaced(options, values).validate()


def _replaced(options: Options, values: Mapping[str, Any]) -> Options:
    changes = {name: _replaced(getattr(options, name), value)
               if isinstance(value, dict) and isinstance(getattr(options, name), Options) else value
               for name, value in values.items()}
    return dataclasses.replace(options, **changes)


def stage_overrides(assignments: list[str], cls: type[Options]) -> dict[str, dict[str, Any]]:
    """The ``--set`` items of every nested stage of ``cls`` (:func:`nested_options`), stage -> changes; items of
    other stages are left to their callers."""
    return {name: section_overrides(assignments, name, stage) for name, stage in nested_options(cls).items()}


def apply_assignments(options: Options, assignments: list[str]) -> Options:
    """``options`` with the ``--set`` items of its nested stages applied, validated."""
    return with_overrides(options, stage_overrides(assignments, type(options)))
