"""Terminal progress: one tqdm bar per PatchMatch pass, advancing view by view, with the whole run's ETA."""

from __future__ import annotations

import sys
from typing import Any

from tqdm import tqdm

# a pass's bar: its views and its own elapsed time, then the whole run's ETA (a pass's own "remaining" read as
# the run's: "level 2 photometric 1/7 [08:17<49:46]" was one of nine passes at a sixteenth of the pixels)
BAR_FORMAT = "{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} [{elapsed}{postfix}]"


class PassProgress:
    """``progress(description, done, total)`` callback that draws a bar per pass (e.g. "level 2 photometric").

    A call with done 0 starts a pass's bar (its clock starts then, so the first view's time counts) and the
    call with done == total closes it (so its elapsed time ends with the pass's last view). ``eta``: anything with
    ``text()`` ("ETA 12 min", ``engine.run.eta.RunEta``), shown after the pass's elapsed time."""

    def __init__(self, enabled: bool = True, eta: Any = None):
        self.enabled = enabled
        self.eta = eta
        self._bar: tqdm | None = None
        self._description: str | None = None

    def __call__(self, description: str, done: int, total: int) -> None:
        if not self.enabled:
            return
        if done == 0 or description != self._description or self._bar is None:
            self.close()
            self._bar = tqdm(total=total, desc=f"{description:<22}", unit="view", file=sys.stderr,
                             leave=True, dynamic_ncols=True, bar_format=BAR_FORMAT)
            self._description = description
        self._bar.n = done
        eta = self.eta.text() if self.eta is not None else ""
        self._bar.set_postfix_str(f"run {eta}" if eta else "", refresh=False)
        self._bar.refresh()
        if done >= total:
            self.close()

    def note(self, line: str) -> None:
        """Print one line on stderr above the bar (the bar is drawn again below it)."""
        if self.enabled:
            tqdm.write(line, file=sys.stderr)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None
            self._description = None
