"""deepc regress: suite files, comparison with baselines, exit codes, and the HTML report in a browser."""

from __future__ import annotations

import contextlib
import io
import json
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO, SAMPLES, make_fake_run
from PIL import Image

from engine.evaluation.depth import roc_curve
from workbench.cli.main import main
from workbench.regress import (
    BETTER,
    CHANGED,
    DEFAULT_SUITE,
    INFO,
    MISSING,
    NEW,
    OK,
    WORSE,
    Calibration,
    RunResult,
    RunSpec,
    Suite,
    baseline_path,
    compare,
    load_suite,
)

# Quick but real: ACMM's 3/2/2 schedule on the tiny scene at 96x72, two pyramid levels (about 7 s of CPU;
# one iteration per pass instead costs F1 at 5 cm and depth within 1 % about 2 points each). Times vary with
# the load of the machine running the tests, so they are reported but not compared here.
TEST_SUITE = """
baseline = "baselines"
thumbnail_views = 2
[defaults]
schedule = "acmm"
levels = 2
seed = 3
max-image-size = 96
[tolerances]
time = false
cpu_time = false
[[scene]]
path = "{tiny}"
[[pipeline]]
name = "vanilla"
{extra}
"""


def deepc(*args) -> tuple[int, str, str]:
    """``deepc ARGS`` in this process: (exit status, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in args])
    return code, out.getvalue(), err.getvalue()


def write_suite(folder: Path, extra: str = "", text: str | None = None) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "suite.toml"
    path.write_text(text if text is not None else TEST_SUITE.format(tiny=SAMPLES / "tiny", extra=extra))
    return path


# ---- ROC and comparison (no runs) ----------------------------------------------------------------------

def test_roc_area_is_the_probability_that_an_inlier_outranks_an_outlier():
    rng = np.random.default_rng(0)
    labels = rng.integers(-1, 2, 400)
    scores = rng.integers(0, 6, 400).astype(np.float32) + (labels == 1) * 2.5  # ties and a real signal
    fpr, tpr, auc = roc_curve(scores, labels)
    pos, neg = scores[labels == 1][:, None], scores[labels == 0][None, :]
    expected = (pos > neg).mean() + 0.5 * (pos == neg).mean()
    assert auc == pytest.approx(expected, abs=1e-12)
    assert 0.7 < auc < 1.0
    assert (fpr[0], tpr[0], fpr[-1], tpr[-1]) == (0, 0, 1, 1) and np.all(np.diff(fpr) >= 0)
    assert roc_curve(-scores, labels)[2] == pytest.approx(1 - expected, abs=1e-12)
    assert np.isnan(roc_curve(scores, np.ones_like(labels))[2])  # no outliers: undefined


def _metrics(f1=50.0, within=80.0, abs_rel=0.02, seconds=10.0, auc=None, tolerances=(0.02, 0.05)):
    m = {"eval": {"tolerances": list(tolerances), "f1": [f1] * len(tolerances), "accuracy": [90.0] * len(tolerances),
                  "completeness": [40.0] * len(tolerances)},
         "depth": {"within_1pct": within, "within_5pct": 90.0, "abs_rel": abs_rel, "valid_fraction": 100.0},
         "seconds": {"total": seconds}, "seconds_cpu": seconds}
    if auc is not None:
        m["confidence_auc"] = auc
    return m


def _status(deltas, label):
    return next(d.status for d in deltas if d.label == label)


def _delta(deltas, label):
    return next(d for d in deltas if d.label == label)


def test_compare_fails_a_change_beyond_tolerance_either_way_and_names_its_direction():
    tol = {"f1": 0.5, "accuracy": 0.5, "completeness": 0.5, "within_1pct": 0.5, "abs_rel": 0.001, "auc": 0.5,
           "time": 0.5, "cpu_time": None, "within_5pct": None, "valid_fraction": None}
    base = _metrics(auc=95.0)
    deltas = compare("s/p", _metrics(f1=49.6, within=79.4, abs_rel=0.0215, seconds=16.0, auc=95.6), base, tol)
    assert _status(deltas, "f1@0.02") == OK  # -0.4 is within 0.5
    assert _delta(deltas, "within_1pct").direction == WORSE  # -0.6
    assert _delta(deltas, "abs_rel").direction == WORSE  # lower is better: +0.0015 > 0.001
    assert _status(deltas, "auc") == CHANGED and _delta(deltas, "auc").direction == BETTER  # +0.6: fails too
    assert all(d.status == CHANGED for d in deltas if d.direction)
    assert _status(deltas, "cpu_time") == INFO and _status(deltas, "within_5pct") == INFO
    time = _delta(deltas, "time")  # 60 % slower: information, noted as slower, never a failure
    assert time.status == INFO and time.ratio == pytest.approx(1.6) and not time.calibrated and time.slower
    better = compare("s/p", _metrics(f1=55.0, abs_rel=0.015, seconds=4.0), base, tol)
    assert {_delta(better, label).direction for label in ("f1@0.02", "f1@0.05", "abs_rel")} == {BETTER}
    assert _status(better, "time") == INFO and not _delta(better, "time").slower
    assert _status(better, "auc") == MISSING  # the baseline had a confidence AUC, this run has none
    no_eval = {k: v for k, v in _metrics().items() if k != "eval"}
    assert _status(compare("s/p", no_eval, base, tol), "f1@0.02") == MISSING
    assert _status(compare("s/p", base, None, tol), "f1@0.02") == NEW
    explained = [d.explain() for d in deltas + better if d.status == CHANGED]
    assert "s/p within_1pct 80.00 -> 79.40 (-0.60, tolerance ±0.5): worse by -0.60" in explained
    assert "s/p f1@0.02 50.00 -> 55.00 (+5.00, tolerance ±0.5): better by +5.00" in explained


def test_times_are_ratios_normalised_by_the_calibrations():
    """A machine twice as slow (its calibration takes twice as long) running the same code twice as slowly: 1.00×."""
    from workbench.regress import time_scales
    from workbench.regress.comparison import describe_time

    baseline_cal = Calibration.from_samples([(0.30, 0.60), (0.32, 0.62), (0.31, 0.61)])
    current_cal = Calibration.from_samples([(0.62, 1.22)])
    assert baseline_cal.seconds == 0.31 and Calibration.from_dict(baseline_cal.to_dict()) == baseline_cal
    assert Calibration.from_dict({**baseline_cal.to_dict(), "workload": "another"}) is None
    assert Calibration.from_dict(None) is None and time_scales(current_cal, None) is None
    tol = {"time": 0.5, "cpu_time": 0.5}
    deltas = compare("s/p", _metrics(seconds=20.0), _metrics(seconds=10.0), tol, time_scales(current_cal, baseline_cal))
    time, cpu = _delta(deltas, "time"), _delta(deltas, "cpu_time")
    assert time.ratio == pytest.approx(1.0) and cpu.ratio == pytest.approx(1.0) and time.calibrated
    assert describe_time(time) == "1.00× the baseline after calibration"
    assert describe_time(_delta(compare("s/p", _metrics(seconds=20.0), _metrics(seconds=10.0), tol), "time")) == (
        "2.00× the baseline (uncalibrated)")


# ---- suite files ---------------------------------------------------------------------------------------------

def _one_line_error(result, *fragments):
    code, out, err = result
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2, (out, err)
    assert len(lines) == 1 and lines[0].startswith("deepc: error: "), err
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


@pytest.mark.parametrize(("text", "fragments"), [
    ("[[scene]\npath = 'tiny'\n", ("not valid TOML", "line 1")),
    ("colour = 'red'\n[[scene]]\npath = '{tiny}'\n", ("unknown key 'colour'",)),
    ("[[scene]]\npath = '{tiny}'\n[[pipeline]]\niteratons = 2\n", ("[[pipeline]]", "unknown key 'iteratons'")),
    ("[[scene]]\npath = 'no/such/scene'\n", ("[[scene]] #1", "no/such/scene", "not a COLMAP workspace")),
    ("[tolerances]\nf1 = -1\n[[scene]]\npath = '{tiny}'\n", ("tolerance f1 = -1",)),
    ("[tolerances]\nf2 = 1\n[[scene]]\npath = '{tiny}'\n", ("unknown metric 'f2'",)),
    ("[[scene]]\npath = '{tiny}'\n[[pipeline]]\nschedule = 'fastest'\n", ("--schedule", "invalid choice")),
    ("[[scene]]\npath = '{tiny}'\n[[pipeline]]\niterations = 0\n", ("run tiny/vanilla", "iterations")),
    ("[[scene]]\npath = '{tiny}'\n[[scene]]\npath = '{tiny}'\n", ("used twice",)),
    ("[defaults]\n", ("no scenes",)),
])
def test_bad_suite_files_give_one_line_naming_the_file(tmp_path, text, fragments):
    suite = write_suite(tmp_path, text=text.format(tiny=SAMPLES / "tiny"))
    _one_line_error(deepc("regress", "--suite", suite, "--report", tmp_path / "r"), str(suite), *fragments)
    assert not (tmp_path / "r").exists()  # nothing ran, nothing was written


def test_a_reason_without_update_baseline_is_refused(tmp_path):
    code, out, err = deepc("regress", "--suite", write_suite(tmp_path / "s"), "--reason", "why")
    assert code == 2 and "--reason" in err and "--update-baseline" in err and not out


def test_missing_suite_bad_baseline_and_foreign_report_folders_are_refused(tmp_path):
    _one_line_error(deepc("regress", "--suite", tmp_path / "none.toml"), "none.toml", "no such suite file")
    suite = write_suite(tmp_path / "s")
    broken = tmp_path / "s" / "baselines" / "tiny" / "vanilla.json"
    broken.parent.mkdir(parents=True)
    broken.write_text("{not json")
    _one_line_error(deepc("regress", "--suite", suite, "--report", tmp_path / "r"), str(broken), "malformed baseline")
    broken.unlink()
    precious = tmp_path / "r" / "tiny" / "vanilla" / "notes.txt"
    precious.parent.mkdir(parents=True)
    precious.write_text("mine")
    _one_line_error(deepc("regress", "--suite", suite, "--report", tmp_path / "r"), "not the output of an earlier run")
    assert precious.read_text() == "mine"


def test_suite_entries_merge_flags_and_tolerances(tmp_path):
    text = f"""
