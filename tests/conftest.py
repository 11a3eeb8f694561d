"""Shared pytest options and fixtures.

``--fuzz-long`` raises the fuzz budget (see ``tests/fuzz.py``). The fixtures give every test
the same rigs (``tests/rigs.py``): ``configs_dir`` and ``tools_dir`` (the shipped configs and
tool ROMs), ``sim_rig`` (the built-in TMS rig without noise, flange at P0) and ``mock_config``
(a copy of a shipped mock config with sections changed, in the test's tmp_path).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from tests import rigs
from tmscal.sim import SimRig


def pytest_addoption(parser) -> None:
    parser.addoption("--fuzz-long", action="store_true", default=False,
                     help="run every fuzz test with at least 100,000 examples (slow)")


def pytest_configure(config) -> None:
    from tests import fuzz
    fuzz.LONG = bool(config.getoption("--fuzz-long"))


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
def mock_config(tmp_path: Path) -> Callable[..., Path]:
    """Factory ``mock_config(base, **changes) -> Path``: ``configs/<base>`` copied into the
    test's tmp_path with sections changed (see :func:`tests.rigs.write_config`)."""
    def make(base: str, **changes) -> Path:
        return rigs.write_config(tmp_path, base, **changes)
    return make
