"""Running the entries of a suite: an untimed warm-up, then each run exactly as ``deepc run --headless``.

A run's outputs go to ``REPORT/<scene>/<pipeline>/`` as ``deepc run`` writes them. Times are measured
after the warm-up, which compiles the numba kernels (or loads their cache), so compilation never counts.
"""

from __future__ import annotations

import dataclasses
import shutil
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any

from engine.core.errors import DeepCError
from engine.run.folder import RunMetrics
from engine.run.pipeline import run_pipeline
from engine.scene import load_scene
from workbench.regress.calibration import Calibration
from workbench.regress.comparison import FAILED, Delta
from workbench.regress.suite import RunSpec

_WARM_UP_SIZE = 64  # px: quick, and still two pyramid levels, so every kernel (upsampling too) is compiled


@dataclasses.dataclass
class RunResult:
    """A finished run: its metrics, its baseline (if any) and the comparison.

    ``metrics`` is the run's metrics.json dict as written (the format its baseline stores and is compared
    in); :attr:`run` reads it as a typed record.
    """

    spec: RunSpec
    out_dir: Path
    metrics: dict[str, Any]
    baseline: dict[str, Any] | None
    deltas: list[Delta]
    load_average: tuple[float, float]  # 1-minute load average before and after the run
    recording: Path | None
    baseline_reason: str | None = None  # why the baseline was last remade (deepc regress --reason)
    baseline_calibration: Calibration | None = None  # measured when the baseline was made; None before calibrations

    @property
    def failures(self) -> list[Delta]:
        return [d for d in self.deltas if d.status in FAILED]

    @property
    def run(self) -> RunMetrics:
        """The run's metrics, typed."""
        return RunMetrics.from_dict(self.metrics, self.out_dir / "metrics.json")


def prepare_out_dir(out_dir: Path) -> None:
    """A run starts from an empty folder (no stale maps of an earlier run), but only a folder that
    holds a deepc output (or nothing) is ever removed."""
    if out_dir.exists():
        if not out_dir.is_dir() or (any(out_dir.iterdir()) and not (out_dir / "metrics.json").is_file()):
            raise DeepCError("exists and is not the output of an earlier run; not overwriting it", out_dir)


def warm_up(runs: list[RunSpec]) -> float:
    """Run each pipeline once on a small copy of its first scene, untimed, so that numba compilation
    (or loading its cache) is never counted in a run's time. Returns the seconds spent."""
    start = time.perf_counter()
    done: set[str] = set()
    with tempfile.TemporaryDirectory(prefix="deepc-warm-up-") as tmp:
        for spec in runs:
            if spec.pipeline in done:
                continue
            done.add(spec.pipeline)
            size = spec.scene_options.max_image_size
            scene = load_scene(spec.scene_path, spec.scene_options.replace(
                max_image_size=min(size, _WARM_UP_SIZE) if size else _WARM_UP_SIZE))
            options = spec.options.replace(patchmatch=spec.options.patchmatch.replace(iterations=1))
            with warnings.catch_warnings():  # e.g. "too small for 3 levels": true, and beside the point here
                warnings.simplefilter("ignore")
                run_pipeline(scene, Path(tmp) / spec.pipeline, options)
    return time.perf_counter() - start


def execute(spec: RunSpec, out_dir: Path, record: bool) -> tuple[dict[str, Any], Path | None]:
    """Run one suite entry exactly as ``deepc run --headless`` would; returns metrics and the recording."""
    scene = load_scene(spec.scene_path, spec.scene_options)
    if out_dir.exists():
        shutil.rmtree(out_dir)
    recording = None
    if record:
        from workbench.rerun.run_recording import open_run_recording  # lazy: rerun

        recording = open_run_recording(str(out_dir / "recording.rrd"), scene, spec.options, spec.stream_options)
    try:
        result = run_pipeline(scene, out_dir, spec.options, observer=recording.stream if recording else None)
    except BaseException:
        if recording:
            recording.abandon()
        raise
    path = recording.finish() if recording else None
    return result.metrics, path
