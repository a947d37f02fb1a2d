"""Terminal progress: one tqdm bar per PatchMatch pass, advancing view by view."""

from __future__ import annotations

import sys

from tqdm import tqdm


class PassProgress:
    """``progress(description, done, total)`` callback that draws a bar per pass (e.g. "level 2 photometric").

    A call with done 0 starts a pass's bar (its clock starts then, so the first view's time counts) and the
    call with done == total closes it (so its elapsed time ends with the pass's last view)."""

    def __init__(self, enabled: bool = True):
        self.enabled = enabled
        self._bar: tqdm | None = None
        self._description: str | None = None

    def __call__(self, description: str, done: int, total: int) -> None:
        if not self.enabled:
            return
        if done == 0 or description != self._description or self._bar is None:
            self.close()
            self._bar = tqdm(total=total, desc=f"{description:<22}", unit="view", file=sys.stderr,
                             leave=True, dynamic_ncols=True)
            self._description = description
        self._bar.n = done
        self._bar.refresh()
        if done >= total:
            self.close()

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None
            self._description = None
