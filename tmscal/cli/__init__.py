"""The ``tmscal`` command line (click). Thin: parses, calls library functions, prints.

The group, the shared argument types and the one rule for output files live in
:mod:`tmscal.cli.app`. Each command is in the module of its name (``tmscal.cli.acquire``,
``check``, ``compare``, ``demo``, ``export``, ``mock``, ``monitor``, ``report``, ``robot``,
``selftest``, ``simulate``, ``solve``, ``stream``, ``study``, ``track``; ``import`` in
``import_csv``); the ``selfcal`` group and its ``simulate`` are in :mod:`tmscal.cli.selfcal`,
its ``acquire`` and ``identify`` in :mod:`tmscal.cli.selfcal_acquire` and
:mod:`tmscal.cli.selfcal_identify`. The other modules hold what several commands share: the
progress display and stderr capture (``progress``), ``track``'s live table (``track_table``),
the Ctrl-C handling (``stopping``), the adaptive acquisition (``acquire_adaptive``), the re-
registration of ``acquire --update`` (``reregister``) and the report of ``demo --kinematics``
(``demo_kinematics``).

Every expected failure (bad input, device error, safety refusal) prints one line
``error: …`` naming the problem and exits non-zero; no tracebacks.
"""

from __future__ import annotations

from .app import main

__all__ = ["main"]

# every command module registers its commands on ``main``
from . import acquire, check, compare, demo, export, mock, report, robot  # noqa: E402,F401,I001
from . import selfcal, selfcal_acquire, selfcal_identify, selftest, simulate, solve, stream  # noqa: E402,F401,I001
from . import import_csv, monitor, study, track  # noqa: E402,F401,I001
