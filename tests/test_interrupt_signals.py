"""engine.core.interrupt: inside deferred_interrupts a signal only requests a stop, raised at check_interrupt."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numba
import numpy as np
import pytest

from engine.core.blocks import FIRST_SHARE, GROWTH, MIN_ROWS, RowPacer
from engine.core.interrupt import EXIT_INTERRUPTED, check_interrupt, deferred_interrupts


@numba.njit(cache=True)
def _busy_tuple(count, n):
    """Spin ``count`` steps, then return a tuple of arrays (boxed by numba's wrapper on return)."""
    s = 0.0
    for i in range(count):
        s += np.sqrt(float(i))
    a = np.full(n, s, np.float32)
    return a, np.arange(n), a.copy(), np.zeros((n, 3), np.uint8)


def _spin_count(seconds: float) -> int:
    """Loop count of :func:`_busy_tuple` that takes about ``seconds`` here."""
    _busy_tuple(10, 2)  # compile or load
    t = time.perf_counter()
    _busy_tuple(2_000_000, 2)
    per = (time.perf_counter() - t) / 2_000_000
    return int(seconds / max(per, 1e-10))


@pytest.fixture(autouse=True)
def _sigint_default():
    """Python's own SIGINT handler for each test: a suite started as a background job (``cmd &``) inherits
    SIGINT ignored, which deferred_interrupts rightly leaves alone (test_ignored_signal_stays_ignored)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def test_signal_waits_for_check_and_handlers_come_back():
    before = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)
    with deferred_interrupts():
        os.kill(os.getpid(), signal.SIGTERM)
        total = sum(range(100_000))  # plenty of bytecode boundaries: nothing is raised here
        with pytest.raises(KeyboardInterrupt):
            check_interrupt()
        check_interrupt()  # a request is honoured once
    assert total == 4999950000
    assert (signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)) == before


def test_request_after_the_last_check_raises_when_the_block_ends():
    before = signal.getsignal(signal.SIGINT)
    with pytest.raises(KeyboardInterrupt), deferred_interrupts():
        os.kill(os.getpid(), signal.SIGINT)
        sum(range(1000))
    assert signal.getsignal(signal.SIGINT) == before
    check_interrupt()  # nothing left pending


def test_ignored_signal_stays_ignored():
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)  # a background job's SIGINT
    try:
        with deferred_interrupts():
            assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN
            os.kill(os.getpid(), signal.SIGINT)
            check_interrupt()
    finally:
        signal.signal(signal.SIGINT, previous)


def test_signal_during_a_numba_kernel_leaves_its_return_value_whole():
    """The defect this module fixes: a handler that raises runs inside numba's wrapper while it boxes the
    kernel's tuple (it calls back into Python), which then holds a NULL: SystemError or SIGSEGV."""
    count = _spin_count(0.4)
    previous = signal.getsignal(signal.SIGALRM)
    try:
        with deferred_interrupts((signal.SIGALRM,)):
            signal.setitimer(signal.ITIMER_REAL, 0.05)  # delivered while the kernel runs
            a, idx, b, c = _busy_tuple(count, 4)
            assert a.shape == (4,) and idx.tolist() == [0, 1, 2, 3] and np.array_equal(a, b) and c.shape == (4, 3)
            with pytest.raises(KeyboardInterrupt):  # the request came during the kernel
                check_interrupt()
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def test_row_pacer_sizes_blocks_to_the_target_and_stops_between_them():
    """Blocks grow from MIN_ROWS to about the target time (at most GROWTH times the previous one); a request that
    comes during a block is honoured when it returns, with every row before it done and none after."""
    per_row = 0.002
    done: list[tuple[int, int]] = []

    def call(start: int, stop: int) -> None:
        done.append((start, stop))
        time.sleep(per_row * (stop - start))

    pacer = RowPacer(target_s=0.04)
    pacer.run("k", 200, 10, call)
    sizes = [b - a for a, b in done]
    assert done[0] == (0, MIN_ROWS) and done[-1][1] == 200
    assert all(b == a2 for (_, b), (a2, _) in zip(done, done[1:], strict=False))  # contiguous, in order
    assert all(s <= GROWTH * p for p, s in zip(sizes, sizes[1:-1], strict=False))
    assert max(sizes[:-1]) <= 0.04 / per_row + 1  # about the target (sleep only overshoots: fewer rows)
    done.clear()
    pacer.run("k", 200, 10, call)  # a later call starts from the measured rate, at a quarter of the target
    assert 1 <= done[0][1] <= 0.04 * FIRST_SHARE / per_row + 1
    done.clear()
    with pytest.raises(KeyboardInterrupt), deferred_interrupts():
        signal.setitimer(signal.ITIMER_REAL, 0.1)
        previous = signal.signal(signal.SIGALRM, signal.getsignal(signal.SIGINT))  # the deferred handler
        try:
            pacer.run("k", 2000, 10, call)
        finally:
            signal.signal(signal.SIGALRM, previous)
    stopped_at = done[-1][1]
    assert 0 < stopped_at < 2000 and done[0][0] == 0
    assert sum(b - a for a, b in done) == stopped_at  # the rows before the stop, each once


SECOND_SIGNAL = r'''
import os, signal, sys, time
from engine.core.interrupt import deferred_interrupts
signal.signal(signal.SIGINT, signal.default_int_handler)
with deferred_interrupts():
    print("ready", flush=True)
    t = time.monotonic()
    while time.monotonic() - t < 30:  # no safe point: only a second signal ends this
        sum(range(1000))
print("not reached", flush=True)
'''


def test_a_second_signal_exits_at_once_with_one_line():
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parent.parent)}
    proc = subprocess.Popen([sys.executable, "-c", SECOND_SIGNAL], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env, start_new_session=True)
    assert proc.stdout.readline().strip() == "ready"
    proc.send_signal(signal.SIGINT)
    time.sleep(0.3)
    assert proc.poll() is None  # the first one only requests a stop
    t = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=10)
    assert time.monotonic() - t < 2.0
    assert proc.returncode == EXIT_INTERRUPTED and "not reached" not in out
    assert err.strip().splitlines() == ["deepc: interrupted again: exiting now (saved PatchMatch passes are kept for "
                                        "--resume)"], err
