"""The mock clock: real time (frame rates and motion durations are honoured) or fast (no
waits: frames advance once per request, motions complete at once). Every mock device takes
one, so a test runs in milliseconds and a demo can run at wall-clock speed."""

from __future__ import annotations

import time
from dataclasses import dataclass


@dataclass(frozen=True)
class Clock:
    """``fast=False``: real time; ``fast=True``: no waits. ``now()`` is monotonic seconds."""

    fast: bool = False

    def now(self) -> float:
        """Monotonic time in seconds."""
        return time.monotonic()


REAL_TIME = Clock(fast=False)
FAST = Clock(fast=True)
