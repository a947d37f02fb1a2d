"""`deepc view`'s errors: one line each, exit 2; a busy port is announced, never viser's raw logs."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from workbench.cli.main import main

ROOT = Path(__file__).resolve().parents[1]


def test_a_missing_path_is_one_line_and_exit_2(capsys, tmp_path):
    assert main(["view", str(tmp_path / "nonexistent")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"deepc: error: {tmp_path / 'nonexistent'}: does not exist"


@pytest.mark.timeout(120)
def test_a_busy_port_is_announced_with_the_port_used_instead(fake_run):
    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen()
    port = busy.getsockname()[1]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-m", "workbench.cli", "view", str(fake_run), "--port", str(port)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=ROOT,
                            start_new_session=True)
    lines = []
    try:
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line.rstrip())
            if line.startswith("viewer: http"):
                break
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            rest, _ = proc.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            rest, _ = proc.communicate(timeout=10)
        busy.close()
    output = lines + rest.splitlines()
    assert lines[0].startswith(f"viewer: port {port} is in use; serving on port "), output
    used = int(lines[0].split("serving on port ")[1].split()[0])
    assert used != port and lines[1] == f"viewer: http://127.0.0.1:{used}  (Ctrl+C to stop)", output
    assert not any("viser" in line or "╭" in line for line in output), output  # no banner, no raw logs
