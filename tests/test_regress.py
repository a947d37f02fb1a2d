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
    DEFAULT_SUITE,
    IMPROVED,
    INFO,
    MISSING,
    NEW,
    OK,
    REGRESSED,
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


def test_compare_applies_direction_and_tolerance_per_metric():
    tol = {"f1": 0.5, "accuracy": 0.5, "completeness": 0.5, "within_1pct": 0.5, "abs_rel": 0.001, "auc": 0.5,
           "time": 0.5, "cpu_time": None, "within_5pct": None, "valid_fraction": None}
    base = _metrics(auc=95.0)
    deltas = compare("s/p", _metrics(f1=49.6, within=79.4, abs_rel=0.0215, seconds=16.0, auc=95.6), base, tol)
    assert _status(deltas, "f1@0.02") == OK  # -0.4 is within 0.5
    assert _status(deltas, "within_1pct") == REGRESSED  # -0.6
    assert _status(deltas, "abs_rel") == REGRESSED  # lower is better: +0.0015 > 0.001
    assert _status(deltas, "time") == REGRESSED  # +60 % > +50 %
    assert _status(deltas, "auc") == IMPROVED
    assert _status(deltas, "cpu_time") == INFO and _status(deltas, "within_5pct") == INFO
    faster = compare("s/p", _metrics(f1=51.0, seconds=4.0), base, tol)
    assert _status(faster, "time") == IMPROVED and _status(faster, "f1@0.05") == IMPROVED
    assert _status(faster, "auc") == MISSING  # the baseline had a confidence AUC, this run has none
    no_eval = {k: v for k, v in _metrics().items() if k != "eval"}
    assert _status(compare("s/p", no_eval, base, tol), "f1@0.02") == MISSING
    assert _status(compare("s/p", base, None, tol), "f1@0.02") == NEW
    regressed = [d for d in deltas if d.status == REGRESSED]
    assert "s/p within_1pct 80.00 -> 79.40 (-0.60, allowed -0.5)" in [d.explain() for d in regressed]


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
    assert a.scene_options.max_image_size == 96 and suite.runs[1].scene_options.max_image_size == 0
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
    assert "nothing regressed (1 runs" in out and "REGRESSED" not in out
    assert "f1@0.02" in out and "within_1pct" in out  # the table of deltas
    root = regress_runs["root"] / "clean"
    summary = json.loads((root / "summary.json").read_text())
    statuses = {d["label"]: d["status"] for d in summary["runs"][0]["deltas"]}
    assert statuses["f1@0.02"] == OK and statuses["within_1pct"] == OK and statuses["time"] == INFO
    assert (root / "tiny" / "vanilla" / "fused.ply").is_file()
    metrics = json.loads((root / "tiny" / "vanilla" / "metrics.json").read_text())
    assert metrics["seconds_cpu"] > 0 and metrics["eval"]["f1"] == stored["metrics"]["eval"]["f1"]  # deterministic
    html = (root / "report.html").read_text()
    assert "Nothing regressed" in html and "<script" not in html
    assert not re.search(r"""(src|href)=['"]?(https?:|//)""", html)  # self-contained: no external assets


@pytest.mark.slow
@pytest.mark.timeout(1200)  # incl. the module fixture's runs, on a busy machine
def test_one_patchmatch_iteration_regresses_and_is_named(regress_runs):
    code, out, err = regress_runs["degraded"]
    assert code == 1, out + err
    regressed = [line for line in out.splitlines() if line.startswith("regressed: tiny/vanilla ")]
    assert regressed, out
    assert any(" f1@" in line or " completeness@" in line or " within_1pct " in line for line in regressed)
    assert "REGRESSION:" in out.splitlines()[-1]
    assert "patchmatch.iterations: None -> 1" in out  # the cause is visible next to the effect
    html = (regress_runs["root"] / "degraded_report" / "report.html").read_text()
    assert "REGRESSED: tiny/vanilla" in html


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
        page.get_by_text("Nothing regressed").wait_for()
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
