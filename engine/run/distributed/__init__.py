"""The per-view work of a run as tasks an executor runs: in this process (``LocalExecutor``) or on a Dask cluster
(``engine.run.distributed.dask_executor``). Tasks are pure functions of (scene, view, options, level, pass) that read
their inputs from and write their outputs to the run folder atomically; see docs/distributed.md."""

from engine.run.distributed.executor import Executor, LocalExecutor

__all__ = ["Executor", "LocalExecutor"]
