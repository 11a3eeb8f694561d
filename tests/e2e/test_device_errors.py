"""Device errors a technician can act on: one line naming what failed and what to check, on
real sockets and ptys (a loopback address where nothing listens, a port whose backlog is full
so that a connect gets no answer, a pty that never answers, a mock address already taken).
The UR cases run ``tmscal robot`` in a child process, so that anything ur_rtde would print
on the process's own stderr is seen too."""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from tmscal.config import load_config
from tmscal.drivers.ndi.tracker import NDITracker
from tmscal.drivers.ur.calls import RTDE_PORT
from tmscal.errors import DeviceTimeout
from tmscal.mocks.launch import start_mock_rig

from ..rigs import CONFIGS, TOOLS_DIR, unique_host

pytestmark = pytest.mark.e2e

ROMS = {"marker": TOOLS_DIR / "marker-8700340.rom", "probe": TOOLS_DIR / "probe-8700340.rom"}


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "tmscal.cli", *args], text=True,
                          capture_output=True, stdin=subprocess.DEVNULL, timeout=120)


def _ur_config(tmp_path: Path, host: str) -> Path:
    """The shipped UR + Polaris template with the robot at ``host`` (``tmscal robot`` reads
    no tracker file)."""
    data = yaml.safe_load((CONFIGS / "ur-polaris.yaml").read_text())
    data["robot"]["host"] = host
    p = tmp_path / "ur.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


@contextlib.contextmanager
def unanswered_port(host: str, port: int) -> Iterator[None]:
    """A listening socket on ``host:port`` that accepts nothing, its backlog filled: a new
    connection's SYN is dropped, so a connect waits and times out (as for an address where
    no device answers)."""
    srv = socket.socket()
    held = [srv]
    try:
        srv.bind((host, port))
        srv.listen(0)
        for _ in range(16):
            c = socket.socket()
            held.append(c)
            c.settimeout(0.5)
            try:
                c.connect((host, port))
            except TimeoutError:
                break
        else:
            pytest.fail("the backlog never filled")
        yield
    finally:
        for s in held:
            s.close()


def _one_line(r: subprocess.CompletedProcess[str]) -> str:
    lines = [ln for ln in (r.stdout + r.stderr).splitlines() if ln.strip()]
    assert r.returncode == 1 and len(lines) == 1, (r.returncode, r.stdout, r.stderr)
    assert lines[0].startswith("error: ")
    return lines[0]


def test_ur_refused_is_one_line_naming_the_address_and_what_to_check(tmp_path) -> None:
    host = unique_host()   # nothing listens there
    line = _one_line(_cli("robot", str(_ur_config(tmp_path, host))))
    assert f"ur {host}: " in line and f"port {RTDE_PORT}" in line
    assert "connection refused" in line and "robot.host" in line and "booting" in line
    assert "Timeout" not in line  # ur_rtde's "Timeout connecting" for a refusal is gone


def test_ur_no_answer_is_told_apart_from_a_refusal(tmp_path) -> None:
    host = unique_host()
    with unanswered_port(host, RTDE_PORT):
        line = _one_line(_cli("robot", str(_ur_config(tmp_path, host))))
    assert f"ur {host}: " in line and "no answer within" in line
    assert "refused" not in line
    for what in ("robot.host", "cable", "powered on", "subnet"):
        assert what in line, what


class _SilentPty:
    """A pty whose far end reads everything and never answers; ``sent`` holds what arrived."""

    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        self.path = os.ttyname(self.slave)
        self.sent = bytearray()
        self._t = threading.Thread(target=self._drain, daemon=True)
        self._t.start()

    def _drain(self) -> None:
        while True:
            try:
                b = os.read(self.master, 1024)
            except OSError:
                return
            if not b:
                return
            self.sent.extend(b)

    def close(self) -> None:
        os.close(self.slave)
        os.close(self.master)
        self._t.join(5)


@pytest.mark.parametrize("baud, rates", [(115200, "9600 and 115200"), (9600, "9600")])
def test_ndi_port_where_nothing_answers_fails_naming_what_to_check(baud, rates) -> None:
    pty = _SilentPty()
    try:
        tr = NDITracker(pty.path, ROMS, baud=baud, retries=3, timeout_s=0.2,
                        reset_timeout_s=0.2, init_timeout_s=0.2)
        with pytest.raises(DeviceTimeout) as e:
            tr.open()
        assert not tr.is_open
    finally:
        pty.close()
    msg = str(e.value)
    assert f"nothing answered on {pty.path}" in msg and f"INIT at {rates} baud" in msg
    for what in ("powered on", "cable", "tracker.port", f"tracker.baud: {baud}"):
        assert what in msg, what
    # no re-sends into a line where nothing ever answered: one INIT per baud rate
    assert bytes(pty.sent).count(b"INIT:") == (2 if baud != 9600 else 1), bytes(pty.sent)


def test_ndi_tcp_tracker_that_never_answers_names_the_address() -> None:
    host = unique_host()
    srv = socket.socket()
    srv.bind((host, 0))
    srv.listen(1)
    port = f"socket://{host}:{srv.getsockname()[1]}"
    try:
        tr = NDITracker(port, ROMS, timeout_s=0.2, init_timeout_s=0.2, reset=False)
        with pytest.raises(DeviceTimeout, match=f"nothing answered on {port} .*tracker.port"):
            tr.open()
    finally:
        srv.close()


def test_second_mock_on_a_taken_address_names_address_and_port(mock_config) -> None:
    cfg_path = mock_config("mock-ur-polaris.yaml")
    cfg = load_config(cfg_path)
    taken = cfg.tracker.settings.address().removeprefix("socket://")
    with start_mock_rig(cfg):
        line = _one_line(_cli("mock", str(cfg_path)))
    assert f"cannot listen on {taken} (TCP)" in line and "already in use" in line
    assert "tmscal mock" in line  # says what is probably holding it
