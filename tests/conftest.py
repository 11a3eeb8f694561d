"""Shared pytest options: ``--fuzz-long`` raises the fuzz budget (see ``tests/fuzz.py``)."""

from __future__ import annotations


def pytest_addoption(parser) -> None:
    parser.addoption("--fuzz-long", action="store_true", default=False,
                     help="run every fuzz test with at least 100,000 examples (slow)")


def pytest_configure(config) -> None:
    from tests import fuzz
    fuzz.LONG = bool(config.getoption("--fuzz-long"))
