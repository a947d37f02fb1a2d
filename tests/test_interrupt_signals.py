"""engine.core.interrupt: inside deferred_interrupts a signal only requests a stop, raised at check_interrupt."""

from __future__ import annotations

import os
import signal
import time

import numba
import numpy as np
import pytest

from engine.core.interrupt import check_interrupt, deferred_interrupts


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
