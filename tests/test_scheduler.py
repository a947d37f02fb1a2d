"""The viewer's scheduling without a browser or a viser server: newest request wins, superseded requests are
dropped, exact recomputations wait for quiet controls (but not forever), errors do not end a worker."""

from __future__ import annotations

import threading
import time

import pytest

from workbench.viewer.scheduler import LatestOnly, NewestWorker, RecomputeScheduler

TIMEOUT = 10.0  # seconds: every wait in these tests is bounded


@pytest.fixture
def errors():
    """What the workers reported as errors; a test that expects none checks it is empty at the end."""
    return []


def wait_until(predicate, timeout: float = TIMEOUT) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            pytest.fail("timed out")
        time.sleep(0.005)


class Blocking:
    """A function that records its calls and blocks on the first one until released."""

    def __init__(self):
        self.calls: list = []
        self.started = threading.Event()
        self.release = threading.Event()

    def __call__(self, *args) -> None:
        self.calls.append(args)
        self.started.set()
        if len(self.calls) == 1:
            assert self.release.wait(TIMEOUT)


def test_latest_only_runs_the_newest_arguments_after_the_running_call():
    fn = Blocking()
    latest = LatestOnly(fn)
    first = threading.Thread(target=latest, args=(1,))
    first.start()
    assert fn.started.wait(TIMEOUT)
    for value in (2, 3, 4):  # arrive while 1 runs: each returns at once, only the newest is kept
        late = threading.Thread(target=latest, args=(value,))
        late.start()
        late.join(TIMEOUT)
        assert not late.is_alive()
    fn.release.set()
    first.join(TIMEOUT)
    assert not first.is_alive()
    assert fn.calls == [(1,), (4,)]  # the first caller ran the newest arguments before returning
    latest(5)
    assert fn.calls[-1] == (5,)  # idle again: a call runs in the caller's thread


def test_newest_worker_drops_superseded_items(errors):
    fn = Blocking()
    worker = NewestWorker(fn, on_error=errors.append)
    try:
        worker.submit(1)
        assert fn.started.wait(TIMEOUT)
        for item in (2, 3, 4):
            worker.submit(item)
        assert not worker.idle()
        fn.release.set()
        wait_until(worker.idle)
        assert fn.calls == [(1,), (4,)] and errors == []
    finally:
        assert worker.stop(TIMEOUT)


def test_newest_worker_waits_for_quiet_submissions(errors):
    done = []
    worker = NewestWorker(done.append, on_error=errors.append, quiet_s=0.3)
    try:
        for item in range(6):  # a slider being dragged: 6 values 0.05 s apart, never 0.3 s quiet
            worker.submit(item)
            time.sleep(0.05)
        assert done == []
        wait_until(worker.idle)
        assert done == [5] and errors == []  # the value the slider stopped at, once
    finally:
        assert worker.stop(TIMEOUT)


def test_newest_worker_runs_a_request_that_waited_max_delay(errors):
    done = []
    worker = NewestWorker(done.append, on_error=errors.append, quiet_s=60.0, max_delay_s=0.2)
    try:
        start = time.monotonic()
        item = 0
        while not done and time.monotonic() - start < TIMEOUT:  # submissions never pause
            worker.submit(item)
            item += 1
            time.sleep(0.02)
        assert done and time.monotonic() - start < 5.0  # the overdue item ran although it never got quiet
        assert errors == []
    finally:
        assert worker.stop(TIMEOUT)


def test_newest_worker_survives_an_error(errors):
    done = []

    def fn(item: int) -> None:
        if item == 1:
            raise ValueError("bad item")
        done.append(item)

    worker = NewestWorker(fn, on_error=errors.append)
    try:
        worker.submit(1)
        wait_until(lambda: errors)
        worker.submit(2)
        wait_until(lambda: done)
        assert [str(e) for e in errors] == ["bad item"] and done == [2]
    finally:
        assert worker.stop(TIMEOUT)


def test_stop_drops_a_waiting_item_and_ends_the_thread(errors):
    done = []
    worker = NewestWorker(done.append, on_error=errors.append, quiet_s=60.0)
    worker.submit(1)
    assert worker.stop(TIMEOUT)
    assert done == [] and errors == []


def test_scheduler_numbers_requests_and_tells_superseded_computations(errors):
    previews, exacts, superseded = [], [], []
    exact_started, exact_release = threading.Event(), threading.Event()

    def exact(request: str, generation: int) -> None:
        exacts.append((request, generation))
        if request == "a":  # a computation that takes a while: newer requests arrive meanwhile
            exact_started.set()
            assert exact_release.wait(TIMEOUT)
        if not scheduler.is_current(generation):
            superseded.append(request)

    scheduler: RecomputeScheduler[str] = RecomputeScheduler(
        lambda request, generation: previews.append((request, generation)), exact, errors.append, quiet_s=0.05)
    try:
        assert scheduler.generation == 0
        assert scheduler.request("a") == 1
        assert exact_started.wait(TIMEOUT)
        assert scheduler.request("b") == 2 and scheduler.request("c") == 3
        assert not scheduler.idle() and not scheduler.wait_idle(0.1)  # "a" is still being computed
        exact_release.set()
        assert scheduler.wait_idle(TIMEOUT)
        assert superseded == ["a"]  # it learns that its result is stale
        assert exacts == [("a", 1), ("c", 3)]  # "b" was superseded before it started
        assert previews[-1] == ("c", 3) and ("a", 1) in previews
        assert scheduler.is_current(3) and not scheduler.is_current(2)
        assert errors == []
    finally:
        exact_release.set()
        assert scheduler.stop(TIMEOUT)
