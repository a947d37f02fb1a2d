"""Vanilla runs of scenes under PatchMatch option sets: the sweeps behind the PatchMatch defaults.

Each configuration runs ``deepc run --pipeline vanilla --schedule S --seed S`` in a child process (with
``--set patchmatch.NAME=VALUE`` per option) on sample scenes and on held-out synthetic scenes
(``engine.synthetic.dataset``), and reports PatchMatch depth metrics and fused F1 at 1 / 2 / 5 cm.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

from engine.run.folder import read_metrics

REPO_ROOT = Path(__file__).resolve().parent.parent


def scene_path(name: str, work: Path) -> Path:
    """A sample scene by name, ``synth_NNNNN`` (that held-out synthetic scene, rendered into ``work``) or a path
    with a '/' (relative to the repository root); a ``@PX`` suffix (the working size) is not part of it."""
    name = name.split("@")[0]
    if name.startswith("synth_"):
        from engine.synthetic.dataset import write_training_scenes

        return write_training_scenes(work / "scenes", [int(name.split("_")[1])])[0]
    if "/" in name:
        return (REPO_ROOT / name).resolve()
    return REPO_ROOT / "sample_scenes" / name


def scene_size(name: str) -> int | None:
    """The working size (``--max-image-size``) a scene name's ``@PX`` suffix asks for; None: the default."""
    return int(name.split("@")[1]) if "@" in name else None


def run(scene: Path, config: str, options: dict[str, float], work: Path, seed: int = 0, schedule: str = "acmm",
        max_image_size: int | None = None) -> dict:
    """``deepc run --pipeline vanilla`` of ``scene`` with PatchMatch ``options`` (kept in ``work`` under the
    configuration's name and reused when its metrics.json exists); its depth metrics, F1 and seconds (the CPU
    seconds of the whole run's process, None for a run made earlier). ``max_image_size``: the working size (None:
    the default)."""
    out = work / "runs" / (f"{scene.name}_{config}" + (f"_seed{seed}" if seed else "")
                           + (f"_{schedule}" if schedule != "acmm" else "")
                           + (f"_{max_image_size}" if max_image_size is not None else ""))
    cpu = None
    if not (out / "metrics.json").exists():
        cmd = [sys.executable, "-m", "workbench.cli", "run", str(scene), "--out", str(out), "--pipeline", "vanilla",
               "--headless", "--schedule", schedule, "--seed", str(seed)]
        if max_image_size is not None:
            cmd += ["--max-image-size", str(max_image_size)]
        for key, value in options.items():
            cmd += ["--set", f"patchmatch.{key}={value}"]
        env = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        proc = subprocess.run(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
        if proc.returncode != 0:
            lines = proc.stderr.strip().splitlines() or ["(no message)"]
            raise SystemExit(f"{scene} ({config}): deepc run failed: {lines[-1]}")
    metrics = read_metrics(out)
    tol = metrics["eval"]["tolerances"]
    f1 = dict(zip(tol, metrics["eval"]["f1"], strict=True))
    return {"within_1pct": metrics["depth"]["within_1pct"], "within_5pct": metrics["depth"]["within_5pct"],
            "valid_fraction": metrics["depth"]["valid_fraction"],
            "f1_1cm": f1.get(0.01), "f1_2cm": f1.get(0.02), "f1_5cm": f1.get(0.05),
            "patchmatch_seconds": metrics["seconds"]["patchmatch"], "cpu_seconds": cpu}


def _num(x: float | None) -> str:
    return f"{x:7.2f}" if x is not None else f"{'-':>7s}"


METRICS_HEADER = (f"{'within1%':>8s} {'within5%':>8s} {'valid%':>6s} {'F1 1cm':>7s} {'F1 2cm':>7s} {'F1 5cm':>7s} "
                  f"{'PM s':>6s}")


def metrics_text(r: dict) -> str:
    """The metric columns of one :func:`run` result (under METRICS_HEADER)."""
    return (f"{r['within_1pct']:8.2f} {r['within_5pct']:8.2f} {r['valid_fraction']:6.1f} {_num(r['f1_1cm'])} "
            f"{_num(r['f1_2cm'])} {_num(r['f1_5cm'])} {r['patchmatch_seconds']:6.1f}")


def sweep(scenes: list[str], configs: dict[str, dict[str, float]], seeds: list[int], schedule: str,
          work: Path | None, schedules: dict[str, str] | None = None) -> list[dict]:
    """Run every configuration ({name: PatchMatch options}) on every scene (:func:`scene_path`, :func:`scene_size`)
    for every seed, printing a table row per run (in a temporary folder when ``work`` is None); returns the rows.
    ``schedules``: a configuration's own schedule (others: ``schedule``)."""
    schedules = schedules or {}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        work = work or Path(tmp)
        print(f"{'scene':12s} {'config':24s} {'seed':>4s} {METRICS_HEADER}")
        for name in scenes:
            scene = scene_path(name, work)
            for config, options in configs.items():
                for seed in seeds:
                    r = {"scene": name, "config": config, "seed": seed, "options": options,
                         **run(scene, config, options, work, seed, schedules.get(config, schedule),
                               scene_size(name))}
                    rows.append(r)
                    print(f"{name:12s} {config:24s} {seed:4d} {metrics_text(r)}", flush=True)
    return rows


def sweep_summary(rows: list[dict]) -> list[dict]:
    """Per scene and configuration, averaged over seeds: depth within 1 %, fused F1 at 1 / 2 cm and the
    PatchMatch seconds (rows of :func:`sweep`; older rows without a seed or F1 count as they are)."""
    groups: dict[tuple[str, str], list[dict]] = {}
    for r in rows:
        groups.setdefault((r.get("scene", "?"), str(r.get("config", r.get("options")))), []).append(r)

    def mean(items: list[dict], key: str) -> float | None:
        values = [r[key] for r in items if r.get(key) is not None]
        return sum(values) / len(values) if values else None

    return [{"scene": scene, "config": config, "seeds": len(items), "within 1 %": mean(items, "within_1pct"),
             "F1 1 cm": mean(items, "f1_1cm"), "F1 2 cm": mean(items, "f1_2cm"),
             "PM s": mean(items, "patchmatch_seconds")} for (scene, config), items in groups.items()]
