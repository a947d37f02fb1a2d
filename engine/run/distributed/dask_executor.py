"""Per-view tasks on a Dask cluster (``deepc run --executor dask``): an existing scheduler (``--scheduler
tcp://host:8786``, workers on any machine that sees the run folder and the scene at the same paths) or a
``LocalCluster`` on this machine.

Each worker runs one task at a time (numba's workqueue layer is not reentrant; the parallelism inside a task is
numba's): a LocalCluster gets ``workers`` single-threaded worker processes with cores / workers numba threads each.
A worker that dies mid-task loses nothing: the scheduler runs the task again on another worker, and the task,
a pure function writing atomically, writes the same bytes (``engine.run.distributed.tasks``). A stage waits on one
``as_completed`` over its futures, so the driver holds one waiter per task whatever the stage lasts.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from typing import Any

from engine.core.errors import DeepCError
from engine.core.interrupt import check_interrupt
from engine.run.distributed.executor import Executor, ResultFn, threads_per_worker

CONNECT_TIMEOUT_S = 10.0  # reaching a scheduler
POLL_S = 0.5  # how often a wait looks at stop requests
WAKE_S = 0.02  # how often it looks for ended tasks


class DaskExecutor(Executor):
    """The tasks on a Dask cluster; see the module docstring.

    Args:
        scheduler: address of a running scheduler (``tcp://host:8786``), or None for a LocalCluster here.
        workers: LocalCluster worker processes (ignored with ``scheduler``).
        threads: numba threads per task (0: cores / workers on a LocalCluster, numba's default with a scheduler).
        stall_timeout: seconds a wait may go without any task ending before the run fails.
    """

    def __init__(self, scheduler: str | None = None, workers: int = 2, threads: int = 0,
                 stall_timeout: float = 3600.0):
        from distributed import Client, LocalCluster  # lazy: dask

        self.scheduler, self.stall_timeout = scheduler, stall_timeout
        self.cluster = None
        if scheduler:
            try:
                self.client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
            except (OSError, TimeoutError) as exc:
                raise DeepCError(f"cannot reach the Dask scheduler at {scheduler} "
                                 f"({' '.join(str(exc).split())[:160]})") from None
            self.workers = max(1, len(self.client.scheduler_info(n_workers=-1).get("workers", {})))
            self.threads = threads
        else:
            self.cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                        dashboard_address=":0", silence_logs=logging.ERROR)
            self.client = Client(self.cluster, timeout=CONNECT_TIMEOUT_S)
            self.workers = workers
            self.threads = threads or threads_per_worker(workers)

    @property
    def dashboard(self) -> str | None:
        """The Dask dashboard's address (None without bokeh)."""
        return self.client.dashboard_link

    def describe(self) -> str:
        where = f"scheduler {self.scheduler}" if self.scheduler else "a LocalCluster on this machine"
        threads = f"{self.threads} numba threads each" if self.threads else "numba's default threads"
        dashboard = f"; dashboard {self.dashboard}" if self.dashboard else ""
        return f"dask: {self.workers} worker(s) on {where}, {threads}{dashboard}"

    def map(self, fn: Callable[[Any], Any], jobs: Sequence[Any], on_result: ResultFn | None = None) -> list[Any]:
        from distributed import as_completed  # lazy: dask

        if not jobs:
            return []
        futures = self.client.map(fn, list(jobs), pure=False)
        index = {f.key: k for k, f in enumerate(futures)}
        out: list[Any] = [None] * len(futures)
        # One waiter per future for the whole stage: ``distributed.wait(..., timeout, FIRST_COMPLETED)`` in a loop
        # leaves a waiter per pending future behind at every timeout (until that future ends): N x seconds / POLL_S
        # of them over a stage, ~2 kB each (hundreds of MB in the driver at 400 views).
        ended = as_completed(futures)
        left = len(futures)
        last = polled = time.monotonic()
        try:
            while left:
                if time.monotonic() - polled > POLL_S:
                    check_interrupt()
                    polled = time.monotonic()
                done = ended.next_batch(block=False)
                if not done:
                    if time.monotonic() - last > self.stall_timeout:
                        raise DeepCError(f"no task ended in {self.stall_timeout:g} s ({left} waiting)")
                    time.sleep(WAKE_S)
                    continue
                last = time.monotonic()
                for future in sorted(done, key=lambda f: index[f.key]):
                    k = index[future.key]
                    out[k] = future.result(timeout=self.stall_timeout)  # raises the task's exception
                    left -= 1
                    if on_result is not None:
                        on_result(k, out[k])
        finally:
            if left:
                self.client.cancel([f for f in futures if not f.done()])
            ended.clear()
        return out

    def close(self) -> None:
        client, cluster = getattr(self, "client", None), self.cluster
        self.cluster = None
        if client is not None:
            client.close(timeout=30)
        if cluster is not None:
            cluster.close(timeout=30)
