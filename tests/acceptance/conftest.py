"""The rig under test for ``tests/acceptance``: the devices of the ``--rig CONFIG`` config,
built through the driver registry like ``tmscal acquire`` builds them, opened by the first
check and closed at the end of the session, and the report a lab keeps (``--rig-report``).

A config with a ``mock:`` section is served by mocks the suite starts itself (``tmscal mock``
in a child process, ``tmscal.mocks.launch.spawn_mock_rig``) unless ``--rig-no-start-mocks``
says they are already running. See ``docs/acceptance.md``.
"""

from __future__ import annotations

import datetime as dt
import os
import platform
from collections.abc import Callable, Iterator
from dataclasses import asdict
from pathlib import Path
from typing import Any

import pytest

from tmscal.acquisition.devices import envelope_for, make_robot, make_tracker
from tmscal.acquisition.selftest import Check, Settings, format_report
from tmscal.config import RigConfig, load_config

NO_RIG = ("no --rig CONFIG given: the rig acceptance suite runs only against a rig config "
          "(pytest tests/acceptance --rig my-rig.yaml; docs/acceptance.md)")

_REPORT = pytest.StashKey[tuple[Path, str]]()


class RigUnderTest:
    """The config, its (not yet opened) devices, the settings of the checks and the checks
    run so far, in order."""

    def __init__(self, path: Path, cfg: RigConfig, settings: Settings, tracker: Any,
                 robot: Any, meta: dict[str, Any]) -> None:
        self.path, self.cfg, self.settings = path, cfg, settings
        self.tracker, self.robot, self.meta = tracker, robot, meta
        self.checks: list[Check] = []

    def run(self, fn: Callable[..., Check], *args: Any) -> Check:
        """Run one check, keep it for the report, print it (seen with -s or on failure)."""
        c = fn(*args)
        self.checks.append(c)
        print(c.summary())
        for k, v in c.values.items():
            print(f"    {k}: {v}")
        return c

    def need(self, kind: str) -> Any:
        """The opened tracker or robot; a skip naming why when it is absent or not open."""
        dev = getattr(self, kind)
        if dev is None:
            pytest.skip(f"{self.path} has no {kind} section")
        if not any(c.key == "connect" and c.status == "pass" for c in self.checks):
            pytest.skip("the connect check did not pass; nothing to test")
        return dev

    @staticmethod
    def verdict(c: Check) -> None:
        """Skip or fail the test as the check says; the failure lists the measured values."""
        if c.status == "skip":
            pytest.skip(c.note)
        assert c.status == "pass", f"{c.summary()} (measured: {c.values})"


def _report_path(option: str | None) -> Path:
    """``--rig-report`` as given, else ``acceptance-report-<date>.txt`` in the current folder,
    with ``-2``, ``-3`` … added rather than overwriting an earlier report."""
    if option:
        return Path(option)
    stem = f"acceptance-report-{dt.date.today().isoformat()}"
    p, k = Path.cwd() / f"{stem}.txt", 2
    while p.exists():
        p, k = Path.cwd() / f"{stem}-{k}.txt", k + 1
    return p


def _devices(cfg: RigConfig, ep: dict[str, str] | None) -> tuple[Any, Any]:
    """The configured tracker and robot (None where the config has none), pointed at the mock
    endpoints ``ep`` when the suite started the mocks."""
    tport = ep.get("tracker") if ep else None
    host, port = None, None
    if ep and ep.get("robot"):
        host, _, p = ep["robot"].partition(":")
        port = int(p) if p else None
    tracker = make_tracker(cfg, tport) if cfg.tracker is not None else None
    robot = (make_robot(cfg, envelope_for(cfg, None), host, port)
             if cfg.robot is not None else None)
    return tracker, robot


@pytest.fixture(scope="session")
def rig(request: pytest.FixtureRequest) -> Iterator[RigUnderTest]:
    """The rig under test; skips every acceptance test when no ``--rig`` is given."""
    opt = request.config.getoption
    if not opt("--rig"):
        pytest.skip(NO_RIG)
    path = Path(opt("--rig"))
    cfg = load_config(path)
    start = cfg.mock is not None and not opt("--rig-no-start-mocks")
    fast = cfg.mock is not None and cfg.mock.clock == "fast"
    settings = Settings(frames=opt("--rig-frames"), real_time=not fast,
                        rate_tolerance=opt("--rig-rate-tolerance"))
    meta = {"host": platform.node(),
            "devices": (f"mocks started by the suite (clock: {cfg.mock.clock})" if start
                        else f"mocks already running (clock: {cfg.mock.clock})"
                        if cfg.mock is not None else "the rig's devices"),
            "settings": ", ".join(f"{k}={v}" for k, v in asdict(settings).items())}
    mocks = None
    if start:
        from tmscal.mocks.launch import spawn_mock_rig
        mocks = spawn_mock_rig(path, transport="tcp")
    rut: RigUnderTest | None = None
    try:
        tracker, robot = _devices(cfg, mocks.endpoints if mocks else None)
        rut = RigUnderTest(path, cfg, settings, tracker, robot, meta)
        yield rut
    finally:
        if rut is not None:
            _finish(request.config, rut)
        if mocks is not None:
            mocks.close()


def _finish(config: pytest.Config, rut: RigUnderTest) -> None:
    """Stop and close the devices, write the report (temp file + rename)."""
    for dev in (rut.robot, rut.tracker):
        if dev is not None:
            try:
                dev.close()
            except Exception as e:  # the report is written whatever closing does
                rut.meta.setdefault("close", []).append(f"{dev.name}: {e}")
    text = format_report(str(rut.path), rut.checks, rut.meta)
    out = _report_path(config.getoption("--rig-report"))
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, out)
    config.stash[_REPORT] = (out, text)


def pytest_terminal_summary(terminalreporter: Any, exitstatus: int, config: pytest.Config) \
        -> None:
    """Print the acceptance report and where it was written."""
    if _REPORT not in config.stash:
        return
    out, text = config.stash[_REPORT]
    terminalreporter.section("rig acceptance report")
    terminalreporter.write(text)
    terminalreporter.write_line(f"report written to {out}")
