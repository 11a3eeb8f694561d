"""Shared test rigs: the shipped configs, copies of them with sections changed and every mock
address made the test's own, loopback addresses and free ports unique to a test, and the
simulated TMS rig without noise. The fixtures in ``tests/conftest.py`` wrap these; import them
directly where a module-level helper needs them.

Frames and units as everywhere: 4×4 poses in mm (``docs/conventions.md``).
"""

from __future__ import annotations

import fcntl
import os
import re
import socket
import subprocess
import tempfile
import threading
import time
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from tmscal.acquisition.progress import Progress
from tmscal.config import load_config, settings_class
from tmscal.registry import KINDS
from tmscal.sim import TMS_RIG_P0, Noise, SimRig, Truth, simulate, tms_rig_truth
from tmscal.timing import Deadline

REPO = Path(__file__).resolve().parents[1]
CONFIGS = REPO / "tmscal" / "data" / "configs"  # (the top-level configs/ links here)
TOOLS_DIR = CONFIGS / "tools"

#: ``mock.noise`` of a mock config that makes the mock rig exact
NOISE_FREE_MOCK = {"fiducial_sigma_mm": 0.0, "robot_rot_sigma_deg": 0.0,
                   "robot_trans_sigma_mm": 0.0}


# --- loopback addresses and ports of a test's own ---------------------------------------------
#
# Two test runs on one machine (two checkouts, `make test` twice, xdist workers) must not bind
# the same address: a UR mock needs a loopback address of its own (ur_rtde's ports are fixed:
# 29999, 30001-30004, 50002), and a fixed port on a shared address is taken by whichever run
# binds it first. Every pytest process claims blocks of 254 addresses 127.<a>.<b>.1-254
# (a ≥ 128, far from the 127.0.x.x of the shipped configs and of a `tmscal mock` a user runs)
# by holding an flock on a file per block in a directory shared by the user's processes; the
# lock goes with the process. Each call of ``unique_host`` then hands out the next address of
# the process's block, so an address is unique per test and per process.

_BLOCK_DIR = Path(tempfile.gettempdir()) / f"tmscal-test-loopback-{os.getuid()}"
_BLOCKS = [(a, b) for a in range(128, 255) for b in range(256)]
_claim = threading.Lock()
_held: list[int] = []  # the descriptors whose flocks hold this process's blocks
_hosts: Any = iter(())


def _claim_block() -> tuple[int, int]:
    """A block (a, b) no other live process holds, claimed for this process's lifetime;
    the search starts at a place given by the pid, so concurrent runs rarely meet."""
    _BLOCK_DIR.mkdir(mode=0o700, exist_ok=True)
    start = zlib.crc32(f"{os.getpid()}:{len(_held)}".encode()) % len(_BLOCKS)
    for i in range(len(_BLOCKS)):
        a, b = _BLOCKS[(start + i) % len(_BLOCKS)]
        fd = os.open(_BLOCK_DIR / f"127.{a}.{b}.lock", os.O_RDWR | os.O_CREAT, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            continue
        os.set_inheritable(fd, False)
        _held.append(fd)
        return a, b
    raise RuntimeError(f"every loopback block under {_BLOCK_DIR} is held by another process")


def unique_host() -> str:
    """A loopback address (``127.a.b.c``, a ≥ 128) that no other call of this process and no
    other process using this helper gets: a mock binds there with any port, fixed ones
    included, without meeting another test's."""
    global _hosts
    with _claim:
        host = next(_hosts, None)
        if host is None:
            a, b = _claim_block()
            _hosts = (f"127.{a}.{b}.{c}" for c in range(1, 255))
            host = next(_hosts)
        return host


def free_port(host: str = "127.0.0.1", udp: bool = False) -> int:
    """A TCP (or UDP) port free on ``host`` now, for a server that cannot report the port it
    bound to (where it can, give it port 0 instead). On a ``unique_host`` address nothing
    else binds, so the port stays free for the test."""
    kind = socket.SOCK_DGRAM if udp else socket.SOCK_STREAM
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, kind) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


#: a loopback address in a config value: "127.0.0.2", "socket://127.0.0.1:8765", "localhost"
_LOOPBACK = re.compile(r"(?<![\w.])(?:127(?:\.\d{1,3}){3}|localhost)(?![\w.])")


def unique_addresses(data: dict[str, Any]) -> dict[str, Any]:
    """``data`` (a parsed rig config) with every loopback address in its device sections
    (``robot``, ``tracker``, ``ft``: any key, any driver) replaced by a ``unique_host`` of its
    own, ports kept: ``host: 127.0.0.2`` → ``host: 127.130.7.1``, ``port:
    socket://127.0.0.1:8765`` → ``socket://127.130.7.2:8765``. Changed in place; returned."""
    def rewrite(v: Any) -> Any:
        if isinstance(v, str):
            return _LOOPBACK.sub(lambda _: unique_host(), v)
        if isinstance(v, dict):
            return {k: rewrite(x) for k, x in v.items()}
        if isinstance(v, list):
            return [rewrite(x) for x in v]
        return v

    for kind in KINDS:
        if isinstance(data.get(kind), dict):
            data[kind] = rewrite(data[kind])
    return data


