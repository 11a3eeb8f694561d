"""Waiting with a bound: one ``Deadline`` instead of hand-written ``time.monotonic() + t``
loops (as pyserial's ``Timeout``). Times are seconds on the monotonic clock."""

from __future__ import annotations

import math
import time
from collections.abc import Callable

__all__ = ["Deadline"]


class Deadline:
    """A moment ``timeout_s`` seconds from now (``None``: never). ``remaining()`` is the
    seconds left (never negative; ``math.inf`` without a timeout), ``expired()`` whether it
    has passed; ``restart()`` starts the same timeout again. ``clock`` is injectable for
    tests (default ``time.monotonic``)."""

    def __init__(self, timeout_s: float | None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if timeout_s is not None and not (timeout_s >= 0):  # refuses NaN and negatives
            raise ValueError(f"timeout must be ≥ 0 seconds or None, got {timeout_s!r}")
        self.timeout_s = timeout_s
        self._clock = clock
        self._end = math.inf if timeout_s is None else clock() + timeout_s

    def remaining(self) -> float:
        """Seconds left, ≥ 0 (``math.inf`` when there is no timeout)."""
        return max(0.0, self._end - self._clock())

    def expired(self) -> bool:
        """True once the deadline has passed."""
        return self._clock() >= self._end

    def restart(self) -> None:
        """Start the same timeout again from now."""
        self._end = math.inf if self.timeout_s is None else self._clock() + self.timeout_s

    def __repr__(self) -> str:
        return f"Deadline({self.timeout_s!r}, remaining={self.remaining():.3f})"
