"""The calibration of ``deepc regress``: a fixed numba workload timed in the same invocation as the suite.

A run's wall-clock and CPU seconds depend on the machine and on what else runs on it, so they are never
compared with a tolerance. Instead the suite times this workload (parallel float32 window statistics, the
kind of loop PatchMatch spends its time in) before, between and after its runs, stores that calibration with the
baselines it writes, and reports each run's time as a ratio to its baseline's, normalised by the two
calibrations: ``(t / c) / (t0 / c0)``. The ratio is information only; speed regressions are caught by the
speed benchmarks (``benchmarks/performance/``; ``speed_ab.py`` runs this tree and another checkout alternately
on one machine), not by CI's wall clock.
"""

from __future__ import annotations

import dataclasses
import statistics
import time
from typing import Any

import numba
import numpy as np

#: name and version of the workload; a calibration made with another one is not comparable
WORKLOAD = "window-moments-v1"
_SIZE = 384  # px: the workload's image is _SIZE x _SIZE
_RADIUS = 5  # 11 x 11 windows, as PatchMatch's default window
_CALLS = 16  # kernel calls a repeat: about 0.25 s of CPU (the default suite's 13 repeats: about 3 s)
REPEATS = 3  # timed repeats before and after the suite (and one after each run)


@dataclasses.dataclass(frozen=True)
class Calibration:
    """Seconds of one repeat of the workload: the median over the timed repeats (wall clock and CPU, all threads)."""

    workload: str
    seconds: float
    cpu_seconds: float
    samples: tuple[tuple[float, float], ...]  # (wall, CPU) seconds of every repeat

    def to_dict(self) -> dict[str, Any]:
        return {"workload": self.workload, "seconds": self.seconds, "cpu_seconds": self.cpu_seconds,
                "samples": [list(s) for s in self.samples]}

    @classmethod
    def from_dict(cls, data: Any) -> Calibration | None:
        """A stored calibration, or None when there is none, it is malformed or it timed another workload."""
        try:
            calibration = cls(str(data["workload"]), float(data["seconds"]), float(data["cpu_seconds"]),
                              tuple((float(w), float(c)) for w, c in data.get("samples", [])))
        except (AttributeError, KeyError, TypeError, ValueError):
            return None
        ok = calibration.workload == WORKLOAD and calibration.seconds > 0 and calibration.cpu_seconds > 0
        return calibration if ok else None

    @classmethod
    def from_samples(cls, samples: list[tuple[float, float]]) -> Calibration:
        return cls(WORKLOAD, statistics.median(s[0] for s in samples), statistics.median(s[1] for s in samples),
                   tuple(samples))

    def merged(self, other: Calibration) -> Calibration:
        """The calibration of both sets of repeats (e.g. before and after a run)."""
        return Calibration.from_samples(list(self.samples) + list(other.samples))

    def describe(self) -> str:
        return f"{self.seconds:.2f} s ({self.cpu_seconds:.2f} s CPU) a repeat of {self.workload}"


@numba.njit(cache=True, parallel=True, fastmath=True)
def _window_moments(image: np.ndarray, radius: int, out: np.ndarray) -> None:
    """Per pixel, the mean and variance of the square roots of its window (a busy, fixed loop)."""
    h, w = image.shape
    for y in numba.prange(radius, h - radius):
        for x in range(radius, w - radius):
            s = np.float32(0.0)
            s2 = np.float32(0.0)
            for dy in range(-radius, radius + 1):
                for dx in range(-radius, radius + 1):
                    v = np.sqrt(image[y + dy, x + dx])
                    s += v
                    s2 += v * v
            n = np.float32((2 * radius + 1) ** 2)
            mean = s / n
            out[y, x] = s2 / n - mean * mean


def _image(size: int) -> np.ndarray:
    return np.random.default_rng(0).random((size, size), dtype=np.float32)


def _one_repeat(image: np.ndarray, out: np.ndarray) -> tuple[float, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    for _ in range(_CALLS):
        _window_moments(image, _RADIUS, out)
    return time.perf_counter() - wall, time.process_time() - cpu


def measure(repeats: int = REPEATS) -> Calibration:
    """Time ``repeats`` repeats of the workload (compiled, or loaded from numba's cache, untimed first)."""
    _window_moments(_image(4 * _RADIUS), _RADIUS, np.zeros((4 * _RADIUS,) * 2, np.float32))
    image = _image(_SIZE)
    out = np.zeros_like(image)
    return Calibration.from_samples([_one_repeat(image, out) for _ in range(max(1, repeats))])


def time_scales(current: Calibration | None, baseline: Calibration | None) -> dict[str, float] | None:
    """Factors that turn a raw time ratio (current / baseline) into a calibrated one, per timing metric
    (``time``: wall clock, ``cpu_time``: CPU seconds); None when either side has no calibration."""
    if current is None or baseline is None:
        return None
    return {"time": baseline.seconds / current.seconds, "cpu_time": baseline.cpu_seconds / current.cpu_seconds}
