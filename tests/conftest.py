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

The suite runs in parallel (``make test``: pytest-xdist, ``-n auto --dist loadfile``): each
worker process has its own loopback blocks (``tests/rigs.py``), robot-lock directory
(``TMSCAL_LOCK_DIR``) and tmp dirs; a test file runs whole on one worker, so a module-scoped
fixture is built once. BLAS libraries run one thread per process (``OPENBLAS_NUM_THREADS`` and
the like, set below before anything imports numpy): OpenBLAS's busy-waiting threads starved the
mock servers on a 2-core machine.
"""

from __future__ import annotations

import os

# before numpy is imported (tests.rigs imports it), here and in every process started from here
# (xdist workers, CLI children): one BLAS thread per process
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import shutil  # noqa: E402
import tempfile  # noqa: E402
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402

import pytest  # noqa: E402

from tests import rigs  # noqa: E402
from tests.slow import is_slow  # noqa: E402
from tmscal.drivers.robot_lock import LOCK_DIR_ENV  # noqa: E402
from tmscal.sim import SimRig  # noqa: E402


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
    # (same user) does not see them. An xdist worker (which inherits the controller's) takes
    # one of its own, so that two workers' tests never meet on a lock either.
    worker = getattr(config, "workerinput", None)
    if worker is not None or not os.environ.get(LOCK_DIR_ENV):
        tag = f"{worker['workerid']}-" if worker is not None else ""
        os.environ[LOCK_DIR_ENV] = tempfile.mkdtemp(prefix=f"tmscal-test-locks-{tag}")
        config._tmscal_lock_dir = os.environ[LOCK_DIR_ENV]


def pytest_unconfigure(config) -> None:
    d = getattr(config, "_tmscal_lock_dir", None)
    if d is not None:
        shutil.rmtree(d, ignore_errors=True)
        os.environ.pop(LOCK_DIR_ENV, None)


def pytest_collection_modifyitems(config, items) -> None:
    """``e2e`` / ``interop`` on every test under ``tests/e2e`` / ``tests/interop`` (so that
    ``-m "not e2e"`` leaves them all out), ``slow`` on the tests ``tests/slow.py`` lists (``-m
    "not slow"``: the fast part); under ``--fuzz-long`` the per-test timeout is lifted (10⁵
    examples take minutes)."""
    for item in items:
        module = item.nodeid.split("::", 1)[0]
        for folder in ("e2e", "interop"):
            if module.startswith(f"tests/{folder}/") and item.get_closest_marker(folder) is None:
                item.add_marker(getattr(pytest.mark, folder))
        if is_slow(item.nodeid) and item.get_closest_marker("slow") is None:
            item.add_marker(pytest.mark.slow)
        if config.getoption("--fuzz-long"):
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
