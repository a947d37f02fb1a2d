"""``deepc regress``: a suite of scenes × pipelines run headless, compared with baselines.

``suite`` reads and checks the suite file, ``running`` runs its entries as ``deepc run --headless``
would, ``comparison`` compares a run's metrics with its baseline under tolerances (quality both ways; times
as information), ``calibration`` times the fixed workload that times are normalised by, ``baselines`` reads
and rewrites the baseline files, ``environment`` records where the numbers were measured, and
``command`` is the command itself (it writes the HTML report of ``workbench/regress/report/``). The command is
not imported here, so that the report can import the comparison without importing itself.
"""

from workbench.regress.baselines import baseline_path, read_baseline, write_baseline
from workbench.regress.calibration import Calibration, time_scales
from workbench.regress.comparison import (
    BETTER,
    CHANGED,
    DEFAULT_TOLERANCES,
    FAILED,
    INFO,
    METRICS,
    MISSING,
    NEW,
    OK,
    WORSE,
    Delta,
    MetricSpec,
    compare,
    format_table,
    option_changes,
)
from workbench.regress.environment import environment, git_revision
from workbench.regress.running import RunResult, execute, warm_up
from workbench.regress.suite import DEFAULT_SUITE, RunSpec, Suite, entry_flags, load_suite

__all__ = ["BETTER", "CHANGED", "DEFAULT_SUITE", "DEFAULT_TOLERANCES", "FAILED", "INFO", "METRICS", "MISSING", "NEW",
           "OK", "WORSE", "Calibration", "Delta", "MetricSpec", "RunResult", "RunSpec", "Suite", "baseline_path",
           "compare", "entry_flags", "environment", "execute", "format_table", "git_revision", "load_suite",
           "option_changes", "read_baseline", "time_scales", "warm_up", "write_baseline"]
