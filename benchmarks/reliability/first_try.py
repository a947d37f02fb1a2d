"""A user's first try on their own COLMAP workspaces (issue 46): `deepc info`, a camera/image size mismatch, an
interrupted undistortion, and `deepc run` with defaults (working size, ETA, Ctrl-C, `--resume`), timed through
the command line.

    .venv/bin/python benchmarks/reliability/first_try.py --workspace LABEL=PATH [--workspace ...]
        [--source LABEL=OWNER/NAME@COMMIT[:FOLDER]] [--mismatch LABEL] [--undistort LABEL] [--run LABEL]
        [--stop-delay S] [--no-stop] [--repeats N] [--json benchmarks/results/first_try.json]

Every workspace gets `deepc info` (wall time and exit status, ``--repeats`` times). ``--mismatch``: a workspace whose
images disagree with their (distorted) camera: `deepc info` and `deepc run` must each end with one `deepc:` line and
exit 2, leaving no output folder and nothing in the cache. ``--undistort``: `deepc run` of a distorted workspace with
a fresh cache (``DEEPC_CACHE``), SIGINT while pycolmap undistorts: exit time and status, no temporary folder, no
child left; then the same undistortion to its end (its time) and a SIGINT during PatchMatch. ``--run``: `deepc run`
with defaults (headless) to its end: the working-size line, the run's ETA on the bars when the first PatchMatch level
ends against the time the run actually took from there (and the "estimated N min" line after the first view); then
a second run SIGINTed ``--stop-delay`` s into PatchMatch's second level (exit time and status) and `--resume` to the
end (its time, the states it reused, whether its maps and cloud are the first run's, byte for byte).

Workspaces are named by their label, counts, sizes and camera models and by ``--source`` (where they were fetched
from); never by a path. They are not part of the repository.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

from support import bench

# Top-level keys of this script's result JSON and their types (support/schema.py); the harness adds its own.
SCHEMA = {"workspaces": list, "info": list, "mismatch": (dict, None), "undistortion": (dict, None),
          "run": (dict, None), "targets": list, "load_note": str}

DEEPC = [sys.executable, "-m", "workbench.cli"]
TEMP_PREFIX = ".undistort-"  # engine/io/undistort.py's temporary folders in the cache
ETA_RE = re.compile(r"ETA (\d+(?:\.\d+)?) (s|min|h)\b")
ESTIMATE_RE = re.compile(r"estimated (\d+(?:\.\d+)?) (s|min|h) on this machine")
LEVEL_RE = re.compile(r"level (\d+)")
PASS_RE = re.compile(r"(level \d+ [a-z]+)\s*:.*\|\s*(\d+)/(\d+) \[")  # a pass's bar: its name, views done, views
UNDISTORT_LOG_RE = re.compile(rb"Undistorting image \[(\d+)/(\d+)\]")  # pycolmap's log line per image


def summary(result: dict) -> list[dict]:
    """One row per Done-when target of issue 46: what was measured, on which workspace, against the target."""
    return result["targets"]


# ---- a command with its stderr, timed segment by segment ----------------------------------------------------

class Watched:
    """A child process whose stdout and stderr are read as they come, split on newlines and carriage returns (tqdm
    redraws a bar with ``\\r``), each segment with the seconds since the start at which it arrived."""

    def __init__(self, args: list[str], env: dict[str, str] | None = None):
        self.start = time.perf_counter()
        self.proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     env=env, cwd=bench.REPO_ROOT)
        self.segments: dict[str, list[tuple[float, str]]] = {"stdout": [], "stderr": []}
        self._lock = threading.Lock()
        self._threads = [threading.Thread(target=self._read, args=(stream, name), daemon=True)
                         for stream, name in ((self.proc.stdout, "stdout"), (self.proc.stderr, "stderr"))]
        for thread in self._threads:
            thread.start()
        self.end: float | None = None
        self.load: list[tuple[float, float]] = []  # (seconds since the start, 1-minute load average), every 10 s
        threading.Thread(target=self._sample_load, daemon=True).start()

    def _sample_load(self) -> None:
        while self.proc.poll() is None:
            self.load.append((time.perf_counter() - self.start, os.getloadavg()[0]))
            time.sleep(10)

    def _read(self, stream: Any, name: str) -> None:
        partial = b""
        fd = stream.fileno()
        while True:
            chunk = os.read(fd, 65536)
            now = time.perf_counter() - self.start
            if not chunk:
                break
            parts = re.split(rb"[\r\n]", partial + chunk)
            partial = parts.pop()
            with self._lock:
                self.segments[name] += [(now, p.decode(errors="replace")) for p in parts if p.strip()]
        if partial.strip():
            with self._lock:
                self.segments[name].append((time.perf_counter() - self.start, partial.decode(errors="replace")))

    def lines(self, name: str = "stderr") -> list[tuple[float, str]]:
        with self._lock:
            return list(self.segments[name])

    def wait_for(self, pattern: str, timeout: float, name: str = "stderr") -> tuple[float, str] | None:
        """The first segment matching ``pattern`` (a regular expression), waiting up to ``timeout`` s; None when the
        process ends or the time runs out first."""
        regex = re.compile(pattern)
        deadline = time.perf_counter() + timeout
        while time.perf_counter() < deadline:
            for t, line in self.lines(name):
                if regex.search(line):
                    return t, line
            if self.proc.poll() is not None:
                for t, line in self.lines(name):
                    if regex.search(line):
                        return t, line
                return None
            time.sleep(0.05)
        return None

    def finish(self, timeout: float) -> int:
        try:
            self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.end = time.perf_counter() - self.start
        for thread in self._threads:
            thread.join(5)
        return self.proc.returncode

    def interrupt(self, timeout: float = 60) -> tuple[float, int]:
        """SIGINT now; (seconds until the process exited, its exit status)."""
        sent = time.perf_counter()
        self.proc.send_signal(signal.SIGINT)
        code = self.finish(timeout)
        return time.perf_counter() - sent, code


def deepc(args: list[str], env: dict[str, str] | None = None, timeout: float = 3600) -> tuple[float, Watched, int]:
    """Run ``deepc ARGS`` to its end: (wall seconds, the watched process, exit status)."""
    watched = Watched(DEEPC + args, env)
    code = watched.finish(timeout)
    return watched.end, watched, code


def seconds_of(value: str, unit: str) -> float:
    return float(value) * {"s": 1, "min": 60, "h": 3600}[unit]


def children_named(text: str) -> list[int]:
    """Processes whose command line contains ``text`` (a child the run should have taken with it)."""
    found = []
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            cmdline = (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if text in cmdline:
            found.append(int(proc.name))
    return found


def tree_digest(root: Path, subfolders: tuple[str, ...] = ("stereo", "fused.ply")) -> dict[str, str]:
    """md5 of every file under ``root``'s ``subfolders`` (maps and cloud), by relative path."""
    out = {}
    for sub in subfolders:
        path = root / sub
        files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else []
        for f in files:
            out[f.relative_to(root).as_posix()] = hashlib.md5(f.read_bytes()).hexdigest()
    return out


