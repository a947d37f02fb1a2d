"""The benchmark harness (support/bench.py), every benchmark script and result JSON (each against its script's
SCHEMA), the stale marks (benchmarks/mark_stale.py), the sources of the numbers of the
hand-written pages (docs/decisions.md, architecture.md, distributed.md, reliability.md) and docs/results.md."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import numpy as np
import pytest

from support import bench, doc_sources, schema

SCRIPTS = bench.scripts()
RESULTS = sorted(bench.RESULTS.glob("*.json"))
ABSOLUTE = re.compile(r"(?<![\w.:/<>~-])/[\w.~+@-]+/")  # the start of an absolute path of 2+ components


def _strings(value) -> list[str]:
    if isinstance(value, str):
        return [value]
    if isinstance(value, dict):
        return [s for k, v in value.items() for s in (k, *_strings(v))]
    if isinstance(value, list):
        return [s for v in value for s in _strings(v)]
    return []


def test_result_starts_with_script_arguments_revision_and_environment(tmp_path):
    script = bench.BENCHMARKS / "performance" / "bench_fusion.py"
    path = bench.write_result({"seconds": np.float64(1.5), "points": np.int64(7), "nan": float("nan")},
                              tmp_path / "out.json", script=script, argv=["--repeats", "3"],
                              schema={"seconds": float, "points": int, "nan": (float, None)})
    data = json.loads(path.read_text())
    assert list(data)[:6] == list(bench.METADATA_KEYS)
    assert data["script"] == "benchmarks/performance/bench_fusion.py"
    assert data["argv"] == ["--repeats", "3"]
    assert data["git"] is None or re.fullmatch(r"[0-9a-f]{40}", data["git"])
    assert data["dirty"] in (None, True, False) and (data["dirty"] is None) == (data["git"] is None)
    assert data["inputs"] == {"weights": {}, "scenes": {}}
    env = data["environment"]
    assert {"python", "cpu_count", "cpu_model", "packages", "date"} <= set(env)
    assert {"numpy", "numba", "torch"} <= set(env["packages"])
    assert os.uname().nodename not in json.dumps(env)  # no host name
    assert (data["seconds"], data["points"], data["nan"]) == (1.5, 7, None)


def test_no_absolute_path_survives(tmp_path):
    tmp = tmp_path / "out"  # pytest makes it in the temporary folder
    data = {"run": str(bench.REPO_ROOT / "runs" / "fountain768"), "scene": str(bench.SHARED_DATA / "fountain_p11"),
            "tmp": str(tmp), "home": str(Path.home() / "data" / "scene7"), "elsewhere": "/opt/x/y/weights.pt",
            "note": f"deepc run {bench.SHARED_DATA / 'fountain_p11'} --out {tmp} (F1 1/2/5 cm, fast / full)",
            str(bench.REPO_ROOT / "as_key"): [Path("/srv/a/b.ply")], "url": "https://example.org/a/b"}
    keys = {"run": str, "scene": str, "tmp": str, "home": str, "elsewhere": str, "note": str, "as_key": list,
            "url": str}
    path = bench.write_result(data, tmp_path / "out.json", script=SCRIPTS[0], argv=[str(tmp), "--x"], schema=keys)
    written = json.loads(path.read_text())
    assert not [s for s in _strings(written) if ABSOLUTE.search(s)]
    assert written["run"] == "runs/fountain768"
    assert written["scene"] == "../shared/data/fountain_p11"
    assert written["tmp"] == "<tmp>/out" and written["argv"] == ["<tmp>/out", "--x"]
    assert written["elsewhere"] == "weights.pt" and written["home"].endswith("scene7")
    assert written["note"] == "deepc run ../shared/data/fountain_p11 --out <tmp>/out (F1 1/2/5 cm, fast / full)"
    assert written["as_key"] == ["b.ply"] and written["url"] == "https://example.org/a/b"


def test_write_is_atomic(tmp_path, monkeypatch):
    path = tmp_path / "out.json"
    bench.write_result({"v": 1}, path, script=SCRIPTS[0], argv=[], schema={"v": int})

    def fail(*args):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(Exception, match="disk full"):
        bench.write_result({"v": 2}, path, script=SCRIPTS[0], argv=[], schema={"v": int})
    assert json.loads(path.read_text())["v"] == 1  # the earlier result is intact
    assert [p.name for p in tmp_path.iterdir()] == ["out.json"]  # and no temporary file is left


def test_results_are_named_after_their_script(monkeypatch, tmp_path):
    monkeypatch.setattr(bench, "RESULTS", tmp_path)
    script = bench.BENCHMARKS / "paper" / "table2_filters.py"
    assert bench.results_path(script, "dense") == tmp_path / "table2_filters_dense.json"
    bench.write_result({"runs": []}, bench.results_path(script, "dense"), script=script, argv=[])
    with pytest.raises(ValueError, match="must be named table2_filters"):
        bench.write_result({"runs": []}, tmp_path / "table2.json", script=script, argv=[])
    with pytest.raises(ValueError, match="harness's keys"):
        bench.write_result({"script": "x"}, tmp_path / "table2_filters.json", script=script, argv=[])


def test_tables_align_and_drop_empty_columns():
    rows = [{"name": "a", "F1": 81.234, "ratio": 0.0123, "none": None, "n": 1234}, {"name": "bb", "F1": None}]
    text = bench.format_table(rows).splitlines()
    assert text[0].split() == ["name", "F1", "ratio", "n"] and len({len(line) for line in text}) == 1
    assert text[2].split() == ["a", "81.23", "0.0123", "1,234"] and text[3].split() == ["bb", "–", "–", "–"]
    md = bench.format_table(rows, markdown=True).splitlines()
    assert md[0] == "| name | F1 | ratio | n |" and md[1] == "|---|---:|---:|---:|"


def test_benchmark_layout():
    assert {p.parent.name for p in SCRIPTS} == set(bench.FOLDERS)
    assert len({p.stem for p in SCRIPTS}) == len(SCRIPTS)  # result names stay unambiguous
    loose = sorted(p.name for p in bench.BENCHMARKS.glob("*.py"))
    assert loose == ["mark_stale.py", "results_md.py"]
    for path in [*SCRIPTS, *(bench.BENCHMARKS / name for name in loose)]:
        assert "sys.path" not in path.read_text(), path


@pytest.mark.parametrize("script", SCRIPTS, ids=[p.stem for p in SCRIPTS])
def test_script_imports_and_answers_help(script, monkeypatch, capsys):
    module = bench.load_script(script)
    assert module.__doc__ and callable(module.summary) and isinstance(module.SCHEMA, dict)
    assert set(getattr(module, "WEIGHTS", ())) <= set(bench.SHIPPED_WEIGHTS)
    text = script.read_text()
    assert "bench.write_result(" in text and "write_json" not in text
    assert f"benchmarks/{script.parent.name}/{script.name}" in module.__doc__  # the usage line names its place
    monkeypatch.setattr("sys.argv", [str(script), "--help"])
    with pytest.raises(SystemExit) as stop:
        module.main()
    assert stop.value.code == 0 and "usage:" in capsys.readouterr().out


@pytest.mark.parametrize("path", RESULTS, ids=[p.stem for p in RESULTS])
def test_result_json_names_its_script_and_no_machine_path(path):
    data = json.loads(path.read_text())
    assert isinstance(data, dict) and list(data)[:3] == ["script", "argv", "git"]
    script = bench.REPO_ROOT / data["script"]
    assert script in SCRIPTS and path.stem.startswith(script.stem)
    assert data["git"] or data.get("committed_in")  # the revision, or the commit that added an older result
    assert not [s for s in _strings(data) if ABSOLUTE.search(s)]
    assert bench.schema_errors(data, script) == []  # the keys and types the script declares it writes
    assert bench.load_script(script).summary(data)  # the docs' table can be made from it


def test_results_md_check_passes():
    """What `benchmarks/results_md.py --check` checks: the page is generated, every JSON matches its script's
    SCHEMA, every stale mark is in place and every number of the pages of
    ``SOURCED_DOCS`` cites a JSON key that holds it."""
    generator = bench.load_script(bench.BENCHMARKS / "results_md.py")
    assert generator.problems() == []


def test_stale_results_are_labelled_on_the_page():
    page = (bench.REPO_ROOT / "docs" / "results.md").read_text()
    assert page.startswith("# Benchmark results\n\nGenerated by `benchmarks/results_md.py`")
    stale = [p for p in RESULTS if json.loads(p.read_text()).get("stale")]
    assert stale
    for path in stale:
        section = page.split(f"**`benchmarks/results/{path.name}`**", 1)[1].split("\n**`", 1)[0]
        assert "**Stale** (marked " in section, path.name


def test_schema_rejects_missing_wrong_and_unknown_keys():
    declared = {"scene": str, "rows": list, "size?": (int, None)}
    base = {"script": "x.py", "argv": [], "git": None}
    assert schema.errors({**base, "scene": "a", "rows": []}, declared) == []
    assert schema.errors({**base, "scene": "a", "rows": [], "size": None}, declared) == []
    assert schema.errors({**base, "rows": {}}, declared) == ["missing key 'scene'", "'rows' is dict, not list"]
    assert schema.errors({**base, "scene": "a", "rows": [], "note": "x"}, declared) == \
        ["key 'note' is not in the script's SCHEMA"]
    marked = {"date": "2026-01-01", "reason": "r", "by": "b", "unexpected_keys": ["note"]}
    assert schema.errors({**base, "scene": "a", "rows": [], "note": "x", "stale": marked}, declared) == []


def test_write_refuses_a_result_its_script_does_not_declare(tmp_path):
    script = bench.BENCHMARKS / "paper" / "table2_filters.py"
    with pytest.raises(ValueError, match="SCHEMA"):
        bench.write_result({"runs": [], "note": "by hand"}, tmp_path / "table2_filters.json", script=script, argv=[])


def test_inputs_record_weights_and_scene_digests(tmp_path):
    weights = tmp_path / "w.pt"
    weights.write_bytes(b"weights")
    scene = bench.REPO_ROOT / "sample_scenes" / "tiny"
    record = bench.inputs_record([str(scene), f"new={weights}"])
    assert record["weights"] == {"<tmp>/w.pt": bench.file_sha256(weights)}
    assert record["scenes"] == {"sample_scenes/tiny": bench.scene_digest(scene)}
    assert re.fullmatch(r"[0-9a-f]{64}", bench.scene_digest(scene))


def test_mark_stale_finds_superseded_weights_and_unrecorded_arguments():
    marker = bench.load_script(bench.BENCHMARKS / "mark_stale.py")
    old = {"script": "benchmarks/paper/table2_filters.py", "argv": ["RUN"], "git": None,
           "inputs": {"weights": {"engine/confidence/weights/deepc_middle.pt": "0" * 64}, "scenes": {}}, "runs": []}
    mark = marker.expected(bench.RESULTS / "table2_filters_x.json", old)
    assert mark["reason"].startswith("weights deepc_middle.pt 000000000000 superseded by ")
    assert mark["refresh"] == "benchmarks/paper/table2_filters.py RUN"
    today = bench.file_sha256(bench.REPO_ROOT / bench.SHIPPED_WEIGHTS["deepc_middle.pt"])
    fresh = {**old, "inputs": {"weights": {"engine/confidence/weights/deepc_middle.pt": today}, "scenes": {}}}
    assert marker.expected(bench.RESULTS / "table2_filters_x.json", fresh) is None
    assert "arguments not recorded" in marker.expected(bench.RESULTS / "table2_filters_x.json",
                                                       {**fresh, "argv": None})["reason"]


def test_doc_sources_convention(tmp_path):
    results = tmp_path / "results"
    results.mkdir()
    (results / "r.json").write_text(json.dumps({"scenes": {"Aloe": {"f1@0.02": 98.5432, "share": 0.7459}},
                                                "stale": None}))
    (results / "old.json").write_text(json.dumps({"v": 1.25, "stale": {"reason": "weights"}}))
    page = tmp_path / "page.md"
    page.write_text("# Heading 12.5 %\n\n"
                    "Aloe: 98.54 % within 2 cm, 74.59 % complete [r.json: scenes/Aloe].\n\n"
                    "**Paper**: 96.42. **Ours**: `confidence.tau = 0.1`, 3 views, 8 iterations.\n\n"
                    "Unsourced: 99.1 % and 285 s.\n\n"
                    "| a | b |\n|---|---|\n| 98.5 | 12.0 |\n[r.json: scenes/Aloe]\n\n"
                    "Old: 1.25 [old.json: v]. Missing key [r.json: scenes/Teddy].\n")
    found = doc_sources.check(page, results)
    assert found == ["line 7: 99.1, 285 without a source",
                     "line 9: 12.0 not found under the block's sources",
                     "line 14: r.json has no key 'scenes/Teddy'",
                     "line 14: cites a result marked stale without saying so"]


def test_a_fresh_result_json_does_not_make_the_next_benchmark_dirty(tmp_path):
    """A chain of benchmarks writes tracked result JSONs one after the other: those are outputs, not the code
    measured, so only a change elsewhere marks a revision dirty."""
    import subprocess

    from workbench.regress.environment import git_revision

    def git(*args: str) -> None:
        subprocess.run(["git", "-C", str(tmp_path), *args], check=True, capture_output=True, timeout=30)

    (tmp_path / "benchmarks" / "results").mkdir(parents=True)
    (tmp_path / "benchmarks" / "results" / "a.json").write_text("{}")
    (tmp_path / "code.py").write_text("x = 1\n")
    git("init", "-q")
    git("add", ".")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "start")
    assert not git_revision(tmp_path).endswith("+dirty")
    (tmp_path / "benchmarks" / "results" / "a.json").write_text('{"new": 1}')
    assert not git_revision(tmp_path).endswith("+dirty")
    (tmp_path / "code.py").write_text("x = 2\n")
    assert git_revision(tmp_path).endswith("+dirty")
