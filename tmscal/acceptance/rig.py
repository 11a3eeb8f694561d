"""The rig under test of the acceptance checks (``docs/acceptance.md``): the devices of a rig
config, built through the driver registry as ``tmscal acquire`` builds them, each check of
:mod:`tmscal.acceptance.checks` run in order with the skips that follow from the config
and from the connect check, and the text report a lab keeps, written whole or not at all.

One implementation for both ways of running the checks: ``tmscal selftest --rig CONFIG``
(:mod:`tmscal.cli.selftest`, from an installed package) and ``pytest tests/acceptance --rig
CONFIG`` (one test per check). A config with a ``mock:`` section is served by mocks that the
caller starts (``tmscal.mocks.launch.spawn_mock_rig``; their endpoints are given here), or
that are already running. Units as in :mod:`tmscal.acceptance.checks`.
"""

from __future__ import annotations

import datetime as dt
import os
import platform
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

from ..acquisition.devices import envelope_for, make_robot, make_tracker
from ..config import RigConfig, load_config
from ..net import split_endpoint
from .checks import (
    CHECK_NAMES,
    Check,
    Settings,
    check_connect,
    check_reconnect,
    check_small_move,
    check_stop,
    check_tools,
    format_report,
)

__all__ = ["RigSelftest", "default_report_path", "write_report"]


class RigSelftest:
    """The acceptance checks on the devices of the config at ``path``.

    ``endpoints``: where mocks started by the caller serve ({"tracker": port or URL,
    "robot": host or host:port}, as ``tmscal mock --json`` prints them), None to use the
    config's own addresses (a real rig, or mocks already running); ``started_mocks`` says
    which for the report. ``frames`` and ``rate_tolerance`` go to :class:`Settings`; the
    mock's fast clock (``mock.clock: fast``) and an in-process device (``real_time`` False:
    the ``sim`` drivers) turn the frame-rate verdict and the stop check off. The devices are
    not opened here: the connect check opens them, :meth:`close` closes them. ``checks``
    holds the checks run so far, in order."""

    def __init__(self, path: str | os.PathLike[str], endpoints: dict[str, str] | None = None,
                 started_mocks: bool = False, frames: int = 100,
                 rate_tolerance: float = 0.10) -> None:
        self.path = Path(path)
        self.cfg: RigConfig = load_config(self.path)
        self.tracker, self.robot = self._devices(endpoints)
        fast = self.cfg.mock is not None and self.cfg.mock.clock == "fast"
        sim = any(d is not None and not d.real_time for d in (self.tracker, self.robot))
        self.settings = Settings(frames=frames, real_time=not (fast or sim),
                                 rate_tolerance=rate_tolerance)
        if sim and not fast:
            self.settings = replace(self.settings, clock="an in-process sim device",
                                    clock_hint="")
        self.meta: dict[str, Any] = {
            "host": platform.node(), "devices": self._devices_note(started_mocks),
            "settings": ", ".join(f"{k}={v}" for k, v in asdict(self.settings).items()
                                  if k not in ("clock", "clock_hint"))}
        self.checks: list[Check] = []

    def _devices_note(self, started: bool) -> str:
        m = self.cfg.mock
        if m is None:
            sim = any(d is not None and not d.real_time for d in (self.tracker, self.robot))
            return "in-process sim devices (docs/devices.md)" if sim else "the rig's devices"
        return (f"mocks started for the checks (clock: {m.clock})" if started
                else f"mocks already running (clock: {m.clock})")

    def _devices(self, ep: dict[str, str] | None) -> tuple[Any, Any]:
        """The configured tracker and robot (None where the config has none), pointed at
        the mock endpoints ``ep`` when given."""
        cfg = self.cfg
        host, port = split_endpoint(ep["robot"]) if ep and ep.get("robot") else (None, None)
        tracker = (make_tracker(cfg, ep.get("tracker") if ep else None)
                   if cfg.tracker is not None else None)
        robot = (make_robot(cfg, envelope_for(cfg, None), host, port)
                 if cfg.robot is not None else None)
        return tracker, robot

    # --- running the checks ------------------------------------------------------------------

    def _missing(self, key: str) -> str | None:
        """Why check ``key`` cannot run (a skip's note), or None."""
        if key == "connect":
            return None
        need = {"tools": ("tracker",), "move": ("robot",), "stop": ("robot",),
                "reconnect": ("tracker", "robot")}[key]
        if not any(getattr(self, kind) is not None for kind in need):
            return f"{self.path} has no {' or '.join(need)} section"
        if not any(c.key == "connect" and c.status == "pass" for c in self.checks):
            return "the connect check did not pass; nothing to test"
        return None

    def run(self, key: str) -> Check:
        """Run the check ``key`` (of ``CHECK_NAMES``), keep it for the report and return it:
        a skip naming why when the config lacks its device or the connect check has not
        passed."""
        if key not in CHECK_NAMES:
            raise KeyError(f"no acceptance check {key!r} (one of {', '.join(CHECK_NAMES)})")
        why = self._missing(key)
        s, cfg = self.settings, self.cfg
        if why is not None:
            c = Check(key, "skip", {}, why)
        elif key == "connect":
            c = check_connect(self.tracker, self.robot)
        elif key == "tools":
            c = check_tools(self.tracker, cfg.sampling.min_share, s)
        elif key == "move":
            c = check_small_move(self.robot, cfg, s)
        elif key == "stop":
            c = check_stop(self.robot, cfg, s)
        else:
            c = check_reconnect(self.tracker, self.robot, s)
        self.checks.append(c)
        return c

    @property
    def passed(self) -> bool:
        """No check failed (skips allowed)."""
        return not any(c.status == "fail" for c in self.checks)

    def close(self) -> None:
        """Stop and close the devices; a failure to close is noted in the report's header
        (``meta["close"]``), never raised: the report is written whatever closing does."""
        for dev in (self.robot, self.tracker):
            if dev is not None:
                try:
                    dev.close()
                except Exception as e:  # noted in the report
                    self.meta.setdefault("close", []).append(f"{dev.name}: {e}")

    def report(self, when: dt.datetime | None = None) -> str:
        """The text report (:func:`tmscal.acceptance.checks.format_report`)."""
        return format_report(str(self.path), self.checks, self.meta, when)

    def __enter__(self) -> RigSelftest:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def default_report_path(folder: str | os.PathLike[str] | None = None,
                        today: dt.date | None = None) -> Path:
    """``acceptance-report-<date>.txt`` in ``folder`` (default: the current folder), with
    ``-2``, ``-3`` … added rather than naming an existing file."""
    where = Path.cwd() if folder is None else Path(folder)
    stem = f"acceptance-report-{(today or dt.date.today()).isoformat()}"
    p, k = where / f"{stem}.txt", 2
    while p.exists():
        p, k = where / f"{stem}-{k}.txt", k + 1
    return p


def write_report(path: str | os.PathLike[str], text: str) -> Path:
    """Write the report whole or not at all (a temporary file in the same folder, then a
    rename); the folder is created. Returns the path."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, out)
    return out