# ---- workspaces ---------------------------------------------------------------------------------------------

def describe_workspace(label: str, path: Path, source: str | None) -> dict[str, Any]:
    """Label, source, camera models, counts and sizes of a workspace (read with pycolmap; no path)."""
    import pycolmap
    from PIL import Image

    from engine.io.colmap_model import find_model_dir

    rec = pycolmap.Reconstruction(str(find_model_dir(path)))
    files = sorted(p for p in (path / "images").rglob("*") if p.is_file() and not p.name.startswith("."))
    sizes = Counter()
    for f in files:
        with Image.open(f) as im:
            sizes[f"{im.width}x{im.height}"] += 1
    cameras = Counter(f"{c.model.name} {c.width}x{c.height}" for c in rec.cameras.values())
    return {"label": label, "source": source, "image_files": len(files), "registered_images": len(rec.images),
            "cameras": len(rec.cameras), "points3D": len(rec.points3D),
            "camera_models": dict(cameras.most_common()), "image_sizes": dict(sizes.most_common())}


def scrubbed(text: str, paths: dict[str, Path]) -> str:
    """``text`` with each workspace's path replaced by ``<LABEL>`` and temporary folders by ``<tmp>``."""
    for label, path in sorted(paths.items(), key=lambda kv: -len(str(kv[1]))):
        text = text.replace(str(path.resolve()), f"<{label}>").replace(str(path), f"<{label}>")
    return bench.scrub(text)


# ---- the measurements ---------------------------------------------------------------------------------------

