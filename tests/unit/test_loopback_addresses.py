"""The test suite's one source of mock addresses (``tests/rigs.py``): every address handed out
is new within the process and not handed to another pytest process, and a shipped config
copied for a test keeps none of its fixed mock addresses."""

from __future__ import annotations

import ipaddress
import json
import re
import socket
import subprocess
import sys

import pytest
import yaml

from tests.rigs import CONFIGS, REPO, free_port, unique_addresses, unique_host, write_config
from tmscal.config import load_config

#: a loopback address as the configs write them
ADDRESS = r"127(?:\.\d{1,3}){3}|localhost"


def _octets(host: str) -> tuple[int, ...]:
    return tuple(int(x) for x in host.split("."))


def test_hosts_are_new_loopback_addresses_away_from_127_0() -> None:
    hosts = [unique_host() for _ in range(300)]  # more than one block of 254
    assert len(set(hosts)) == len(hosts)
    for h in hosts:
        assert ipaddress.ip_address(h).is_loopback
        assert _octets(h)[0] == 127 and _octets(h)[1] >= 128 and 1 <= _octets(h)[3] <= 254


def test_another_process_gets_other_addresses() -> None:
    mine = {unique_host() for _ in range(10)}  # this process holds its block now
    code = ("import json; from tests.rigs import unique_host; "
            "print(json.dumps([unique_host() for _ in range(300)]))")
    r = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    theirs = set(json.loads(r.stdout))
    assert len(theirs) == 300 and not theirs & mine
    # and not in a block of ours: the blocks are claimed per process
    assert not {_octets(h)[:3] for h in theirs} & {_octets(h)[:3] for h in mine}


def test_a_unique_host_takes_a_ur_mocks_fixed_ports() -> None:
    host = unique_host()
    with socket.socket() as a, socket.socket() as b:
        a.bind((host, 30004))  # RTDE's fixed port, on an address no one else binds
        b.bind((host, free_port(host)))


@pytest.mark.parametrize("name", sorted(p.name for p in CONFIGS.glob("mock-*.yaml")))
def test_every_mock_address_of_a_shipped_config_is_replaced(name) -> None:
    shipped = yaml.safe_load((CONFIGS / name).read_text())
    copied = unique_addresses(yaml.safe_load((CONFIGS / name).read_text()))

    def devices(d: dict, host: str | None = None) -> str:
        sections = {k: {f: v for f, v in d[k].items() if f != "tools"}
                    for k in ("robot", "tracker", "ft") if k in d}
        text = yaml.safe_dump(sections)
        return text if host is None else re.sub(ADDRESS, host, text)

    assert "127.0." not in devices(copied) and "localhost" not in devices(copied)
    assert len(re.findall(ADDRESS, devices(copied))) == len(re.findall(ADDRESS,
                                                                       devices(shipped)))
    # nothing else changed: the same keys and values, ports included
    assert devices(copied, "HOST") == devices(shipped, "HOST")


def test_a_copied_config_loads_with_its_own_addresses(tmp_path) -> None:
    cfg = load_config(write_config(tmp_path, "mock-ur-ati.yaml"))
    assert cfg.robot is not None and cfg.ft is not None and cfg.tracker is not None
    hosts = [cfg.robot.host, cfg.ft.host, cfg.tracker.settings.address().split("//")[1]]
    assert all(_octets(h.split(":")[0])[1] >= 128 for h in hosts), hosts


def test_only_loopback_addresses_of_device_sections_change() -> None:
    data = unique_addresses({"robot": {"host": "127.0.0.2", "driver": "ur"},
                             "ft": {"host": "robot"}, "name": "127.0.0.1 in a name"})
    assert data["ft"]["host"] == "robot" and data["name"] == "127.0.0.1 in a name"
    assert _octets(data["robot"]["host"])[1] >= 128
