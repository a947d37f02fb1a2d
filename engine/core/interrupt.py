"""Cooperative interruption: SIGINT/SIGTERM only *request* a stop, honoured at safe points between kernels.

Why the signal handler must not raise: CPython runs a Python-level signal handler at the next bytecode
boundary of the main thread, and that can be inside Python code that compiled code calls back. numba's
generated wrappers call ``numba.core.serialize._numba_unpickle`` while they box a kernel's return values
and do not check that call for an error: a KeyboardInterrupt raised there leaves a NULL item in the
returned tuple, and unpacking it crashes the interpreter (SIGSEGV in ``tupleiter_next``; seen with the
fusion kernel when a SIGTERM landed during it). An exception raised between two statements of
:func:`engine.io.atomic.atomic_write` can also leave its temporary file behind.

So inside :func:`deferred_interrupts` the handlers only record the signal, and the engine's long loops
call :func:`check_interrupt` after each kernel (every PatchMatch iteration, view, tile, solver
iteration, stage; long PatchMatch kernels and the refinement's similarity graph run as row blocks of a fraction
of a second, ``engine.core.blocks``),
which raises KeyboardInterrupt there. Outside that block, or when no signal came, :func:`check_interrupt` costs
one list test. A second signal while a stop is pending (or under way) ends the process at once: one line on
stderr, exit 130, nothing more written (files are written atomically, so what is on disk is whole: the last
PatchMatch checkpoint stays for ``deepc run --resume``).
"""

from __future__ import annotations

import contextlib
import os
import signal
from collections.abc import Iterable, Iterator

_requested: list[int] = []  # signal numbers received inside deferred_interrupts, not yet honoured
_stopping: list[bool] = []  # not empty once a request was raised inside the current deferred_interrupts block
EXIT_INTERRUPTED = 130
SECOND_SIGNAL_LINE = b"\ndeepc: interrupted again: exiting now (saved PatchMatch passes are kept for --resume)\n"


def check_interrupt() -> None:
    """Raise KeyboardInterrupt if a SIGINT/SIGTERM arrived inside :func:`deferred_interrupts`.

    Call it only where raising leaves nothing half-done (between kernels, between files).
    """
    if _requested:
        _requested.clear()
        _stopping.append(True)
        raise KeyboardInterrupt


def _request(signum: int, frame: object) -> None:  # noqa: ARG001  (signal handler signature)
    if _requested or _stopping:  # the second Ctrl-C: do not wait for the next safe point
        os.write(2, SECOND_SIGNAL_LINE)  # not sys.stderr: the main thread may be inside its write
        os._exit(EXIT_INTERRUPTED)
    _requested.append(signum)


@contextlib.contextmanager
def deferred_interrupts(signals: Iterable[int] = (signal.SIGINT, signal.SIGTERM)) -> Iterator[None]:
    """Within the block, ``signals`` set a flag that :func:`check_interrupt` turns into KeyboardInterrupt (a
    second one exits the process at once, status 130); on leaving, the previous handlers come back and a request
    that no safe point honoured yet raises.

    A signal that is ignored (e.g. SIGINT of a background job) stays ignored. Main thread only.
    """
    previous = {}
    for sig in signals:
        handler = signal.getsignal(sig)
        if handler in (signal.SIG_IGN, None):  # None: set outside Python, leave it alone
            continue
        previous[sig] = handler
        signal.signal(sig, _request)
    _requested.clear()
    _stopping.clear()
    try:
        yield
        check_interrupt()  # a signal after the block's last safe point still stops the command
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        _requested.clear()
        _stopping.clear()