def measure_info(label: str, path: Path, repeats: int, env: dict[str, str]) -> dict[str, Any]:
    times, codes, lines = [], [], 0
    for _ in range(repeats):
        wall, watched, code = deepc(["info", str(path)], env, timeout=600)
        times.append(round(wall, 3))
        codes.append(code)
        lines = len(watched.lines("stdout"))
    print(f"info {label}: {times} s, exit {codes}, {lines} lines")
    return {"workspace": label, "seconds": times, "best_s": min(times), "exit": codes, "stdout_lines": lines}


def one_line_error(watched: Watched, paths: dict[str, Path]) -> dict[str, Any]:
    err = [line for _, line in watched.lines("stderr")]
    return {"stderr_lines": len(err), "one_deepc_line": len(err) == 1 and err[0].startswith("deepc:"),
            "traceback": any("Traceback" in line for line in err),
            "stderr": scrubbed(err[0], paths)[:300] if err else ""}


def measure_mismatch(label: str, path: Path, repeats: int, paths: dict[str, Path], tmp: Path) -> dict[str, Any]:
    cache = tmp / "cache-mismatch"
    env = dict(os.environ, DEEPC_CACHE=str(cache))
    rows = []
    for command in ("info", "run"):
        for i in range(repeats):
            out = tmp / f"mismatch-out-{i}"
            args = ["info", str(path)] if command == "info" else ["run", str(path), "--out", str(out), "--headless"]
            wall, watched, code = deepc(args, env, timeout=600)
            row = {"command": f"deepc {command}", "seconds": round(wall, 3), "exit": code,
                   **one_line_error(watched, paths), "output_folder": out.exists(),
                   "cache_entries": len(list((cache / "undistorted").iterdir())) if (cache / "undistorted").is_dir()
                   else 0}
            print(f"mismatch {label} {row}")
            rows.append(row)
            shutil.rmtree(out, ignore_errors=True)
    return {"workspace": label, "rows": rows}


