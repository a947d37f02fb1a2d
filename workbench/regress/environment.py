"""Where the numbers of a regression run were measured: versions, machine, load and git revision."""

from __future__ import annotations

import datetime
import importlib.metadata
import os
import platform
import subprocess
from pathlib import Path
from typing import Any

import numba

from engine import __version__

REPO_ROOT = Path(__file__).resolve().parents[2]
#: the packages whose versions can move the numbers
PACKAGES = ("numpy", "numba", "scipy", "torch", "pycolmap", "open3d", "matplotlib", "rerun-sdk")


def environment() -> dict[str, Any]:
    """Where the numbers were measured: versions, machine, git revision of the code."""
    packages = {}
    for name in PACKAGES:
        try:
            packages[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            packages[name] = None
    return {"deepc": __version__, "git": git_revision(), "python": platform.python_version(),
            "platform": platform.platform(), "cpu_count": os.cpu_count(),
            "numba_threads": int(numba.config.NUMBA_NUM_THREADS),
            "load_average": [round(x, 2) for x in os.getloadavg()],
            "packages": packages, "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")}


def git_revision(root: Path = REPO_ROOT) -> str | None:
    """``<commit>`` or ``<commit>+dirty`` of the code being tested; None outside a git checkout."""
    try:
        rev = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True,
                             timeout=10, check=True).stdout.strip()
        # (benchmark results are outputs, not the code: one script's fresh JSON does not make the next one dirty)
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no", "--", ".",
                                ":(exclude)benchmarks/results"],
                               capture_output=True, text=True, timeout=10, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return rev + ("+dirty" if dirty else "")
