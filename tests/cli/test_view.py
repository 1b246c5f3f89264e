"""`real2sim view`: serves an asset in Meshcat (loopback only unless --host says otherwise) and exits
after --duration-s; a model Drake cannot load, or a port it cannot listen on, is one line and exit 2."""

from __future__ import annotations

import shutil
import socket
from pathlib import Path

import pytest

from real2sim.cli import build_parser, main
from real2sim.cli.view import start_meshcat
from real2sim.geometry.objects import export_object
from tests.cli_helpers import run_cli


@pytest.fixture(scope="module")
def can_asset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("view")
    mesh = export_object("can", root / "can" / "model.obj")
    asset = root / "asset"
    assert main(["asset", str(mesh), "--mass-kg", "0.35", "--out", str(asset), "--collision", "mesh"]) == 0
    return asset




def assert_one_line(code: int, err: str, text: str) -> None:
    lines = [line for line in err.splitlines() if not line.startswith("INFO:drake:")]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert text in lines[0], err


def test_view_serves_asset_then_exits(can_asset, capsys):
    capsys.readouterr()
    assert main(["view", str(can_asset), "--duration-s", "0.2"]) == 0
    out = capsys.readouterr().out
    assert "mesh/model.urdf" in out and "http://127.0.0.1:" in out


def test_view_bad_input(tmp_path, capsys):
    assert main(["view", str(tmp_path / "nope")]) == 2
    assert "asset folder not found" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert main(["view", str(tmp_path / "empty")]) == 2
    assert "no representation" in capsys.readouterr().err


def _listening(port: int) -> set[str]:
    """Local addresses (hex, as /proc/net/tcp* writes them) listening on ``port``."""
    found = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            rows = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for row in rows:
            local, state = row.split()[1], row.split()[3]
            address, hex_port = local.split(":")
            if state == "0A" and int(hex_port, 16) == port:
                found.add(address)
    return found


@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="needs Linux's /proc/net/tcp")
def test_view_listens_on_loopback_only_by_default():
    assert build_parser().parse_args(["view", "x"]).host == "127.0.0.1"
    meshcat = start_meshcat("127.0.0.1", None)
    try:
        assert _listening(meshcat.port()) == {"0100007F"}  # 127.0.0.1, and nothing else
    finally:
        del meshcat
    everywhere = start_meshcat(build_parser().parse_args(["view", "x", "--host", "*"]).host, None)
    try:
        assert _listening(everywhere.port()) & {"00000000", "00000000000000000000000000000000"}
    finally:
        del everywhere


def test_busy_port_is_one_line(can_asset, capsys):
    with socket.socket() as busy:
        busy.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        code, _, err = run_cli(capsys, "view", can_asset, "--port", port, "--duration-s", "0")
    assert_one_line(code, err, f"--port {port}: cannot listen on 127.0.0.1:{port}")


@pytest.mark.parametrize("case, text", [
    ("malformed URDF", "Failed to parse XML"),
    ("URDF without a link", "cannot load"),
    ("missing visual mesh", "does not exist"),
    ("missing collision mesh", "does not exist"),
])
def test_model_drake_cannot_load_is_one_line(case, text, can_asset, tmp_path, capsys):
    asset = Path(shutil.copytree(can_asset, tmp_path / "asset"))
    urdf = asset / "mesh" / "model.urdf"
    if case == "malformed URDF":
        urdf.write_text("<robot><link")
    elif case == "URDF without a link":
        urdf.write_text('<?xml version="1.0"?><robot name="x"><joint name="j" type="fixed"/></robot>')
    elif case == "missing visual mesh":
        (asset / "visual" / "model.obj").unlink()
    else:
        shutil.rmtree(asset / "mesh" / "pieces")
    code, out, err = run_cli(capsys, "view", asset, "--duration-s", "0")
    assert_one_line(code, err, text)
    assert "http://" not in out, "no server for a model that does not load"


# ------------------------------------------------------------------------- issue 33: hangs and addresses


def test_unresolvable_host_is_one_line_at_once(can_asset):
    """Issue 33 #4: a name that does not resolve made Drake's server stall ~200 s (and ignore SIGTERM)
    before saying anything; now it is one line and exit 2 (the subprocess timeout catches a stall)."""
    import subprocess
    import sys

    for name in ("no.such.host.invalid", "nosuchhost"):
        proc = subprocess.run([sys.executable, "-m", "real2sim", "view", str(can_asset), "--host", name,
                               "--duration-s", "1"], capture_output=True, text=True, timeout=60)
        assert_one_line(proc.returncode, proc.stderr, f"--host {name}: no such host")
        assert "http://" not in proc.stdout


def test_stalled_resolver_is_bounded_and_sigterm_stops_the_wait(can_asset):
    """A resolver that never answers: the wait ends after the timeout with one line; SIGTERM during the
    wait stops the command at once (exit 143), since the main thread only waits on a daemon thread."""
    import signal
    import subprocess
    import sys
    import threading

    from real2sim.cli.view import resolve_host
    from real2sim.plumbing.errors import UserInputError

    never = threading.Event()
    with pytest.raises(UserInputError, match="did not resolve within 0.2 s"):
        resolve_host("stalled.example", timeout_s=0.2, resolve=lambda *a, **k: never.wait())
    script = ("import sys, threading, socket\n"
              "def stalled(*args, **kwargs):\n"
              "    print('resolving', flush=True)\n"
              "    threading.Event().wait()\n"
              "socket.getaddrinfo = stalled\n"
              "import real2sim.cli.view as view\n"
              "view.RESOLVE_TIMEOUT_S = 600.0\n"
              "from real2sim.cli import main\n"
              "sys.exit(main(['view', sys.argv[1], '--host', 'stalled.example']))\n")
    proc = subprocess.Popen([sys.executable, "-c", script, str(can_asset)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "resolving"
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert err.strip().splitlines()[-1] == "real2sim: terminated" and "Traceback" not in err, err


def test_every_interface_prints_an_address_a_browser_can_open(can_asset, capsys):
    """Issue 33 #10: --host 0.0.0.0 (or '*') printed http://0.0.0.0:7000, which no browser opens."""
    for host in ("0.0.0.0", "*"):
        capsys.readouterr()
        assert main(["view", str(can_asset), "--host", host, "--duration-s", "0.1"]) == 0
        out = capsys.readouterr().out
        assert "0.0.0.0:" not in out and "http://localhost:" in out and "all interfaces" in out, out


def test_sigterm_while_serving_exits_143(can_asset):
    """Ctrl-C is how a user stops the server (exit 0); SIGTERM was swallowed the same way (exit 0),
    where every other verb exits 143."""
    import signal
    import subprocess
    import sys
    import time

    proc = subprocess.Popen([sys.executable, "-m", "real2sim", "view", str(can_asset), "--duration-s", "600"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().startswith("showing ")
        time.sleep(1.0)  # into the serving loop (the URL is printed just before it)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert err.strip().splitlines()[-1] == "real2sim: terminated", err