name = "mine"
[defaults]
schedule = "acmm"
seed = 1
[tolerances]
f1 = 1.0
[[scene]]
path = "{SAMPLES / 'tiny'}"
max-image-size = 96
tolerances = {{ within_1pct = 2.0 }}
[[scene]]
path = "{SAMPLES / 'small'}"
name = "small2"
[[pipeline]]
name = "a"
seed = 7
plane-propagation = false
set = ["patchmatch.tau0=0.7", "fusion.min_num_pixels=2"]
[[pipeline]]
name = "b"
scenes = ["tiny"]
tolerances = {{ f1 = false }}
"""
    suite = load_suite(write_suite(tmp_path, text=text))
    assert [r.key for r in suite.runs] == ["tiny/a", "small2/a", "tiny/b"]
    a = suite.runs[0]
    assert (a.options.patchmatch.seed, a.options.patchmatch.schedule, a.options.patchmatch.tau0) == (7, "acmm", 0.7)
    assert a.options.patchmatch.plane_propagation is False and a.options.fusion.min_num_pixels == 2
    # no max-image-size: the default working size, resolved when the scene is read (0 for these small scenes)
    assert a.scene_options.max_image_size == 96 and suite.runs[1].scene_options.max_image_size is None
    assert (a.tolerances["f1"], a.tolerances["within_1pct"], a.tolerances["time"]) == (1.0, 2.0, 0.5)
    assert suite.runs[1].tolerances["within_1pct"] == 0.5
    assert suite.runs[2].tolerances["f1"] is None and suite.runs[2].options.patchmatch.seed == 1
    assert suite.baseline_dir == (tmp_path / "baselines").resolve() and suite.name == "mine"


def test_the_default_suite_has_a_current_baseline_for_every_run():
    """Editing sample_scenes/suite.toml without remaking tests/baselines would make CI compare apples and pears."""
    suite = load_suite(DEFAULT_SUITE)
    assert [r.key for r in suite.runs] == ["tiny/vanilla", "small/vanilla", "fountain_p11/vanilla", "tiny/fast",
                                           "fountain_p11/fast", "tiny/full", "tiny/vanilla-paper"]
    assert suite.baseline_dir == REPO / "tests" / "baselines"
    for spec in suite.runs:
        stored = json.loads(baseline_path(suite.baseline_dir, spec).read_text())
        assert stored["flags"] == spec.flags, spec.key
        assert stored["metrics"]["options"]["patchmatch"] == spec.options.patchmatch.to_dict(), spec.key
        assert stored["metrics"]["eval"]["f1"] and stored["metrics"]["depth"]["within_1pct"] > 50


# ---- the command on fake runs (no PatchMatch): two-sided quality, times as information -------------------

FAKE_SUITE = """
baseline = "baselines"
thumbnail_views = 1
[[scene]]
path = "{tiny}"
[[pipeline]]
name = "vanilla"
"""


class FakeRuns:
    """``deepc regress`` without PatchMatch: every run is support/fake_run.py's folder made from GT depth with the
    metrics of :func:`_metrics` (F1 ``f1``, times ``seconds`` wall and CPU), no warm-up, and a calibration of
    ``calibration`` seconds a pass (wall and CPU)."""

    def __init__(self):
        self.f1, self.seconds, self.calibration, self.cpu = 50.0, 10.0, 0.3, 0.0

    def execute(self, spec, out_dir, record):
        make_fake_run(spec.scene_path, out_dir, scene_options=spec.scene_options)
        metrics = json.loads((out_dir / "metrics.json").read_text())
        self.cpu += self.seconds  # the command measures CPU seconds around execute
        return {**metrics, **_metrics(f1=self.f1, seconds=self.seconds)}, None

    def process_time(self) -> float:
        return self.cpu

    def measure(self, repeats: int = 3) -> Calibration:
        return Calibration.from_samples([(self.calibration, self.calibration)] * repeats)


@pytest.fixture
def fake_runs(monkeypatch, tmp_path):
    """(FakeRuns, deepc regress with the fake suite and its baselines in tmp_path: ARGS -> (code, out, err))."""
    import types

    import workbench.regress.command as command

    fake = FakeRuns()
    monkeypatch.setattr(command, "execute", fake.execute)
    monkeypatch.setattr(command, "warm_up", lambda runs: 0.0)
    monkeypatch.setattr(command, "measure", fake.measure)
    monkeypatch.setattr(command, "time", types.SimpleNamespace(process_time=fake.process_time))
    suite = write_suite(tmp_path / "suite", text=FAKE_SUITE.format(tiny=SAMPLES / "tiny"))
    reports = iter(range(100))

    def regress(*args):
        return deepc("regress", "--suite", suite, "--report", tmp_path / f"report{next(reports)}", *args)
    return fake, regress


def test_an_f1_gain_of_5_fails_as_changed_until_the_baselines_are_remade_with_a_reason(fake_runs, tmp_path):
    fake, regress = fake_runs
    code, out, err = regress("--update-baseline", "--reason", "first baseline")
    assert code == 0 and "tiny/vanilla: new baseline" in out, out + err
    stored = json.loads((tmp_path / "suite" / "baselines" / "tiny" / "vanilla.json").read_text())
    assert stored["calibration"]["seconds"] == 0.3 and stored["reason"] == "first baseline"
    code, out, err = regress()
    assert code == 0 and "nothing changed (1 runs" in out, out + err
    assert "baselines remade on purpose: first baseline" in out  # why the baseline is what it is

    fake.f1 = 55.0  # a bug that inflates F1 by 5 points
    code, out, err = regress()
    assert code == 1, out + err
    changed = [line for line in out.splitlines() if line.startswith("changed: tiny/vanilla ")]
    assert "changed: tiny/vanilla f1@0.02 50.00 -> 55.00 (+5.00, tolerance ±0.5): better by +5.00" in changed
    assert len(changed) == 2  # f1 at both evaluation tolerances; nothing else moved
    assert re.search(r"tiny/vanilla\s+f1@0.02\s+50.00\s+55.00\s+\+5.00\s+±0.5\s+CHANGED \(better\)", out), out
    assert out.splitlines()[-1].startswith("CHANGED: 2 metric(s) beyond tolerance (2 better, 0 worse)")
    assert "--update-baseline --reason" in out.splitlines()[-1]
    report = tmp_path / "report2"
    html = (report / "report.html").read_text()
    assert "CHANGED: tiny/vanilla f1@0.02 50.00 -&gt; 55.00" in html and "better by +5.00" in html
    assert "CHANGED (better)" in html
    summary = json.loads((report / "summary.json").read_text())
    f1 = next(d for d in summary["runs"][0]["deltas"] if d["label"] == "f1@0.02")
    assert (f1["status"], f1["direction"]) == (CHANGED, BETTER)

    code, out, err = regress("--update-baseline", "--reason", "F1 +5 on purpose")
    assert code == 0 and "reason: F1 +5 on purpose" in out and "f1@0.02 50.00 -> 55.00 (+5.00)" in out, out + err
    code, out, err = regress()
    assert code == 0 and "nothing changed" in out, out + err
    assert "baselines remade on purpose: F1 +5 on purpose (" in out
    assert "Baseline remade on purpose: F1 +5 on purpose" in (tmp_path / "report4" / "report.html").read_text()


def test_a_run_5_times_slower_passes_and_reports_its_calibrated_ratio(fake_runs, tmp_path):
    fake, regress = fake_runs
    assert regress("--update-baseline")[0] == 0
    fake.seconds = 50.0  # five times the wall clock and the CPU seconds of the baseline's run
    code, out, err = regress()
    assert code == 0 and "nothing changed" in out, out + err
    assert ("tiny/vanilla  time 5.00× the baseline after calibration, CPU time 5.00× the baseline after "
            "calibration") in out
    assert re.search(r"tiny/vanilla\s+time\s+10.0 s\s+50.0 s\s+5.00× calibrated\s+note > 1.5×\s+info: slower", out)
    assert "speed regressions are caught by benchmarks/performance/" in out
    summary = json.loads((tmp_path / "report1" / "summary.json").read_text())
    times = {d["metric"]: d for d in summary["runs"][0]["deltas"] if d["metric"] in ("time", "cpu_time")}
    assert {d["status"] for d in times.values()} == {INFO} and all(d["calibrated"] for d in times.values())
    assert "5.00× the baseline after calibration" in (tmp_path / "report1" / "report.html").read_text()

    fake.calibration = 1.5  # the machine is five times as slow (busy): the same code reads 1.00×
    code, out, err = regress()
    assert code == 0 and "time 1.00× the baseline after calibration" in out, out + err

    baseline = tmp_path / "suite" / "baselines" / "tiny" / "vanilla.json"  # made before calibrations existed
    stored = json.loads(baseline.read_text())
    del stored["calibration"]
    baseline.write_text(json.dumps(stored))
    code, out, err = regress()
    assert code == 0 and "time 5.00× the baseline (uncalibrated)" in out and "has no calibration" in out, out + err


# ---- real runs on the tiny scene --------------------------------------------------------------------------

@pytest.fixture(scope="module")
def regress_runs(tmp_path_factory):
    """Make a baseline, rerun cleanly, rerun with one PatchMatch iteration, then accept that on purpose; all with
    fake secrets in the environment (reports, baselines and recordings must not carry them)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("AWS_SECRET_ACCESS_KEY", SECRET)
        mp.setenv("GITHUB_TOKEN", SECRET + "-gh")
        return _regress_runs(tmp_path_factory)


