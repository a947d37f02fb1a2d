"""Mark the result JSONs that no longer describe today's code or weights as stale: the one writer of ``"stale"``.

    .venv/bin/python benchmarks/mark_stale.py [--check]

A result in benchmarks/results is stale when

- its script runs the shipped networks (the script's ``WEIGHTS``: the first always, a second where the result
  names it) and the sha256 of such a weights file that
  the result recorded (``inputs.weights``), or failing that the one committed at its revision (``committed_in``,
  else ``git``), is not today's;
- it records no arguments (results committed before the harness recorded them): it cannot be rerun as recorded;
- it holds top-level keys its script's ``SCHEMA`` does not name (added by hand, or by an older version of the
  script): they are listed in the mark's ``unexpected_keys``;
- :data:`KNOWN` names it, with the reason.

Each such JSON gains ``"stale": {"date", "reason", "by", "refresh", "unexpected_keys"?}`` (the date it was
first marked for that reason; ``refresh``: what would remake it) and nothing else changes; a JSON that is no
longer stale loses its mark. docs/results.md labels stale tables (benchmarks/results_md.py), and ``--check``
(run by ``results_md.py --check``) exits 1 when a mark is missing or out of date. Rerunning a script rewrites
its JSON without a mark.
"""

from __future__ import annotations

import argparse
import datetime
import json
import subprocess
import sys
from functools import cache
from pathlib import Path
from typing import Any

from engine.io.atomic import write_json
from support import bench

BY = "benchmarks/mark_stale.py"
# Results stale for a reason no rule above finds: file name -> reason.
KNOWN = {
    "peer_fountain.json": "peer_openmvs holds OpenMVS numbers that were hard-coded in the script, not measured "
                          "(peer numbers come from benchmarks/performance/bench_peer.py)",
}
# What would remake a result whose arguments were not recorded (the runs named are fresh `deepc run --pipeline
# vanilla` folders of the scenes at the sizes the JSON records).
REFRESH = {
    "confidence_auc_table.json": "benchmarks/paper/confidence_auc_table.py --variant shipped="
                                 "engine/confidence/weights/deepc_middle.pt --run fountain_p11=RUN --run "
                                 "synth_01000=RUN ... --run small=RUN --run tiny=RUN",
    "confidence_auc_table_refined.json": "benchmarks/paper/confidence_auc_table.py --refined --variant network2="
                                         "engine/confidence/weights/deepc_refined.pt --run fountain_p11=RUN ...",
    "table2_filters.json": "benchmarks/paper/table2_filters.py RUN ... --weights "
                           "engine/confidence/weights/deepc_middle.pt",
    "table2_filters_pixels.json": "benchmarks/paper/table2_filters.py RUN ... --weights "
                                  "engine/confidence/weights/deepc_middle.pt --preset pixels --out "
                                  "benchmarks/results/table2_filters_pixels.json",
    "table3_refinement_small_networks.json": "benchmarks/paper/table3_refinement.py RUN_small --weights "
                                             "engine/confidence/weights/deepc_middle.pt --refined-weights "
                                             "engine/confidence/weights/deepc_refined.pt",
    "table3_refinement_fountain_p11_networks.json": "benchmarks/paper/table3_refinement.py RUN_fountain768 "
                                                    "--weights engine/confidence/weights/deepc_middle.pt "
                                                    "--refined-weights engine/confidence/weights/deepc_refined.pt",
}


def _git(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["git", "-C", str(bench.REPO_ROOT), *args], capture_output=True, timeout=60)


@cache
def sha_at(revision: str, relpath: str) -> str | None:
    """sha256 of ``relpath`` as committed at ``revision``; "" when absent there, None when git cannot say."""
    if not revision:
        return None
    if _git("cat-file", "-e", f"{revision}^{{commit}}").returncode != 0:
        return None  # unknown revision (a shallow clone): no verdict
    shown = _git("show", f"{revision}:{relpath}")
    if shown.returncode != 0:
        return ""
    import hashlib

    return hashlib.sha256(shown.stdout).hexdigest()


@cache
def today(relpath: str) -> tuple[str, str]:
    """sha256 of today's ``relpath`` and the date of the commit that last changed it."""
    date = _git("log", "-1", "--format=%cs", "--", relpath).stdout.decode().strip() or "?"
    return bench.file_sha256(bench.REPO_ROOT / relpath), date


