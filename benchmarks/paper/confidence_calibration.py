"""Calibration of the confidence network on the leave-one-family-out folds, and the default τ by the fold-averaged
fused F1.

    .venv/bin/python benchmarks/paper/confidence_calibration.py [--folds /work/runs/lofo] [--seeds 0]
        [--cache runs/train_cache] [--taus 0.05,0.1,0.2,0.3,0.5] [--family hololens ...]
        [--out benchmarks/results/confidence_calibration.json]

For every fold that benchmarks/paper/confidence_lofo.py trained (``--folds/seed<s>/<family>/weights.pt`` and its
``history.json``; folds not trained yet are left out and ``complete`` says so), the network's output is calibrated on
the fold's validation scenes, the ones that picked its checkpoint, minimising the binary cross-entropy against the GT
inlier labels: by a temperature, c' = σ(logit(c) / T) (Guo et al. 2017, "On Calibration of Modern Neural
Networks"), reported, and by Platt scaling, c' = σ(a · logit(c) + b) (Platt 1999), whose bias can move where the
thresholds fall when a temperature alone cannot, used for the calibrated τ. On the held-out family it reports the
expected calibration error (15 equal bins) of c and of both c', and the fused F1 and accuracy at 2 cm of the maps
filtered at each calibrated τ (c' ≥ τ, i.e. c at least the raw threshold τ maps to) beside vanilla and the
uncalibrated filter at the paper's 0.05 and the shipped default (``ConfidenceOptions().tau``), scored as
support/confidence_scores.py scores them. The fold-averaged F1 (families weighted equally: each family's mean over its
scenes, then over seeds) ranks the candidates for the default τ; the ranking is made on held-out families only.
Per fold the results are kept beside its weights (``calibration.json``) and reused.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from engine.confidence.apply import predict_samples
from engine.confidence.data import load_run
from engine.confidence.options import ConfidenceOptions
from engine.confidence.weights import load_weights
from engine.filtering import filter_by_confidence
from engine.fusion import DEFAULT_PRESET
from engine.io.atomic import atomic_write_text
from support import bench
from support.confidence_scores import fused_row
from workbench.cli.train import recipe_run
from workbench.viewer.session import ViewerSession

LOFO = bench.load_script(bench.BENCHMARKS / "paper" / "confidence_lofo.py")
finite_mean = LOFO.finite_mean

# Top-level keys of this script's result JSON and their types (support/schema.py); the harness adds its own.
SCHEMA = {"recipe": str, "seeds": list, "taus": list, "uncalibrated": list, "preset": str, "folds": dict,
          "families": dict, "ranking": list, "complete": bool}

BINS = 15  # equal-width bins of the expected calibration error
EPS = 1e-6  # confidences are clipped to [EPS, 1 - EPS] before the logit


def logit(c: np.ndarray) -> np.ndarray:
    c = np.clip(np.asarray(c, np.float64), EPS, 1.0 - EPS)
    return np.log(c) - np.log1p(-c)


def nll(z: np.ndarray, labels: np.ndarray, temperature: float) -> float:
    """Mean binary cross-entropy of σ(z / T) against ``labels`` (1 inlier, 0 outlier)."""
    s = z / temperature
    # log σ(s) = -log(1 + e^-s), log(1 - σ(s)) = -log(1 + e^s), both in a stable form
    return float(np.mean(np.where(labels == 1, np.logaddexp(0.0, -s), np.logaddexp(0.0, s))))


def fit_temperature(confidence: np.ndarray, labels: np.ndarray) -> float:
    """The T > 0 minimising :func:`nll` of ``confidence`` ((N,) in [0, 1]) against ``labels`` ((N,) 0/1): a golden
    section search over log T in [-3, 3] (T from 0.05 to 20; the NLL is convex in 1/T)."""
    z = logit(confidence)
    lo, hi = -3.0, 3.0
    ratio = (np.sqrt(5.0) - 1.0) / 2.0
    a, b = hi - ratio * (hi - lo), lo + ratio * (hi - lo)
    fa, fb = nll(z, labels, np.exp(a)), nll(z, labels, np.exp(b))
    for _ in range(60):
        if fa <= fb:
            hi, b, fb = b, a, fa
            a = hi - ratio * (hi - lo)
            fa = nll(z, labels, np.exp(a))
        else:
            lo, a, fa = a, b, fb
            b = lo + ratio * (hi - lo)
            fb = nll(z, labels, np.exp(b))
    return float(np.exp((lo + hi) / 2.0))


def fit_platt(confidence: np.ndarray, labels: np.ndarray, steps: int = 50) -> tuple[float, float]:
    """(a, b) of Platt scaling, c' = σ(a · logit(c) + b), minimising the binary cross-entropy against ``labels``:
    Newton's method on the two parameters (a logistic regression on the logit; Platt 1999). Temperature scaling
    is the case b = 0, a = 1 / T."""
    z = logit(confidence)
    y = np.asarray(labels, np.float64)
    a, b = 1.0, 0.0
    for _ in range(steps):
        p = 1.0 / (1.0 + np.exp(-(a * z + b)))
        r, w = p - y, np.maximum(p * (1.0 - p), 1e-12)
        grad = np.array([np.mean(r * z), np.mean(r)])
        hess = np.array([[np.mean(w * z * z), np.mean(w * z)], [np.mean(w * z), np.mean(w)]])
        step = np.linalg.solve(hess + 1e-9 * np.eye(2), grad)
        a, b = a - step[0], b - step[1]
        if np.abs(step).max() < 1e-8:
            break
    return float(a), float(b)


def calibrated(confidence: np.ndarray, scale: float, bias: float = 0.0) -> np.ndarray:
    """σ(scale · logit(c) + bias), float32, the shape of ``confidence`` (temperature T: ``scale`` 1 / T)."""
    return (1.0 / (1.0 + np.exp(-(scale * logit(confidence) + bias)))).astype(np.float32)


def raw_threshold(tau: float, scale: float, bias: float = 0.0) -> float:
    """The uncalibrated confidence c with σ(scale · logit(c) + bias) = τ: the calibrated c' ≥ τ exactly where c ≥
    it (``scale`` > 0)."""
    return float(1.0 / (1.0 + np.exp(-(logit(np.float64(tau)) - bias) / scale)))


def expected_calibration_error(confidence: np.ndarray, labels: np.ndarray, bins: int = BINS) -> float:
    """Σ over equal-width confidence bins of (share of pixels) × |inlier rate − mean confidence|, in percent."""
    edges = np.minimum((np.asarray(confidence, np.float64) * bins).astype(np.int64), bins - 1)
    total, error = len(labels), 0.0
    for b in range(bins):
        inside = edges == b
        n = int(inside.sum())
        if n:
            error += n / total * abs(float(labels[inside].mean()) - float(confidence[inside].mean()))
    return 100.0 * error


def pooled(samples: list, confidence: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(confidence, label) of every labelled pixel of ``samples``, pooled."""
    return (np.concatenate([c[s.labels >= 0] for s, c in zip(samples, confidence, strict=True)]),
            np.concatenate([s.labels[s.labels >= 0] for s in samples]).astype(np.int64))