SECRET = "deepc-fake-secret-Rg42pV"


def _regress_runs(tmp_path_factory) -> dict:
    root = tmp_path_factory.mktemp("regress")
    clean = write_suite(root / "suite")
    degraded = write_suite(root / "degraded", extra="iterations = 1")
    baselines = root / "baselines"
    common = ("--baseline", baselines)
    runs = {"make": deepc("regress", "--suite", clean, "--report", root / "make", "--update-baseline", *common)}
    runs["baseline_file"] = json.loads((baselines / "tiny" / "vanilla.json").read_text())
    runs["clean"] = deepc("regress", "--suite", clean, "--report", root / "clean", *common)
    runs["degraded"] = deepc("regress", "--suite", degraded, "--report", root / "degraded_report", *common)
    runs["accept"] = deepc("regress", "--suite", degraded, "--report", root / "accept", "--update-baseline", "--record",
                           "--reason", "one iteration per pass, on purpose", *common)
    runs["accepted_file"] = json.loads((baselines / "tiny" / "vanilla.json").read_text())
    runs["root"] = root
    return runs


@pytest.mark.slow
@pytest.mark.timeout(1200)  # incl. the module fixture's runs, on a busy machine
def test_reports_baselines_and_recordings_hold_no_secret(regress_runs):
    files = [p for p in regress_runs["root"].rglob("*") if p.is_file()]
    assert {p.suffix for p in files} >= {".html", ".json", ".rrd", ".ply"}
    for path in files:
        assert SECRET.encode() not in path.read_bytes(), path
    for _code, out, err in (regress_runs[k] for k in ("make", "clean", "degraded", "accept")):
        assert SECRET not in out + err


