"""Errors the user can act on.

Every problem with user input (a scene, a map file, an option) raises :class:`DeepCError` with a
one-line message that names the file (or option) and says what is wrong. The command line prints
that line and exits with status 2; a traceback is a bug.
"""

from __future__ import annotations

from pathlib import Path


class DeepCError(Exception):
    """A problem with user input, explained in one line."""

    def __init__(self, message: str, path: str | Path | None = None):
        self.path = None if path is None else Path(path)
        text = " ".join(str(message).split())  # always one line
        super().__init__(f"{self.path}: {text}" if self.path is not None else text)


class OptionsError(DeepCError):
    """An option value that is out of range or inconsistent with another option."""