def _md5(path: Path) -> str:
    return hashlib.md5(path.read_bytes()).hexdigest()


def calibrate_fold(fold, cache: Path, folder: Path, taus: Sequence[float], uncalibrated: Sequence[float],
                   preset: str, label: str) -> dict | None:
    """Fit T on the fold's validation scenes and score its held-out family; None when the fold is not trained."""
    weights, history_path = folder / "weights.pt", folder / "history.json"
    if not weights.is_file() or not history_path.is_file():
        return None
    history = json.loads(history_path.read_text())
    if history["identity"]["scenes"] != fold.names():
        raise SystemExit(f"{label}: {history_path} was trained on other scenes than this fold's")
    identity = {"weights_md5": _md5(weights), "taus": list(taus), "uncalibrated": list(uncalibrated),
                "preset": preset}
    saved_path = folder / "calibration.json"
    if saved_path.is_file():
        saved = json.loads(saved_path.read_text())
        if saved.get("identity") == identity:
            print(f"{label} reusing {saved_path}", flush=True)
            return saved["result"]
    model = load_weights(weights)
    options = ConfidenceOptions(zero_backfacing=False)  # the pipeline's default rule (confidence_lofo's headline)
    parts = []
    for entry in fold.validation:
        samples = load_run(recipe_run(entry, cache))
        parts.append(pooled(samples, predict_samples(model, samples, options)))
    c_val, y_val = np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
    temperature = fit_temperature(c_val, y_val)
    scale, bias = fit_platt(c_val, y_val)
    z_val = logit(c_val)
    result = {"temperature": temperature, "platt": [scale, bias], "best_epoch": history["best"]["epoch"],
              "validation": {"scenes": [e.run_name for e in fold.validation], "pixels": int(len(y_val)),
                             "nll": nll(z_val, y_val, 1.0), "nll_temperature": nll(z_val, y_val, temperature),
                             "nll_platt": nll(scale * z_val + bias, y_val, 1.0),
                             "ece": expected_calibration_error(c_val, y_val),
                             "ece_temperature": expected_calibration_error(calibrated(c_val, 1.0 / temperature),
                                                                           y_val),
                             "ece_calibrated": expected_calibration_error(calibrated(c_val, scale, bias), y_val)},
              "raw_thresholds": {str(t): raw_threshold(t, scale, bias) for t in taus}, "scenes": {}}
    v = result["validation"]
    print(f"{label} on {', '.join(v['scenes'])}: T = {temperature:.3f} (ECE {v['ece']:.2f} -> "
          f"{v['ece_temperature']:.2f} %), Platt a = {scale:.3f}, b = {bias:.3f} (ECE -> {v['ece_calibrated']:.2f} %)",
          flush=True)
    for entry in fold.test:
        t = time.perf_counter()
        run = recipe_run(entry, cache)
        samples = load_run(run)
        raw = predict_samples(model, samples, options)
        c, y = pooled(samples, raw)
        row = {"ece": expected_calibration_error(c, y), "ece_calibrated":
               expected_calibration_error(calibrated(c, scale, bias), y),
               "ece_temperature": expected_calibration_error(calibrated(c, 1.0 / temperature), y),
               "inlier_pct": 100.0 * float(y.mean())}
        session = ViewerSession.open(run)
        if session.scene.has_gt_points:
            data = session.data
            row["vanilla"] = fused_row(session, [d.depth for d in data], [d.normal for d in data], preset)
            thresholds = {f"calibrated@{t}": raw_threshold(t, scale, bias) for t in taus}
            thresholds |= {f"uncalibrated@{t}": float(t) for t in uncalibrated}
            for name, threshold in thresholds.items():
                kept = [filter_by_confidence(d.depth, d.normal, conf, threshold)
                        for d, conf in zip(data, raw, strict=True)]
                row[name] = fused_row(session, [k[0] for k in kept], [k[1] for k in kept], preset)
        result["scenes"][entry.run_name] = row
        f1 = (f", F1@2cm vanilla {row['vanilla']['f1@0.02']:.2f}, "
              + ", ".join(f"{k} {v['f1@0.02']:.2f}" for k, v in row.items() if k.startswith(("calibrated@",
                                                                                             "uncalibrated@")))
              if "vanilla" in row else "")
        print(f"{label} {entry.run_name}: ECE {row['ece']:.2f} -> {row['ece_calibrated']:.2f} %{f1} "
              f"({time.perf_counter() - t:.0f} s)", flush=True)
    atomic_write_text(saved_path, json.dumps({"identity": identity, "result": result}, default=float))
    return result