@pytest.mark.slow
@pytest.mark.timeout(1200)  # incl. the module fixture's runs, on a busy machine
def test_a_clean_run_exits_0_and_writes_the_report(regress_runs):
    code, out, err = regress_runs["make"]
    assert code == 0, err
    assert "tiny/vanilla: new baseline" in out
    stored = regress_runs["baseline_file"]
    assert stored["metrics"]["options"]["patchmatch"]["schedule"] == "acmm" and stored["flags"][:2] == ["--schedule",
                                                                                                         "acmm"]
    assert "scene_path" not in stored["metrics"] and stored["measured"]["cpu_count"] >= 1
    code, out, err = regress_runs["clean"]
    assert code == 0, out + err
    assert "nothing changed (1 runs" in out and "CHANGED" not in out
    assert "f1@0.02" in out and "within_1pct" in out  # the table of deltas
    root = regress_runs["root"] / "clean"
    summary = json.loads((root / "summary.json").read_text())
    statuses = {d["label"]: d["status"] for d in summary["runs"][0]["deltas"]}
    assert statuses["f1@0.02"] == OK and statuses["within_1pct"] == OK and statuses["time"] == INFO
    assert (root / "tiny" / "vanilla" / "fused.ply").is_file()
    metrics = json.loads((root / "tiny" / "vanilla" / "metrics.json").read_text())
    assert metrics["seconds_cpu"] > 0 and metrics["eval"]["f1"] == stored["metrics"]["eval"]["f1"]  # deterministic
    html = (root / "report.html").read_text()
    assert "Nothing changed" in html and "<script" not in html
    assert not re.search(r"""(src|href)=['"]?(https?:|//)""", html)  # self-contained: no external assets


