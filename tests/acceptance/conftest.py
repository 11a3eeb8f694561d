"""The rig under test for ``tests/acceptance``: the ``--rig CONFIG`` config's devices and checks
as ``tmscal selftest`` runs them (``tmscal.acceptance.rig.RigSelftest``, the one
implementation), opened by the first check and closed at the end of the session, and the
report a lab keeps (``--rig-report``).

A config with a ``mock:`` section is served by mocks the suite starts itself (``tmscal mock``
in a child process, ``tmscal.mocks.launch.spawn_mock_rig``) unless ``--rig-no-start-mocks``
says they are already running. See ``docs/acceptance.md``.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tmscal.acceptance.checks import Check
from tmscal.acceptance.rig import RigSelftest, default_report_path, write_report
from tmscal.config import load_config

NO_RIG = ("no --rig CONFIG given: the rig acceptance suite runs only against a rig config "
          "(pytest tests/acceptance --rig my-rig.yaml, or tmscal selftest --rig my-rig.yaml; "
          "docs/acceptance.md)")

_REPORT = pytest.StashKey[tuple[Path, str]]()


class RigUnderTest:
    """The checks of ``tmscal selftest`` on the rig, one per test."""

    def __init__(self, selftest: RigSelftest) -> None:
        self.selftest = selftest

    def check(self, key: str) -> None:
        """Run one check (``RigSelftest.run``), print it (seen with -s or on failure), and
        skip or fail the test as it says; a failure lists the measured values."""
        c: Check = self.selftest.run(key)
        print(c.summary())
        for k, v in c.values.items():
            print(f"    {k}: {v}")
        if c.status == "skip":
            pytest.skip(c.note)
        assert c.status == "pass", f"{c.summary()} (measured: {c.values})"


@pytest.fixture(scope="session")
def rig(request: pytest.FixtureRequest) -> Iterator[RigUnderTest]:
    """The rig under test; skips every acceptance test when no ``--rig`` is given."""
    opt = request.config.getoption
    if not opt("--rig"):
        pytest.skip(NO_RIG)
    path = Path(opt("--rig"))
    start = load_config(path).mock is not None and not opt("--rig-no-start-mocks")
    mocks = None
    if start:
        from tmscal.mocks.launch import spawn_mock_rig
        mocks = spawn_mock_rig(path, transport="tcp")
    st: RigSelftest | None = None
    try:
        st = RigSelftest(path, mocks.endpoints if mocks else None, started_mocks=start,
                         frames=opt("--rig-frames"), rate_tolerance=opt("--rig-rate-tolerance"))
        yield RigUnderTest(st)
    finally:
        if st is not None:
            st.close()
            text = st.report()
            opt_path = opt("--rig-report")
            out = write_report(opt_path if opt_path else default_report_path(), text)
            request.config.stash[_REPORT] = (out, text)
        if mocks is not None:
            mocks.close()


def pytest_terminal_summary(terminalreporter: Any, exitstatus: int, config: pytest.Config) \
        -> None:
    """Print the acceptance report and where it was written."""
    if _REPORT not in config.stash:
        return
    out, text = config.stash[_REPORT]
    terminalreporter.section("rig acceptance report")
    terminalreporter.write(text)
    terminalreporter.write_line(f"report written to {out}")
