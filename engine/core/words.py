"""Counted nouns in what users read: "1 view", "2 views", never "1 views"."""

from __future__ import annotations


def plural(count: int, noun: str, many: str | None = None) -> str:
    """``count`` and ``noun``, the plural form (``many``, else ``noun + "s"``) unless the count is one."""
    return f"{count} {noun if count == 1 else many or noun + 's'}"