def _recorded_weights(data: dict[str, Any], name: str) -> str | None:
    for path, sha in ((data.get("inputs") or {}).get("weights") or {}).items():
        if Path(path).name == name and path.startswith("engine/"):
            return sha
    return None


def weights_reasons(data: dict[str, Any], module: Any) -> list[str]:
    reasons = []
    revision = data.get("committed_in") or (data.get("git") or "").removesuffix("+dirty")
    text = json.dumps(data)
    for i, name in enumerate(getattr(module, "WEIGHTS", ())):
        if i > 0 and Path(name).stem not in text:
            continue  # a second network counts where the result names it
        relpath = bench.SHIPPED_WEIGHTS[name]
        used = _recorded_weights(data, name)
        if used is None:
            used = sha_at(revision, relpath)
        if not used:
            continue  # unknown (no git history) or the file did not exist then: not the shipped network
        now, date = today(relpath)
        if used != now:
            reasons.append(f"weights {name} {used[:12]} superseded by {now[:12]} on {date}")
    return reasons


def expected(path: Path, data: dict[str, Any]) -> dict[str, Any] | None:
    """The stale mark ``path`` should carry (its date from the current mark where the reason is unchanged)."""
    script = bench.REPO_ROOT / data["script"]
    module = bench.load_script(script)
    reasons = weights_reasons(data, module)
    if data.get("argv") is None:
        where = f" (committed in {data['committed_in']})" if data.get("committed_in") else ""
        reasons.append(f"revision and arguments not recorded{where}: it cannot be rerun as recorded")
    from support.schema import HARNESS

    known = {k.rstrip("?") for k in [*HARNESS, *getattr(module, "SCHEMA", {})]}
    unexpected = [k for k in data if k not in known]
    if unexpected:
        keys = f"{'key' if len(unexpected) == 1 else 'keys'} {', '.join(unexpected)}"
        reasons.append(f"{keys} not written by {data['script']} (added by hand or by an older version of the "
                       f"script)")
    if path.name in KNOWN:
        reasons.append(KNOWN[path.name])
    if not reasons:
        return None
    reason = "; ".join(reasons)
    current = data.get("stale") or {}
    date = current.get("date") if current.get("reason") == reason else None
    argv = data.get("argv")
    refresh = REFRESH.get(path.name) or (f"{data['script']} {' '.join(argv)}".strip() if argv is not None else
                                          f"{data['script']} (arguments not recorded: see its usage line)")
    mark = {"date": date or datetime.date.today().isoformat(), "reason": reason, "by": BY, "refresh": refresh}
    if unexpected:
        mark["unexpected_keys"] = unexpected
    return mark


def _comparable(mark: dict[str, Any] | None) -> dict[str, Any] | None:
    return None if mark is None else {k: v for k, v in mark.items() if k != "date"}


def out_of_date() -> list[str]:
    """Result files whose stale mark is missing, superfluous or says something else than :func:`expected`."""
    wrong = []
    for path in sorted(bench.RESULTS.glob("*.json")):
        data = json.loads(path.read_text())
        if _comparable(data.get("stale")) != _comparable(expected(path, data)):
            wrong.append(path.name)
    return wrong


def mark_all() -> list[str]:
    changed = []
    for path in sorted(bench.RESULTS.glob("*.json")):
        data = json.loads(path.read_text())
        mark = expected(path, data)
        if data.get("stale") == mark:
            continue
        data.pop("stale", None)
        if mark is not None:  # after the harness's keys, before the numbers
            keys = list(data)
            at = max(i for i, k in enumerate(keys) if k in (*bench.METADATA_KEYS, "committed_in")) + 1
            data = {**{k: data[k] for k in keys[:at]}, "stale": mark, **{k: data[k] for k in keys[at:]}}
        write_json(path, data)
        changed.append(path.name)
    return changed


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="report marks that are missing or out of date")
    args = parser.parse_args(argv)
    if args.check:
        wrong = out_of_date()
        for name in wrong:
            print(f"benchmarks/results/{name}: stale mark missing or out of date (run {BY})", file=sys.stderr)
        return 1 if wrong else 0
    for name in mark_all():
        print(f"marked benchmarks/results/{name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