def candidates(taus: Sequence[float], uncalibrated: Sequence[float]) -> list[str]:
    return [f"calibrated@{t}" for t in taus] + [f"uncalibrated@{t}" for t in uncalibrated]


def family_table(folds: dict, names: list[str]) -> dict:
    """Per family: mean over its scenes, then over the seeds done, of T, the ECE before and after, and the fused
    F1 / accuracy at 2 cm of vanilla and of each candidate filter (None where the family has no fusion rows)."""
    table = {}
    for family, seeds in folds.items():
        per_seed = []
        for done in seeds.values():
            rows = list(done["scenes"].values())
            m = {"temperature": done["temperature"], "platt_a": done["platt"][0], "platt_b": done["platt"][1],
                 **{key: finite_mean(r[key] for r in rows) for key in ("ece", "ece_temperature", "ece_calibrated")}}
            for name in ["vanilla", *names]:
                m[f"f1 {name}"] = finite_mean(r[name]["f1@0.02"] for r in rows if name in r)
                m[f"acc {name}"] = finite_mean(r[name]["accuracy@0.02"] for r in rows if name in r)
            per_seed.append(m)
        if per_seed:
            table[family] = {"seeds_done": len(per_seed),
                             "mean": {k: finite_mean(s[k] for s in per_seed) for k in per_seed[0]}}
    return table


