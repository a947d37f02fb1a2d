"""The executor seam: "run this pure function on every job of a stage and wait".

``deepc run --executor local`` (the default) never reaches this module: the pipeline keeps its in-process loops.
:class:`LocalExecutor` runs the per-view tasks one after the other in this process (the same tasks a Dask cluster
runs; tests compare the two), ``engine.run.distributed.dask_executor.DaskExecutor`` runs them on a cluster.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from typing import Any

from engine.core.interrupt import check_interrupt

ResultFn = Callable[[int, Any], None]


class Executor:
    """Runs a function on jobs and waits for all of them (interface).

    Attributes:
        workers: how many tasks may run at once.
        threads: numba threads each task uses (0 = numba's default on the machine that runs it).
    """

    workers: int = 1
    threads: int = 0

    def map(self, fn: Callable[[Any], Any], jobs: Sequence[Any], on_result: ResultFn | None = None) -> list[Any]:
        """``[fn(job) for job in jobs]``, in any order; ``on_result(index, result)`` as each one ends (in the
        caller's thread). The first exception of a task is raised here, the other tasks cancelled."""
        raise NotImplementedError

    def describe(self) -> str:
        """One line for the user: where the tasks run."""
        raise NotImplementedError

    def close(self) -> None:
        """Release the workers (idempotent)."""

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class LocalExecutor(Executor):
    """The tasks one after the other in this process (a stop request is honoured between tasks)."""

    def __init__(self, threads: int = 0):
        self.workers, self.threads = 1, threads

    def map(self, fn: Callable[[Any], Any], jobs: Sequence[Any], on_result: ResultFn | None = None) -> list[Any]:
        out = []
        for k, job in enumerate(jobs):
            check_interrupt()
            out.append(fn(job))
            if on_result is not None:
                on_result(k, out[-1])
        return out

    def describe(self) -> str:
        return "tasks in this process"


def threads_per_worker(workers: int, cores: int | None = None) -> int:
    """Numba threads per worker so that workers × threads = the cores of this machine (at least 1)."""
    return max(1, (cores or os.cpu_count() or 1) // max(1, workers))
