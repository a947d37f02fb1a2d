"""Observer protocol: how the engine reports progress without knowing who listens.

The engine calls ``observer.on_iteration(event)`` after every red-black iteration of every pass and
level, and ``observer.on_stage(name, **info)`` at coarse stage boundaries. Both methods are optional:
the engine checks with ``hasattr`` (or derive from :class:`NullObserver`). When no observer is given
the engine builds no events at all, so a run without observers pays nothing for them.

Arrays in an :class:`IterationEvent` are read-only *views* of the engine's live state (no copies):
they are valid during the call and change afterwards. An observer that keeps data must copy it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from typing import Any, Protocol, runtime_checkable

import numpy as np


@dataclasses.dataclass(frozen=True)
class IterationEvent:
    """State of one view after one red-black iteration.

    Attributes:
        view: index of the view in the list given to ``run_patchmatch``.
        view_name: its name.
        level: pyramid level, 0 = finest (working resolution).
        pass_kind: ``"photometric"`` or ``"geometric"``.
        pass_index: 0..2 within a level (0 = photometric, 1 and 2 = geometric).
        iteration: 0-based red-black iteration within the pass.
        step: global step counter, strictly increasing over the whole run (0-based).
        depth: (H, W) float32 depth (camera-frame z), 0 = none. Read-only view.
        normal: (H, W, 3) float32 unit normals, camera frame, facing the camera. Read-only view.
        cost: (H, W) float32 aggregated matching cost of the stored hypothesis. Read-only view.
        selected_views: (H, W) uint32 bitmask over positions in the view's source list. Read-only.
        seconds: wall-clock seconds spent on this iteration.
        ncc_windows: photometric costs (bilateral NCC windows) evaluated in this iteration; the engine's
            caches make this far fewer than the (K_up + 1 + 5) · N per pixel of an uncached half-step.
        pixel_updates: pixel updates evaluated in this iteration (both half-steps).
        pixels_skipped: pixel updates the active set left out (``PatchMatchOptions.active_share``; 0 when off).
    """

    view: int
    view_name: str
    level: int
    pass_kind: str
    pass_index: int
    iteration: int
    step: int
    depth: np.ndarray
    normal: np.ndarray
    cost: np.ndarray
    selected_views: np.ndarray
    seconds: float
    ncc_windows: int = 0
    pixel_updates: int = 0
    pixels_skipped: int = 0


def readonly(array: np.ndarray) -> np.ndarray:
    """A non-writeable view of ``array`` (no copy)."""
    view = array.view()
    view.flags.writeable = False
    return view


@runtime_checkable
class Observer(Protocol):
    """What an observer may implement (both methods optional)."""

    def on_iteration(self, event: IterationEvent) -> None: ...

    def on_stage(self, name: str, **info: Any) -> None: ...


class NullObserver:
    """Base class with no-op methods; derive and override what you need."""

    def on_iteration(self, event: IterationEvent) -> None:
        pass

    def on_stage(self, name: str, **info: Any) -> None:
        pass


class ObserverList(NullObserver):
    """Fans every call out to several observers (each may implement either method or neither)."""

    def __init__(self, observers: Iterable[Any] = ()):
        self.observers = [o for o in observers if o is not None]

    def on_iteration(self, event: IterationEvent) -> None:
        for o in self.observers:
            if hasattr(o, "on_iteration"):
                o.on_iteration(event)

    def on_stage(self, name: str, **info: Any) -> None:
        for o in self.observers:
            if hasattr(o, "on_stage"):
                o.on_stage(name, **info)
