"""Temperature scaling of benchmarks/paper/confidence_calibration.py: the fitted T undoes a known over-confidence,
a calibrated τ is one raw threshold, and the calibration error says which of two confidences is honest. No
network, no engine run."""

from __future__ import annotations

import numpy as np
import pytest

from support import bench

CAL = bench.load_script(bench.BENCHMARKS / "paper" / "confidence_calibration.py")


def _labelled(n: int = 200_000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Logits z and labels drawn with P(inlier) = σ(z): σ(z) is calibrated."""
    rng = np.random.default_rng(seed)
    z = rng.normal(0.5, 2.0, n)
    labels = (rng.random(n) < 1.0 / (1.0 + np.exp(-z))).astype(np.int64)
    return z, labels


@pytest.mark.parametrize("factor", [0.5, 1.0, 2.5])
def test_the_fitted_temperature_undoes_a_known_scaling_of_the_logits(factor):
    z, labels = _labelled()
    confidence = 1.0 / (1.0 + np.exp(-factor * z))  # over-confident for factor > 1, under- for < 1
    temperature = CAL.fit_temperature(confidence, labels)
    assert temperature == pytest.approx(factor, rel=0.05)
    fixed = CAL.calibrated(confidence, 1.0 / temperature)
    if factor != 1.0:
        assert CAL.expected_calibration_error(fixed, labels) < 0.5 * CAL.expected_calibration_error(confidence,
                                                                                                     labels)
    assert CAL.expected_calibration_error(fixed, labels) < 1.0  # percent


@pytest.mark.parametrize(("temperature", "bias"), [(0.4, 0.0), (1.0, -1.5), (3.0, 0.7)])
def test_a_calibrated_tau_keeps_exactly_the_pixels_above_its_raw_threshold(temperature, bias):
    confidence = np.linspace(0.0005, 0.9995, 20_001).astype(np.float32)
    for tau in (0.05, 0.1, 0.3):
        threshold = CAL.raw_threshold(tau, 1.0 / temperature, bias)
        above = confidence >= threshold
        kept = CAL.calibrated(confidence, 1.0 / temperature, bias) >= tau
        assert np.count_nonzero(above != kept) <= 2  # float32 rounding at the boundary only
    assert CAL.raw_threshold(0.5, 1.0 / temperature) == pytest.approx(0.5)


def test_ranking_puts_the_best_fold_averaged_f1_first_and_names_the_worst_family():
    families = {"a": {"mean": {"f1 vanilla": 80.0, "f1 calibrated@0.1": 79.0, "acc calibrated@0.1": 90.0,
                               "f1 uncalibrated@0.05": 80.5, "acc uncalibrated@0.05": 88.0}},
                "b": {"mean": {"f1 vanilla": 60.0, "f1 calibrated@0.1": 62.0, "acc calibrated@0.1": 80.0,
                               "f1 uncalibrated@0.05": 58.0, "acc uncalibrated@0.05": 79.0}}}
    rows = CAL.ranking(families, ["calibrated@0.1", "uncalibrated@0.05"])
    assert [r["filter"] for r in rows] == ["calibrated@0.1", "uncalibrated@0.05"]
    assert rows[0]["change"] == pytest.approx(0.5) and rows[0]["worst family"] == "a"
    assert rows[1]["worst change"] == pytest.approx(-2.0)


def test_platt_scaling_finds_a_shift_that_a_temperature_cannot():
    """A confidence biased downwards (σ(z - 1.5) where σ(z) is calibrated): Platt's bias recovers the shift and
    calibrates it; a temperature alone leaves most of the error."""
    z, labels = _labelled(seed=2)
    confidence = 1.0 / (1.0 + np.exp(-(z - 1.5)))
    a, b = CAL.fit_platt(confidence, labels)
    assert a == pytest.approx(1.0, abs=0.05) and b == pytest.approx(1.5, abs=0.08)
    platt = CAL.expected_calibration_error(CAL.calibrated(confidence, a, b), labels)
    temperature = CAL.expected_calibration_error(
        CAL.calibrated(confidence, 1.0 / CAL.fit_temperature(confidence, labels)), labels)
    assert platt < 1.0 < temperature
