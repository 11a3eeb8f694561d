"""Hypothesis budgets for the fuzz and property tests.

CI runs a small budget; ``pytest --fuzz-long`` (see ``tests/conftest.py``) raises every fuzz
test to at least 100,000 examples for a long hunt before a release (``TMSCAL_FUZZ_EXAMPLES``
sets another number).
"""

from __future__ import annotations

import os

from hypothesis import HealthCheck, settings

#: set by ``tests/conftest.py`` from ``--fuzz-long`` before the test modules are collected
LONG = False
LONG_EXAMPLES = int(os.environ.get("TMSCAL_FUZZ_EXAMPLES", "100000"))


def fuzz_settings(examples: int = 200, **kw) -> settings:
    """Hypothesis settings with ``examples`` in CI and ≥ 10⁵ under ``--fuzz-long``; no
    deadline (the machine may be loaded), slow-data health checks off."""
    n = max(examples, LONG_EXAMPLES) if LONG else examples
    kw.setdefault("suppress_health_check", [HealthCheck.too_slow, HealthCheck.data_too_large,
                                            HealthCheck.filter_too_much])
    return settings(max_examples=n, deadline=None, **kw)
