"""Shared test rigs: the shipped configs, copies of them with sections changed, and the
simulated TMS rig without noise. The fixtures in ``tests/conftest.py`` wrap these; import them
directly where a module-level helper needs them.

Frames and units as everywhere: 4×4 poses in mm (``docs/conventions.md``).
"""

from __future__ import annotations

import subprocess
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from tmscal.acquisition.progress import Progress
from tmscal.config import load_config, settings_class
from tmscal.sim import TMS_RIG_P0, Noise, SimRig, Truth, simulate, tms_rig_truth
from tmscal.timing import Deadline

REPO = Path(__file__).resolve().parents[1]
CONFIGS = REPO / "tmscal" / "data" / "configs"  # (the top-level configs/ links here)
TOOLS_DIR = CONFIGS / "tools"

#: ``mock.noise`` of a mock config that makes the mock rig exact
NOISE_FREE_MOCK = {"fiducial_sigma_mm": 0.0, "robot_rot_sigma_deg": 0.0,
                   "robot_trans_sigma_mm": 0.0}


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
    portable (``portable_tools``), each keyword a section: a dict updates that section,
    anything else replaces it."""
    data = yaml.safe_load((CONFIGS / base).read_text())
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
