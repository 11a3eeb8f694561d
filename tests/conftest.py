"""Shared pytest options and fixtures.

``--fuzz-long`` raises the fuzz budget (see ``tests/fuzz.py``); ``--rig CONFIG`` and the other
``--rig-*`` options run the rig acceptance suite, ``tests/acceptance`` (``docs/acceptance.md``).
The fixtures give every test the same rigs (``tests/rigs.py``): ``configs_dir`` and
``tools_dir`` (the shipped configs and tool ROMs), ``sim_rig`` (the built-in TMS rig without
noise, flange at P0), ``mock_config`` (a copy of a shipped mock config with sections changed
and every mock address the test's own, in the test's tmp_path) and ``loopback_host`` (a
loopback address no other test and no other pytest run on the machine gets; with
``tests.rigs.free_port`` where a server cannot take port 0), so that two runs of the suite
side by side never meet on an address.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

import pytest

from tests import rigs
from tmscal.drivers.robot_lock import LOCK_DIR_ENV
from tmscal.sim import SimRig


def pytest_addoption(parser) -> None:
    parser.addoption("--fuzz-long", action="store_true", default=False,
                     help="run every fuzz test with at least 100,000 examples (slow)")
    # the rig acceptance suite, tests/acceptance (docs/acceptance.md)
    group = parser.getgroup("rig acceptance (tests/acceptance, docs/acceptance.md)")
    group.addoption("--rig", metavar="CONFIG", default=None,
                    help="run tests/acceptance against the devices of this rig config "
                         "(without it those tests are skipped)")
    group.addoption("--rig-report", metavar="PATH", default=None,
                    help="where to write the acceptance report (default: "
                         "acceptance-report-<date>.txt in the current folder, never "
                         "overwriting an earlier one)")
    group.addoption("--rig-no-start-mocks", action="store_true", default=False,
                    help="a config with a mock: section is served by mocks that are already "
                         "running (tmscal mock CONFIG); by default the suite starts them")
    group.addoption("--rig-rate-tolerance", metavar="FRACTION", type=float, default=0.10,
                    help="how far the measured tracker frame rate may be from "
                         "tracker.frame_rate_hz, as a fraction (default 0.10: 10 %%)")
    group.addoption("--rig-frames", metavar="N", type=int, default=100,
                    help="distinct tracker frames read by the tool-visibility check "
                         "(default 100)")


def pytest_configure(config) -> None:
    from tests import fuzz
    fuzz.LONG = bool(config.getoption("--fuzz-long"))
    # robot locks (tmscal.drivers.robot_lock) of this test session, and of the processes it
    # starts, in a directory of its own: a suite run elsewhere on the machine at the same time
    # (same user) does not see them
    if not os.environ.get(LOCK_DIR_ENV):
        os.environ[LOCK_DIR_ENV] = tempfile.mkdtemp(prefix="tmscal-test-locks-")
        config._tmscal_lock_dir = os.environ[LOCK_DIR_ENV]


def pytest_unconfigure(config) -> None:
    d = getattr(config, "_tmscal_lock_dir", None)
    if d is not None:
        shutil.rmtree(d, ignore_errors=True)
        os.environ.pop(LOCK_DIR_ENV, None)


def pytest_collection_modifyitems(config, items) -> None:
    """Under ``--fuzz-long`` the per-test timeout is lifted (10⁵ examples take minutes)."""
    if config.getoption("--fuzz-long"):
        for item in items:
            item.add_marker(pytest.mark.timeout(0))


@pytest.fixture
def configs_dir() -> Path:
    """The shipped ``configs/`` directory."""
    return rigs.CONFIGS


@pytest.fixture
def tools_dir() -> Path:
    """The shipped tool ROMs, ``configs/tools/``."""
    return rigs.TOOLS_DIR


@pytest.fixture
def sim_rig() -> SimRig:
    """The built-in TMS rig without noise, the flange at ``TMS_RIG_P0`` (fresh per test)."""
    return rigs.quiet_tms_rig()


@pytest.fixture
def loopback_host() -> str:
    """A loopback address of this test's own (:func:`tests.rigs.unique_host`): a mock binds
    there with any port, a UR mock's fixed ones included. Call ``tests.rigs.unique_host()``
    for more than one."""
    return rigs.unique_host()


@pytest.fixture
def mock_config(tmp_path: Path) -> Callable[..., Path]:
    """Factory ``mock_config(base, **changes) -> Path``: ``configs/<base>`` copied into the
    test's tmp_path, every mock address the test's own, with sections changed (see
    :func:`tests.rigs.write_config`)."""
    def make(base: str, **changes) -> Path:
        return rigs.write_config(tmp_path, base, **changes)
    return make