@pytest.mark.slow
@pytest.mark.timeout(1200)  # incl. the module fixture's runs, on a busy machine
def test_one_patchmatch_iteration_is_a_change_for_the_worse_and_is_named(regress_runs):
    code, out, err = regress_runs["degraded"]
    assert code == 1, out + err
    changed = [line for line in out.splitlines() if line.startswith("changed: tiny/vanilla ")]
    assert changed, out
    assert any(" f1@" in line or " completeness@" in line or " within_1pct " in line for line in changed)
    assert any(": worse by " in line for line in changed)
    assert "CHANGED:" in out.splitlines()[-1]
    assert "patchmatch.iterations: None -> 1" in out  # the cause is visible next to the effect
    html = (regress_runs["root"] / "degraded_report" / "report.html").read_text()
    assert "CHANGED: tiny/vanilla" in html


@pytest.mark.slow
@pytest.mark.timeout(1200)  # incl. the module fixture's runs, on a busy machine
def test_update_baseline_rewrites_it_and_says_what_changed(regress_runs):
    code, out, err = regress_runs["accept"]
    assert code == 0, out + err
    changes = next(line for line in out.splitlines() if line.strip().startswith("tiny/vanilla:"))
    assert "f1@0.02" in changes and "->" in changes
    before, after = regress_runs["baseline_file"]["metrics"], regress_runs["accepted_file"]["metrics"]
    assert after["options"]["patchmatch"]["iterations"] == 1 and before["options"]["patchmatch"]["iterations"] is None
    assert after["eval"]["f1"] != before["eval"]["f1"]
    # --reason: stored with the baseline and shown in the report; the first baseline had none
    assert regress_runs["accepted_file"]["reason"] == "one iteration per pass, on purpose"
    assert "reason" not in regress_runs["baseline_file"]
    assert "Baseline remade on purpose: one iteration per pass, on purpose" in (
        regress_runs["root"] / "accept" / "report.html").read_text()
    # --record: a rerun recording per run, linked from the report
    accept = regress_runs["root"] / "accept"
    assert (accept / "tiny" / "vanilla" / "recording.rrd").stat().st_size > 10_000
    assert "href='tiny/vanilla/recording.rrd'" in (accept / "report.html").read_text()


