"""A tiny declarative schema for result JSONs: each benchmark script's module-level ``SCHEMA``.

A schema maps a top-level key to the type(s) its value must have; a key ending in ``?`` may be absent::

    SCHEMA = {"scene": str, "rows": list, "size?": (int, None)}

Types are ``str``, ``int``, ``float`` (an int is accepted too), ``bool``, ``list``, ``dict`` and ``None``
(JSON null), or a tuple of them. :func:`errors` also rejects a top-level key the schema does not name, unless
the result's ``stale`` mark lists it under ``unexpected_keys`` (a key added by hand or by an older version of
the script: the result is then shown as stale). No dependency beyond the standard library.
"""

from __future__ import annotations

import numbers
from collections.abc import Mapping
from typing import Any

# Keys every result may carry, written by the harness (support/bench.py) or benchmarks/mark_stale.py.
HARNESS = {"script": str, "argv": (list, None), "git": (str, None), "dirty?": (bool, None),
           "environment?": (dict, None), "inputs?": dict, "committed_in?": str, "stale?": dict}
STALE = {"date": str, "reason": str, "by": str, "refresh?": str, "unexpected_keys?": list}

_NAMES = {str: "string", int: "integer", float: "number", bool: "boolean", list: "list", dict: "object",
          type(None): "null"}


def _accepts(kind: Any, value: Any) -> bool:
    if kind is None:
        return value is None
    if kind is float:  # numpy scalars too: the harness checks before writing
        return isinstance(value, numbers.Real) and not isinstance(value, bool)
    if kind is int:
        return isinstance(value, numbers.Integral) and not isinstance(value, bool)
    return isinstance(value, kind)


def _kinds(spec: Any) -> tuple:
    return spec if isinstance(spec, tuple) else (spec,)


def _name(kind: Any) -> str:
    return _NAMES[type(None) if kind is None else kind]


def errors(data: Any, schema: Mapping[str, Any], *, harness: bool = True) -> list[str]:
    """What is wrong with ``data`` against ``schema`` (plus :data:`HARNESS` when ``harness``); [] when nothing."""
    if not isinstance(data, dict):
        return ["not a JSON object"]
    full = {**(HARNESS if harness else {}), **schema}
    found = []
    known = set()
    for key, spec in full.items():
        optional = key.endswith("?")
        name = key[:-1] if optional else key
        known.add(name)
        if name not in data:
            if not optional:
                found.append(f"missing key {name!r}")
            continue
        if not any(_accepts(k, data[name]) for k in _kinds(spec)):
            want = " or ".join(_name(k) for k in _kinds(spec))
            found.append(f"{name!r} is {type(data[name]).__name__}, not {want}")
    stale = data.get("stale")
    if harness and isinstance(stale, dict):
        found += [f"stale: {e}" for e in errors(stale, STALE, harness=False)]
    allowed = set(stale.get("unexpected_keys") or []) if isinstance(stale, dict) else set()
    found += [f"key {k!r} is not in the script's SCHEMA" for k in data if k not in known and k not in allowed]
    return found
