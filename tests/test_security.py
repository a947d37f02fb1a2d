"""Security: servers bind 127.0.0.1 by default, GUI file names cannot leave OUT/exports, outputs hold no
secrets from the environment."""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys

import msgspec
import psutil
import pytest
import viser
import websockets
from conftest import REPO, SAMPLES, run_async, running_viewer, wait_for

from support.interruption import FAST
from support.viewer_clients import CAMERA as _CAMERA
from workbench.cli.main import build_parser
from workbench.viewer.export import safe_file_name

TRAVERSALS = ["../../../escaped", "/tmp/escaped_abs", "..\\..\\escaped", "a/../../escaped", "....//....//escaped",
              "%2e%2e%2fescaped", "exports/../../escaped", "~/escaped", "\x00escaped", "..", ".", "", "x" * 500,
              "name\nwith\nlines", "ünïcødé/../../escaped"]


def test_every_server_binds_loopback_by_default():
    parser = build_parser()
    assert parser.parse_args(["view", "out"]).host == "127.0.0.1"
    assert parser.parse_args(["replay", "x.rrd"]).host == "127.0.0.1"
    assert parser.parse_args(["run", "scene", "--out", "o"]).host == "127.0.0.1"


def test_viewer_listens_on_loopback_only(fake_run):
    with running_viewer(fake_run) as app:
        listening = [c for c in psutil.Process().net_connections(kind="inet")
                     if c.status == psutil.CONN_LISTEN and c.laddr.port == app.port]
        assert listening and all(c.laddr.ip == "127.0.0.1" for c in listening)


@pytest.mark.parametrize("name", TRAVERSALS)
def test_safe_file_name_is_a_plain_name(name):
    safe = safe_file_name(name, ".ply")
    assert "/" not in safe and "\\" not in safe and "\x00" not in safe and not safe.startswith(".")
    assert safe.endswith(".ply") and len(safe) <= 84


def test_path_traversal_through_the_export_field_stays_in_exports(fake_run, tmp_path):
    outside = {p for p in fake_run.parent.rglob("*")}
    with running_viewer(fake_run) as app:
        async def attack():
            async with websockets.connect(f"ws://127.0.0.1:{app.port}", subprotocols=[f"viser-v{viser.__version__}"],
                                          max_size=None) as ws:
                await ws.send(msgspec.msgpack.encode(_CAMERA))  # a client counts once it reports its camera
                for name in TRAVERSALS[:6]:
                    for uuid, updates in ((app.export_name._impl.uuid, {"value": name}),
                                          (app.export_button._impl.uuid, {"value": True})):
                        await ws.send(msgspec.msgpack.encode({"type": "GuiUpdateMessage", "uuid": uuid,
                                                              "updates": updates}))
                        await asyncio.sleep(0.3)

        run_async(attack(), timeout=120)
        exports = fake_run / "exports"
        wait_for(lambda: exports.is_dir() and len(list(exports.glob("*.ply"))) >= 1, timeout=60)
        for name in TRAVERSALS:  # and the same names through the method the button calls
            path = app.export_ply(name)
            assert path.parent == exports, path
    created = {p for p in fake_run.parent.rglob("*")} - outside
    assert created and all(exports in p.parents or p == exports for p in created), sorted(created)
    assert not list(fake_run.parent.parent.glob("escaped*")) and not os.path.exists("/tmp/escaped_abs.ply")


def test_outputs_hold_no_secret_from_the_environment(tmp_path):
    secret = "deepc-fake-secret-Zq81xW"
    env = {**os.environ, "PYTHONPATH": str(REPO), "NUMBA_THREADING_LAYER": "workqueue",
           "AWS_SECRET_ACCESS_KEY": secret, "GITHUB_TOKEN": secret + "-gh"}
    out = tmp_path / "out"
    result = subprocess.run([sys.executable, "-m", "workbench.cli", "run", str(SAMPLES / "tiny"), "--out", str(out),
                             "--headless", "--record", *FAST], capture_output=True, text=True, env=env, cwd=REPO,
                            timeout=600)
    assert result.returncode == 0, result.stderr
    files = [p for p in out.rglob("*") if p.is_file()]
    assert any(p.name == "recording.rrd" for p in files) and any(p.name == "metrics.json" for p in files)
    for path in files:
        assert secret.encode() not in path.read_bytes(), path
    assert secret not in result.stdout + result.stderr