@pytest.mark.slow
@pytest.mark.timeout(1200)  # incl. the module fixture's runs, on a busy machine
@pytest.mark.browser
def test_the_report_shows_its_plots_in_chromium(regress_runs, browser_context, tmp_path):
    report = regress_runs["root"] / "clean" / "report.html"
    page = browser_context.new_page()
    requests: list[str] = []
    page.on("request", lambda request: requests.append(request.url))
    page.route("file://**", lambda route: route.continue_())  # the shared context only lets 127.0.0.1 through
    try:
        page.goto(report.as_uri())
        page.get_by_text("Nothing changed").wait_for()
        sizes = page.evaluate("Array.from(document.images).map(i => [i.className, i.complete, i.naturalWidth])")
        plots = [s for s in sizes if s[0] == "plot"]
        thumbs = [s for s in sizes if s[0] == "thumb"]
        assert len(plots) == 3, sizes  # F1 vs tolerance, ROC, depth-error histogram
        assert len(thumbs) >= 2 * 5  # 2 views x image, depth, normal, counter, error
        assert all(complete and width > 100 for _, complete, width in plots)
        assert all(complete and width > 0 for _, complete, width in thumbs)
        assert requests == [report.as_uri()]  # self-contained: nothing else was fetched
        plot = page.locator("img.plot").first
        plot.scroll_into_view_if_needed()
        assert plot.is_visible() and plot.bounding_box()["width"] > 100
        shot = tmp_path / "report.png"
        page.screenshot(path=str(shot), full_page=True)
        pixels = np.asarray(Image.open(shot).convert("RGB"), np.float32)
        assert pixels.shape[0] > 1000 and pixels.std() > 20
        assert (np.abs(pixels - 255).sum(axis=2) > 30).mean() > 0.05  # plots and thumbnails, not a white page
    finally:
        page.close()


