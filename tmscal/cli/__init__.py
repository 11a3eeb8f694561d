"""The ``tmscal`` command line (click). Thin: parses, calls library functions, prints.

The group, the shared argument types and the one rule for output files live here; the
commands are in :mod:`tmscal.cli.offline` (simulate, solve, study),
:mod:`tmscal.cli.rig_commands` (mock, track, robot, acquire), and compare, demo, export,
report, stream, monitor, selftest, selfcal and selfcal_rig (the ``selfcal`` group), one module each.

Every expected failure (bad input, device error, safety refusal) prints one line
``error: …`` naming the problem and exits non-zero; no tracebacks.
"""

from __future__ import annotations

from .app import main

__all__ = ["main"]

# every command module registers its commands on ``main``
from . import check, compare, demo, export, offline, report, rig_commands  # noqa: E402,F401,I001
from . import monitor, selfcal, selfcal_rig, selftest, stream  # noqa: E402,F401,I001