def ranking(families: dict, names: list[str]) -> list[dict]:
    """The candidates by fold-averaged fused F1 at 2 cm (families with fusion rows weighted equally), best first,
    with the change against vanilla and the worst family's change."""
    rows = []
    for name in names:
        deltas = {f: e["mean"][f"f1 {name}"] - e["mean"]["f1 vanilla"] for f, e in families.items()
                  if e["mean"].get(f"f1 {name}") is not None and e["mean"].get("f1 vanilla") is not None}
        if not deltas:
            continue
        worst = min(deltas, key=deltas.get)
        rows.append({"filter": name, "F1": finite_mean(families[f]["mean"][f"f1 {name}"] for f in deltas),
                     "F1 vanilla": finite_mean(families[f]["mean"]["f1 vanilla"] for f in deltas),
                     "change": finite_mean(deltas.values()), "worst family": worst, "worst change": deltas[worst],
                     "accuracy": finite_mean(families[f]["mean"][f"acc {name}"] for f in deltas),
                     "families": len(deltas)})
    return sorted(rows, key=lambda r: -r["F1"])


def summary(result: dict) -> list[dict]:
    """Per held-out family: the fitted temperature and Platt parameters, ECE before and after each, fused F1 at
    2 cm of vanilla, of the uncalibrated filters and of each calibrated τ."""
    names = candidates(result["taus"], result["uncalibrated"])
    rows = []
    for family, entry in result["families"].items():
        m = entry["mean"]
        rows.append({"family": family, "seeds": entry["seeds_done"], "T": m["temperature"], "a": m["platt_a"],
                     "b": m["platt_b"], "ECE": m["ece"], "ECE T": m["ece_temperature"],
                     "ECE Platt": m["ece_calibrated"], "F1 vanilla": m["f1 vanilla"],
                     **{f"F1 {n.replace('calibrated@', 'cal ').replace('uncal ', 'raw ')}": m[f"f1 {n}"]
                        for n in names}})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    LOFO.add_fold_arguments(parser, "the folds confidence_lofo.py trained (outside the repository)")
    parser.add_argument("--taus", default="0.05,0.1,0.2,0.3,0.5", help="calibrated thresholds to try")
    parser.add_argument("--out", type=Path, default=bench.results_path(__file__))
    args = parser.parse_args()
    recipe, folds = LOFO.chosen_folds(parser, args)
    taus = [float(t) for t in args.taus.split(",") if t]
    uncalibrated = sorted({0.05, ConfidenceOptions().tau})  # the paper's and the shipped default
    names = candidates(taus, uncalibrated)
    done: dict = {f: {} for f in folds}
    for seed in args.seeds:
        for family, fold in folds.items():
            result = calibrate_fold(fold, args.cache, args.folds / f"seed{seed}" / family, taus, uncalibrated,
                                    DEFAULT_PRESET, f"[{family} seed {seed}]")
            if result is not None:
                done[family][str(seed)] = result
    families = family_table({f: s for f, s in done.items() if s}, names)
    record = {"recipe": bench.scrub(str(args.recipe)), "seeds": args.seeds, "taus": taus,
              "uncalibrated": uncalibrated, "preset": DEFAULT_PRESET, "folds": done, "families": families,
              "ranking": ranking(families, names),
              "complete": all(len(s) == len(args.seeds) for s in done.values())}
    bench.print_table(summary(record), title="per held-out family (mean over its scenes, then over seeds)")
    bench.print_table(record["ranking"], title="default τ candidates by fold-averaged F1 at 2 cm")
    bench.write_result(record, args.out)
    print(f"\nwrote {args.out}")


if __name__ == "__main__":
    np.seterr(invalid="ignore")
    main()