def portable_tools(data: dict[str, Any], base_dir: Path) -> None:
    """Make ``data``'s ``tracker.tools`` load from any folder: each value as the tracker
    driver reads it from ``base_dir`` (its settings' ``parse_tool``: an NDI's ROM file made
    absolute, an OpenIGTLink TRANSFORM name kept). No tracker section: nothing to do."""
    t = data.get("tracker")
    if not t or not t.get("tools"):
        return
    cls = settings_class("tracker", t.get("driver", "ndi"))
    t["tools"] = {k: cls.parse_tool(k, v, "<test>", base_dir, False)
                  for k, v in t["tools"].items()}


def write_config(tmp_path: Path, base: str, **changes: Any) -> Path:
    """A copy of the shipped config ``configs/<base>`` in ``tmp_path``, tool values made
    portable (``portable_tools``), every mock address made the test's own
    (``unique_addresses``), then each keyword a section: a dict updates that section,
    anything else replaces it."""
    data = unique_addresses(yaml.safe_load((CONFIGS / base).read_text()))
    portable_tools(data, CONFIGS)
    for section, values in changes.items():
        if isinstance(values, dict) and isinstance(data.get(section), dict):
            data[section].update(values)
        else:
            data[section] = values
    p = tmp_path / f"rig-{base}"
    p.write_text(yaml.safe_dump(data))
    return p


def point_config(cfg_path: Path, ep: dict[str, str], name: str = "run.yaml") -> Path:
    """A copy of a config whose tracker and robot addresses are the running mocks': the
    tracker's through its driver's settings (``with_address``: an NDI's ``port``, an
    OpenIGTLink source's ``host`` and ``port``)."""
    data = yaml.safe_load(cfg_path.read_text())
    tracker = load_config(cfg_path, check_files=False).tracker
    if tracker is not None and "tracker" in ep:
        moved = tracker.settings.with_address(ep["tracker"])
        for key in moved.KEYS:
            if getattr(moved, key) != getattr(tracker.settings, key):
                data["tracker"][key] = getattr(moved, key)
    host, _, port = ep["robot"].partition(":")
    data["robot"]["host"] = host
    if port:
        data["robot"]["port"] = int(port)
    out = cfg_path.parent / name
    out.write_text(yaml.safe_dump(data))
    return out


class SeenPoses(Progress):
    """A run's Progress that keeps the session index of every pose saved, in ``seen`` (the
    list given, so that a ``should_stop`` can look at it)."""

    def __init__(self, seen: list[int] | None = None) -> None:
        self.seen = [] if seen is None else seen

    def pose(self, done: int, total: int, record: Any) -> None:
        self.seen.append(record.index)


def endpoints_kwargs(ep: dict[str, str]) -> dict[str, Any]:
    """``acquire``'s endpoint overrides (tracker_port, robot_host, robot_port) for the
    endpoints of a running mock rig."""
    host, _, port = ep["robot"].partition(":")
    return {"tracker_port": ep["tracker"], "robot_host": host,
            "robot_port": int(port) if port else None}


def quiet_tms_rig(**kw: Any) -> SimRig:
    """The built-in TMS rig (``tms_rig_truth``) without noise, the flange at ``TMS_RIG_P0``;
    keywords override SimRig's fields."""
    kw.setdefault("noise", Noise.none())
    kw.setdefault("start", TMS_RIG_P0)
    return SimRig(tms_rig_truth(), **kw)


def simulated(n: int, seed: int = 0, plan: str = "eq14", noise: Noise | None = None,
              **kw: Any) -> tuple[Truth, dict[str, np.ndarray]]:
    """``tmscal.sim.simulate`` of n poses from ``default_rng(seed)`` (default noise: the
    paper's); returns (truth, {"A", "commanded", "marker"[, "probe"]}) in mm."""
    return simulate(n, np.random.default_rng(seed), plan=plan,
                    noise=Noise() if noise is None else noise, **kw)


def wait_for_lines(path: Path, lines: int, proc: subprocess.Popen, timeout_s: float = 60.0,
                   poll_s: float = 0.01) -> int:
    """Wait until the file at ``path`` holds at least ``lines`` complete lines, the process
    ends, or ``timeout_s`` passes; returns the lines counted last (0 if the file is absent)."""
    deadline = Deadline(timeout_s)
    count = 0
    while not deadline.expired() and proc.poll() is None:
        if path.exists():
            count = path.read_bytes().count(b"\n")
            if count >= lines:
                break
        time.sleep(poll_s)
    return count


def wait_until(pred: Any, timeout_s: float, what: str, poll_s: float = 0.002) -> None:
    """Poll ``pred()`` until true; AssertionError naming ``what`` after ``timeout_s`` s (a
    guard against a hang, not a timing assertion)."""
    deadline = Deadline(timeout_s)
    while not pred():
        assert not deadline.expired(), f"timed out after {timeout_s:.1f} s waiting for {what}"
        time.sleep(poll_s)
