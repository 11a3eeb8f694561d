"""The mocks bind to loopback only, checked as addresses (not by spelling): a mock config that
names a non-loopback endpoint gives one ``error:`` line naming it (no traceback) from
``tmscal mock``, nothing is bound, and the servers that do start listen on loopback only."""

from __future__ import annotations

import ipaddress
import socket
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from tests.rigs import free_port, unique_addresses, unique_host
from tmscal.config import load_config
from tmscal.errors import ConfigError
from tmscal.mocks.launch import start_mock_rig
from tmscal.net import loopback_family

from ..rigs import portable_tools

pytestmark = pytest.mark.e2e

ROOT = Path(__file__).resolve().parents[2]
TMSCAL = Path(sys.executable).with_name("tmscal")


def _config(tmp_path: Path, base: str, **changes: Any) -> Path:
    """A copy of ``configs/<base>`` with every mock address the test's own, then ``changes``
    ({"robot.host": …}), its tool values made portable (an NDI's ROM files absolute)."""
    data = unique_addresses(yaml.safe_load((ROOT / "configs" / base).read_text()))
    for key, value in changes.items():
        section, _, field = key.partition(".")
        data[section][field] = value
    portable_tools(data, ROOT / "configs")
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize("host", ["127.0.0.1", "127.3.4.5", "localhost", "::1"])
def test_loopback_addresses_are_accepted(host: str) -> None:
    fam = loopback_family(host, "test")
    assert fam == (socket.AF_INET6 if host == "::1" else socket.AF_INET)


@pytest.mark.parametrize("host", ["0.0.0.0", "::", "8.8.8.8", "10.1.2.3", "::ffff:8.8.8.8",
                                  "2001:db8::1", ""])
def test_other_addresses_are_refused(host: str) -> None:
    with pytest.raises(ConfigError, match="loopback"):
        loopback_family(host, "test endpoint")


@pytest.mark.parametrize("base, changes, named", [
    ("mock-denso-polaris.yaml", {"tracker.port": "socket://0.0.0.0:8799"},
     "key 'tracker.port' (socket://0.0.0.0:8799)"),
    ("mock-denso-polaris.yaml", {"tracker.port": "socket://8.8.8.8:8799"},
     "key 'tracker.port' (socket://8.8.8.8:8799)"),
    ("mock-denso-polaris.yaml", {"robot.host": "0.0.0.0"}, "key 'robot.host' (0.0.0.0)"),
    ("mock-ur-polaris.yaml", {"robot.host": "192.168.56.101"},
     "key 'robot.host' (192.168.56.101)"),
    ("mock-franka-polaris.yaml", {"robot.host": "0.0.0.0"}, "key 'robot.host' (0.0.0.0)"),
    ("mock-ur-igtl.yaml", {"tracker.host": "0.0.0.0"}, "key 'tracker.host' (0.0.0.0:18945)"),
    ("mock-ur-igtl.yaml", {"tracker.host": "::"}, "key 'tracker.host' ([::]:18945)"),
])
def test_tmscal_mock_refuses_non_loopback_endpoints(tmp_path: Path, base: str,
                                                    changes: dict[str, str],
                                                    named: str) -> None:
    cfg = _config(tmp_path, base, **changes)
    proc = subprocess.run([str(TMSCAL), "mock", str(cfg)], capture_output=True, text=True,
                          timeout=60, stdin=subprocess.DEVNULL)
    assert proc.returncode != 0
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), proc.stderr
    assert named in lines[0] and str(cfg) in lines[0]
    assert "Traceback" not in proc.stderr + proc.stdout


def test_nothing_binds_when_one_endpoint_is_refused(tmp_path: Path) -> None:
    host = unique_host()  # for the (loopback) tracker
    port = free_port(host)
    cfg = load_config(_config(tmp_path, "mock-denso-polaris.yaml",
                              **{"tracker.port": f"socket://{host}:{port}",
                                 "robot.host": "0.0.0.0"}))
    with pytest.raises(ConfigError, match="robot.host"):
        start_mock_rig(cfg)
    with pytest.raises(ConnectionRefusedError):  # the tracker was never started
        socket.create_connection((host, port), timeout=5).close()


def _bound(mr: Any) -> list[str]:
    out = []
    for d in mr.devices:
        socks = [getattr(d, "_listener", None), *getattr(d, "_listeners", []),
                 *getattr(d, "_sockets", [])]
        out += [s.getsockname()[0] for s in socks if s is not None]
    return out


@pytest.mark.parametrize("base, changes", [
    # a loopback name: free ports on 127.0.0.1, the address "localhost" names
    ("mock-denso-polaris.yaml", {"tracker.port": "socket://localhost:{}", "robot.port": "{}",
                                 "robot.host": "localhost"}),
    ("mock-ur-polaris.yaml", {}),
    ("mock-franka-polaris.yaml", {}),
    ("mock-ur-igtl.yaml", {}),
])
def test_started_servers_listen_on_loopback_only(tmp_path: Path, base: str,
                                                 changes: dict[str, Any]) -> None:
    filled: dict[str, Any] = {k: v.format(free_port()) for k, v in changes.items()}
    for key in ("robot.port", "tracker.port"):
        if filled.get(key, "").isdigit():
            filled[key] = int(filled[key])
    cfg = load_config(_config(tmp_path, base, **filled))
    with start_mock_rig(cfg) as mr:
        addrs = _bound(mr)
        assert len(addrs) >= 2
        assert all(ipaddress.ip_address(a).is_loopback for a in addrs), addrs
        assert set(mr.endpoints) == {"tracker", "robot"}


@pytest.mark.parametrize("transport", ["tcp", "pty"])
def test_a_tcp_only_tracker_mock_is_served_on_loopback_tcp_whatever_the_transport(
        tmp_path: Path, transport: str) -> None:
    """An OpenIGTLink tracker has no serial line: asked for a pty (or an ephemeral port) the
    mock rig serves it on a loopback TCP port, and the driver's settings take the endpoint
    back as its address (``with_address``, as ``--tracker-port`` does)."""
    cfg = load_config(_config(tmp_path, "mock-ur-igtl.yaml"))
    with start_mock_rig(cfg, tracker_transport=transport) as mr:
        host, _, port = mr.endpoints["tracker"].rpartition(":")
        assert ipaddress.ip_address(host).is_loopback and int(port) != cfg.tracker.settings.port
        moved = cfg.tracker.settings.with_address(mr.endpoints["tracker"])
        assert (moved.host, moved.port) == (host, int(port))
        with socket.create_connection((host, int(port)), timeout=5):
            pass
