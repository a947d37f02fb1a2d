"""Newest request wins: how the viewer schedules its recomputations.

GUI events arrive faster than a result can be computed and pushed to every browser tab (50 per second from
five tabs). Queueing each of them made latency and memory grow with the load, so every piece here keeps
only the newest request and drops the ones it superseded:

- :class:`LatestOnly` runs a function in the calling thread, one call at a time, for the newest arguments;
- :class:`NewestWorker` is a thread that runs a function on the newest submitted item, optionally once
  the submissions have been quiet for a while (a slider still being dragged);
- :class:`RecomputeScheduler` numbers every request (its *generation*) and hands it to a preview worker
  and a debounced exact worker; a computation asks :meth:`RecomputeScheduler.is_current` whether a newer
  request has superseded it.

Nothing here knows about viser or clouds; ``tests/test_scheduler.py`` drives it with plain functions.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from typing import Generic, TypeVar

T = TypeVar("T")


class LatestOnly:
    """Calls ``fn`` for the newest arguments only, one call at a time, in the calling thread.

    A call that arrives while ``fn`` runs only replaces the arguments waiting for the next run, which the
    running caller picks up when it finishes; the late caller returns at once.
    """

    def __init__(self, fn: Callable[..., None]):
        self._fn = fn
        self._running = threading.Lock()
        self._swap = threading.Lock()
        self._next: tuple | None = None

    def __call__(self, *args) -> None:
        with self._swap:
            self._next = args
        while True:
            if not self._running.acquire(blocking=False):
                return  # the running call picks our arguments up when it finishes
            try:
                with self._swap:
                    args, self._next = self._next, None
                if args is not None:
                    self._fn(*args)
            finally:
                self._running.release()
            with self._swap:
                if self._next is None:
                    return


class NewestWorker(Generic[T]):
    """A daemon thread that runs ``fn(item)`` on the newest submitted item, one at a time.

    An item submitted while another waits replaces it. With ``quiet_s`` the worker starts only once no item
    has been submitted for that long, or once the first waiting item has waited ``max_delay_s`` (a user who
    never lets go of a slider still gets results). An exception of ``fn`` goes to ``on_error``; the worker
    goes on with the next item.
    """

    def __init__(self, fn: Callable[[T], None], on_error: Callable[[Exception], None], name: str = "newest-worker",
                 quiet_s: float = 0.0, max_delay_s: float = math.inf):
        self._fn = fn
        self._on_error = on_error
        self._quiet_s = quiet_s
        self._max_delay_s = max_delay_s
        self._cond = threading.Condition()
        self._item: T | None = None
        self._waiting = False  # an item is waiting (items may be None)
        self._running = False
        self._stopping = False
        self._last_submit = 0.0  # time.monotonic() of the last submission
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    def submit(self, item: T) -> None:
        """Queue ``item`` in place of any item still waiting."""
        with self._cond:
            self._item, self._waiting = item, True
            self._last_submit = time.monotonic()
            self._cond.notify_all()

    def idle(self) -> bool:
        """Whether no item is waiting or running."""
        with self._cond:
            return not self._waiting and not self._running

    def _loop(self) -> None:
        while True:
            with self._cond:
                while not self._waiting and not self._stopping:
                    self._cond.wait()
                overdue = time.monotonic() + self._max_delay_s
                while not self._stopping:
                    wait = min(self._last_submit + self._quiet_s, overdue) - time.monotonic()
                    if wait <= 0:
                        break
                    self._cond.wait(wait)
                if self._stopping:
                    return
                item, self._item, self._waiting = self._item, None, False
                self._running = True
            try:
                self._fn(item)
            except Exception as exc:  # one bad item must not end the worker
                self._on_error(exc)
            finally:
                with self._cond:
                    self._running = False
                    self._cond.notify_all()

    def stop(self, timeout: float = 10.0) -> bool:
        """Drop any waiting item and end the thread after the running one; whether it ended in ``timeout``."""
        with self._cond:
            self._stopping = True
            self._cond.notify_all()
        self._thread.join(timeout=timeout)
        return not self._thread.is_alive()


class RecomputeScheduler(Generic[T]):
    """Every request gets the next generation and goes to two workers: ``preview(request, generation)`` at
    once and ``exact(request, generation)`` once the requests have been quiet for ``quiet_s`` (at most
    ``max_delay_s`` late). Each worker runs the newest request only; a computation that a newer request
    superseded while it ran can tell with :meth:`is_current` and skip its result."""

    def __init__(self, preview: Callable[[T, int], None], exact: Callable[[T, int], None],
                 on_error: Callable[[Exception], None], quiet_s: float = 0.0, max_delay_s: float = math.inf,
                 name: str = "recompute"):
        self._lock = threading.Lock()  # a request reaches both workers before wait_idle looks at them
        self._generation = 0
        self._previews: NewestWorker[tuple[T, int]] = NewestWorker(
            lambda item: preview(*item), on_error, f"{name}-preview")
        self._exact: NewestWorker[tuple[T, int]] = NewestWorker(
            lambda item: exact(*item), on_error, f"{name}-exact", quiet_s, max_delay_s)

    @property
    def generation(self) -> int:
        """The generation of the newest request (0 before the first)."""
        return self._generation

    def request(self, request: T) -> int:
        """Schedule a preview and an exact recomputation of ``request``; returns its generation."""
        with self._lock:
            self._generation += 1
            generation = self._generation
            self._previews.submit((request, generation))
            self._exact.submit((request, generation))
        return generation

    def is_current(self, generation: int) -> bool:
        """Whether no request newer than ``generation`` has been made."""
        return generation == self._generation

    def idle(self) -> bool:
        """Whether nothing is waiting or running."""
        with self._lock:
            return self._previews.idle() and self._exact.idle()

    def wait_idle(self, timeout: float) -> bool:
        """Block until :meth:`idle` (True) or ``timeout`` seconds have passed (False)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.idle():
                return True
            time.sleep(0.02)
        return False

    def stop(self, timeout: float = 10.0) -> bool:
        """Stop both workers (waiting requests are dropped); whether both ended within ``timeout`` each."""
        exact = self._exact.stop(timeout)
        return self._previews.stop(timeout) and exact