# ---- the report's confidence and refinement parts (fake run, no PatchMatch) ------------------------------

def test_report_of_a_run_with_confidence_and_refined_maps(tmp_path):
    """A fast/full-style output folder: the ROC of a confidence that ranks outliers low, error histograms of
    PatchMatch and refined depth, and thumbnails of every map."""
    from engine.run.folder import read_map, write_map
    from engine.scene import load_scene
    from workbench.regress.report import analyse_run, relative_depth_labels, write_report

    run = make_fake_run(SAMPLES / "tiny", tmp_path / "run")
    scene = load_scene(SAMPLES / "tiny")
    for view in scene.views:  # depth 10 % wrong where the confidence and counter ramps are low
        depth = read_map(run, "depth", view.name)
        rows = np.arange(depth.shape[0])[:, None] / depth.shape[0]
        write_map(run, "refined_depth", view.name, np.where(rows < 0.25, depth * 1.1, depth))
        write_map(run, "depth", view.name, np.where(rows < 0.6, depth * 1.1, depth))
    analysis = analyse_run(run, max_views=2, labels=("within 1 %", relative_depth_labels))
    assert set(analysis.roc) == {"confidence", "counter (PatchMatch depth)"}
    assert analysis.roc["confidence"][2] > 0.99  # judged against the refined depth, whose errors it ranks low
    assert analysis.roc["counter (PatchMatch depth)"][2] > 0.9  # the counter ramps like the confidence
    reversed_labels = ("reversed", lambda scene, i, depth: 1 - relative_depth_labels(scene, i, depth))
    assert analyse_run(run, max_views=0, labels=reversed_labels).roc["confidence"][2] < 0.01  # pluggable labels
    assert np.median(analysis.errors["PatchMatch"]) > 0.05 > np.median(analysis.errors["refined"])
    kinds = set(analysis.thumbnails[0][1])
    assert {"image", "depth", "normal", "counter", "confidence", "refined depth", "error"} <= kinds
    assert len(analysis.thumbnails) == 2

    metrics = json.loads((run / "metrics.json").read_text())
    spec = RunSpec("tiny", "full", SAMPLES / "tiny", [], None, None, None, {})
    result = RunResult(spec, run, metrics, None, compare(spec.key, metrics, None, {}), (0.0, 0.0), None)
    suite = Suite(tmp_path / "suite.toml", "fake", tmp_path, 2, [spec])
    report = write_report(tmp_path / "report.html", suite, [result], {"git": "abc"}, tmp_path,
                          labels=("within 1 %", relative_depth_labels))
    html = report.read_text()
    assert html.count("<img class=plot") == 2  # ROC and histogram; no eval block, so no F1 plot
    assert "confidence (0..1)" in html and "refined depth" in html and "no baseline" in html.lower()