def measure_undistortion(label: str, path: Path, paths: dict[str, Path], tmp: Path) -> dict[str, Any]:
    cache = tmp / "cache-undistort"
    env = dict(os.environ, DEEPC_CACHE=str(cache))
    result: dict[str, Any] = {"workspace": label}
    # 1. SIGINT while pycolmap undistorts, once its log (in the temporary folder) says a quarter of the images are done
    out = tmp / "undistort-out-1"
    cache_root = cache / "undistorted"
    watched = Watched(DEEPC + ["run", str(path), "--out", str(out), "--headless"], env)
    started = watched.wait_for(r"undistorting \d+ images", 600)
    moved = None
    while started and watched.proc.poll() is None and moved is None:
        for log in cache_root.glob(TEMP_PREFIX + "*/undistort.log"):
            done = UNDISTORT_LOG_RE.findall(log.read_bytes())
            if done and int(done[-1][0]) >= max(2, int(done[-1][1]) // 4):
                moved = (time.perf_counter() - watched.start, f"{int(done[-1][0])}/{int(done[-1][1])}")
        if any(re.search(r"undistorted \d+ images in", line) for _, line in watched.lines()):
            break
        time.sleep(0.05)
    if moved is None:
        watched.interrupt()
        result["interrupted"] = {"error": "no undistortion seen in progress",
                                 "stderr": [scrubbed(line, paths) for _, line in watched.lines()][-5:]}
        return result
    latency, code = watched.interrupt()
    left = sorted(p.name for p in cache_root.iterdir()) if cache_root.is_dir() else []
    err = [line for _, line in watched.lines()]
    result["interrupted"] = {
        "undistort_started_s": round(started[0], 2), "sigint_at_s": round(moved[0], 2),
        "images_done_at_sigint": moved[1],
        "exit_s": round(latency, 3), "exit": code, "last_line": scrubbed(err[-1], paths) if err else "",
        "temporary_folders_left": sum(n.startswith(TEMP_PREFIX) for n in left),
        "cache_entries_left": left, "undistort_children_left": len(children_named(f"engine.io.undistort {cache}")),
        "output_folder_files": sum(1 for p in out.rglob("*") if p.is_file()) if out.exists() else 0}
    print(f"undistortion interrupted: {result['interrupted']}")
    # 2. the same undistortion (a fresh cache) to its end, then a SIGINT once PatchMatch has started
    cache = tmp / "cache-undistort-2"
    cache_root = cache / "undistorted"
    env = dict(os.environ, DEEPC_CACHE=str(cache))
    out2 = tmp / "undistort-out-2"
    watched = Watched(DEEPC + ["run", str(path), "--out", str(out2), "--headless"], env)
    bar = watched.wait_for(r"level \d+ ", 3600)
    done = next(((t, line) for t, line in watched.lines() if re.search(r"undistorted \d+ images in", line)), None)
    line_undistorting = next((scrubbed(line, paths) for _, line in watched.lines() if "undistorting" in line), "")
    working = next((line for _, line in watched.lines() if line.startswith("working size")), "")
    if bar is not None:
        time.sleep(3.0)
        latency, code = watched.interrupt()
    else:
        code, latency = watched.finish(3600), None
    left = sorted(p.name for p in cache_root.iterdir()) if cache_root.is_dir() else []
    seconds = re.search(r"in (\d+(?:\.\d+)?) s", done[1]) if done else None
    result["complete"] = {"undistorting_line": line_undistorting, "undistorted_line": scrubbed(done[1], paths) if done
                          else "", "undistortion_s": float(seconds.group(1)) if seconds else None,
                          "working_size_line": working, "sigint_in_patchmatch_exit_s":
                          round(latency, 3) if latency is not None else None, "exit": code,
                          "cache_entries": len([n for n in left if not n.startswith(TEMP_PREFIX)]),
                          "temporary_folders_left": sum(n.startswith(TEMP_PREFIX) for n in left)}
    print(f"undistortion complete: {result['complete']}")
    return result


def eta_rows(watched: Watched, end: float) -> dict[str, Any]:
    """The ETA when the first PatchMatch level ended (the last bar of that level) and the first view's estimate,
    against the time the run actually took from the moment each was printed."""
    lines = watched.lines()
    first_level = None
    last_of_first = None
    for t, line in lines:
        level = LEVEL_RE.search(line)
        if level is None:
            continue
        if first_level is None:
            first_level = int(level.group(1))
        if int(level.group(1)) != first_level:
            break
        if ETA_RE.search(line):
            last_of_first = (t, line)
    out: dict[str, Any] = {"first_level": first_level}
    if last_of_first is not None:
        t, line = last_of_first
        eta = seconds_of(*ETA_RE.search(line).groups())
        actual = end - t
        out.update({"after_first_level_at_s": round(t, 2), "after_first_level_bar": line.strip()[-120:],
                    "eta_s": eta, "actual_left_s": round(actual, 2), "eta_error": round(eta / actual - 1, 4)})
    passes = {}  # each pass's last bar (its end): the run's ETA then against the time actually left
    for t, line in lines:
        bar = PASS_RE.search(line)
        if bar and ETA_RE.search(line) and bar.group(2) == bar.group(3):
            passes[bar.group(1).strip()] = (t, seconds_of(*ETA_RE.search(line).groups()))
    out["passes"] = [{"pass": name, "ended_at_s": round(t, 1), "eta_s": eta, "actual_left_s": round(end - t, 1),
                      "error": round(eta / (end - t) - 1, 3)} for name, (t, eta) in passes.items()]
    out["load_average"] = [(round(t), load) for t, load in watched.load]
    estimate = next(((t, line) for t, line in lines if ESTIMATE_RE.search(line)), None)
    if estimate is not None:
        t, line = estimate
        eta = seconds_of(*ESTIMATE_RE.search(line).groups())
        out.update({"first_view_estimate_at_s": round(t, 2), "first_view_estimate_s": eta,
                    "first_view_actual_left_s": round(end - t, 2), "first_view_error": round(eta / (end - t) - 1, 4)})
    return out


def measure_run(label: str, path: Path, stop_delay: float, paths: dict[str, Path], tmp: Path,
                stop: bool = True) -> dict[str, Any]:
    env = dict(os.environ, DEEPC_CACHE=str(tmp / "cache-run"))
    result: dict[str, Any] = {"workspace": label}
    # 1. defaults, headless, to the end
    full = tmp / "run-full"
    wall, watched, code = deepc(["run", str(path), "--out", str(full), "--headless"], env, timeout=3 * 3600)
    lines = [line for _, line in watched.lines()]
    out_lines = [line for _, line in watched.lines("stdout")]
    result["full"] = {"seconds": round(wall, 2), "exit": code,
                      "working_size_line": next((x for x in lines if x.startswith("working size")), None),
                      "memory_line": next((x for x in lines if x.startswith("memory:")), None),
                      "summary_line": scrubbed(out_lines[0], paths) if out_lines else None,
                      "traceback": any("Traceback" in x for x in lines), **eta_rows(watched, wall)}
    print(f"run {label}: {result['full']}")
    if code != 0:
        result["full"]["stderr_tail"] = [scrubbed(x, paths) for x in lines[-5:]]
        return result
    if not stop:
        return result
    reference = tree_digest(full)
    # 2. SIGINT stop_delay s into PatchMatch's second level, then --resume
    stopped = tmp / "run-stopped"
    watched = Watched(DEEPC + ["run", str(path), "--out", str(stopped), "--headless"], env)
    first = watched.wait_for(r"level \d+ ", 3600)
    first_level = int(LEVEL_RE.search(first[1]).group(1)) if first else None
    second = watched.wait_for(rf"level (?!{first_level}\b)\d+ ", 3600) if first else None
    interrupt: dict[str, Any] = {"stop_delay_s": stop_delay}
    if second is None:
        interrupt["error"] = "the run never reached a second level"
        watched.finish(3600)
    else:
        time.sleep(max(0.0, stop_delay - (time.perf_counter() - watched.start - second[0])))
        at = time.perf_counter() - watched.start
        latency, code = watched.interrupt()
        err = [line for _, line in watched.lines()]
        bar = next((x for x in reversed(err) if LEVEL_RE.search(x)), "")
        interrupt.update({"second_level_at_s": round(second[0], 2), "sigint_at_s": round(at, 2),
                          "bar_at_sigint": bar.strip()[:120], "exit_s": round(latency, 3), "exit": code,
                          "last_line": scrubbed(err[-1], paths) if err else "",
                          "traceback": any("Traceback" in x for x in err),
                          "saved_states": sum(1 for _ in (stopped / ".deepc-resume").rglob("*.npz"))
                          if (stopped / ".deepc-resume").is_dir() else 0})
        wall, watched, code = deepc(["run", str(path), "--out", str(stopped), "--headless", "--resume"], env,
                                    timeout=3 * 3600)
        lines = [line for _, line in watched.lines()]
        resumed = next((x for x in lines if x.startswith("resumed:")), None)
        digest = tree_digest(stopped)
        result["resume"] = {"seconds": round(wall, 2), "exit": code, "resumed_line": resumed,
                            "traceback": any("Traceback" in x for x in lines),
                            "files_compared": len(reference), "identical_to_full_run": digest == reference,
                            "differing_files": sorted(k for k in reference if digest.get(k) != reference[k])[:10]}
        print(f"resume {label}: {result['resume']}")
    result["interrupt"] = interrupt
    print(f"interrupt {label}: {interrupt}")
    return result


# ---- targets ------------------------------------------------------------------------------------------------

def targets(info: list[dict], mismatch: dict | None, undistortion: dict | None, run: dict | None,
            described: dict[str, dict]) -> list[dict]:
    """The issue's Done-when targets against what was measured."""
    rows = []

    def add(target: str, workspace: str, measured: str, met: bool | None) -> None:
        rows.append({"target": target, "workspace": workspace, "measured": measured, "met": met})

    if mismatch:
        for command in ("deepc info", "deepc run"):
            rs = [r for r in mismatch["rows"] if r["command"] == command]
            if rs:
                ok = all(r["exit"] == 2 and r["one_deepc_line"] and not r["output_folder"] and not r["cache_entries"]
                         for r in rs)
                add(f"size mismatch ({command}): one line, exit 2, < 5 s", mismatch["workspace"],
                    f"{max(r['seconds'] for r in rs):.2f} s worst of {len(rs)}, exit {sorted({r['exit'] for r in rs})}"
                    f", {max(r['stderr_lines'] for r in rs)} stderr line(s)",
                    ok and max(r["seconds"] for r in rs) < 5)
    for row in info:
        d = described[row["workspace"]]
        add("deepc info < 10 s", row["workspace"],
            f"{row['best_s']:.2f} s best, {max(row['seconds']):.2f} s worst ({d['registered_images']} images), "
            f"exit {sorted(set(row['exit']))}", max(row["seconds"]) < 10 and set(row["exit"]) == {0})
    if run and "full" in run:
        f = run["full"]
        add("deepc run with defaults finishes, prints its working size", run["workspace"],
            f"exit {f['exit']} in {f['seconds']:.0f} s; {f['working_size_line'] or 'no working size line'}"[:160],
            f["exit"] == 0 and bool(f["working_size_line"]))
        if "eta_error" in f:
            add("ETA after the first level within 30 %", run["workspace"],
                f"ETA {f['eta_s']:.0f} s vs {f['actual_left_s']:.0f} s actual ({f['eta_error'] * 100:+.0f} %)",
                abs(f["eta_error"]) <= 0.3)
    if run and "interrupt" in run and "exit_s" in run["interrupt"]:
        i = run["interrupt"]
        add("Ctrl-C during PatchMatch exits within 2 s", run["workspace"],
            f"{i['exit_s']:.2f} s, exit {i['exit']}", i["exit_s"] <= 2 and i["exit"] == 130)
    if run and "resume" in run:
        r = run["resume"]
        add("--resume continues", run["workspace"],
            f"exit {r['exit']} in {r['seconds']:.0f} s; {r['resumed_line'] or 'no resumed line'}; identical to the "
            f"uninterrupted run: {r['identical_to_full_run']}", r["exit"] == 0 and bool(r["resumed_line"]))
    if undistortion and "exit_s" in undistortion.get("interrupted", {}):
        u = undistortion["interrupted"]
        add("no stale folder after an interrupted undistortion", undistortion["workspace"],
            f"SIGINT at image {u['images_done_at_sigint']}: exit {u['exit']} after {u['exit_s']:.2f} s, "
            f"{u['temporary_folders_left']} temporary folder(s), {len(u['cache_entries_left'])} cache entries, "
            f"{u['undistort_children_left']} child(ren) left",
            u["exit"] == 130 and not u["temporary_folders_left"] and not u["cache_entries_left"]
            and not u["undistort_children_left"])
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workspace", action="append", default=[], metavar="LABEL=PATH", required=True)
    ap.add_argument("--source", action="append", default=[], metavar="LABEL=TEXT",
                    help="where a workspace came from (repository@commit:folder)")
    ap.add_argument("--mismatch", metavar="LABEL", help="workspace whose images disagree with their camera")
    ap.add_argument("--undistort", metavar="LABEL", help="distorted workspace for the interrupted undistortion")
    ap.add_argument("--run", metavar="LABEL", help="workspace for deepc run with defaults, Ctrl-C and --resume")
    ap.add_argument("--stop-delay", type=float, default=5.0, help="seconds into PatchMatch's second level")
    ap.add_argument("--no-stop", action="store_true", help="--run: the run to its end only (no Ctrl-C, no --resume)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", default=bench.results_path(__file__))
    args = ap.parse_args()
    # A background job (`cmd &` from a script) inherits SIGINT ignored, and so would every deepc started here: a
    # Python handler is reset to the default in a child, an ignored signal stays ignored.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    paths = {label: Path(p) for label, p in (w.split("=", 1) for w in args.workspace)}
    sources = dict(s.split("=", 1) for s in args.source)
    described = {label: describe_workspace(label, path, sources.get(label)) for label, path in paths.items()}
    for d in described.values():
        print(d)
    tmp = Path(tempfile.mkdtemp(prefix="first-try-"))
    load = [os.getloadavg()[0]]
    try:
        env = dict(os.environ, DEEPC_CACHE=str(tmp / "cache-info"))
        info = [measure_info(label, path, args.repeats, env) for label, path in paths.items()
                if label != args.mismatch]
        mismatch = measure_mismatch(args.mismatch, paths[args.mismatch], args.repeats, paths, tmp) \
            if args.mismatch else None
        load.append(os.getloadavg()[0])
        undistortion = measure_undistortion(args.undistort, paths[args.undistort], paths, tmp) \
            if args.undistort else None
        load.append(os.getloadavg()[0])
        run = measure_run(args.run, paths[args.run], args.stop_delay, paths, tmp, not args.no_stop) \
            if args.run else None
        load.append(os.getloadavg()[0])
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    rows = targets(info, mismatch, undistortion, run, described)
    bench.print_table(rows, title="issue 46 targets")
    note = (f"1-minute load average at the start and after each part: {', '.join(f'{x:.1f}' for x in load)} "
            f"(a shared {os.cpu_count()}-core machine; other sessions' jobs run beside)")
    print(note)
    bench.write_result({"workspaces": list(described.values()), "info": info, "mismatch": mismatch,
                        "undistortion": undistortion, "run": run, "targets": rows, "load_note": note}, args.json)


if __name__ == "__main__":
    main()
