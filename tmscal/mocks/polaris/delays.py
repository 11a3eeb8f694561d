"""How long the Polaris mock takes over the commands a real Polaris is slow with.

After a serial break (or power-up) a Polaris answers nothing until its reset is done and then
sends ``RESETBE6F`` on its own; ndicapi waits up to 7 s for it (``ndiSerialProbe``), other
clients sleep 3 s. INIT, PINIT and TSTART can each take seconds (PlusLib's
``vtkPlusNDITracker``: "First init can take up to 5 seconds"). See docs/devices.md.

On the real-time clock a reset takes :data:`REAL_TIME_RESET_S` unless configured; every other
delay defaults to 0 on both clocks (ndicapi's probe gives INIT ~200 ms before it resets with a
break, which a pty cannot carry). Any delay can be set on either clock (``mock.tracker:
{reset_delay_s: 6, init_delay_s: 2, ...}`` in a config): the mock then really waits, so the
driver's timeouts are exercised on the fast clock too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..clock import Clock

__all__ = ["CommandDelays", "REAL_TIME_RESET_S"]

#: how long a reset takes on the real-time clock unless configured (s); other clients of the
#: Polaris sleep 3 s after the break
REAL_TIME_RESET_S = 3.0


@dataclass(frozen=True)
class CommandDelays:
    """Seconds the mock takes before it answers: ``reset_s`` from a break (or the RESET
    command) to ``RESET``, and ``init_s``, ``pinit_s``, ``tstart_s`` for those commands."""

    reset_s: float = 0.0
    init_s: float = 0.0
    pinit_s: float = 0.0
    tstart_s: float = 0.0

    def __post_init__(self) -> None:
        for name in ("reset_s", "init_s", "pinit_s", "tstart_s"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) \
                    or not 0.0 <= v <= 60.0:
                raise ValueError(f"Polaris mock delay {name[:-2]}_delay_s must be a number "
                                 f"in [0, 60] s, got {v!r}")

    @classmethod
    def make(cls, clock: Clock, reset_s: float | None, init_s: float, pinit_s: float,
             tstart_s: float) -> CommandDelays:
        """The delays for ``clock``: ``reset_s`` None means the clock's default."""
        if reset_s is None:
            reset_s = 0.0 if clock.fast else REAL_TIME_RESET_S
        return cls(reset_s, init_s, pinit_s, tstart_s)

    def of(self, command: str) -> float:
        """The delay before the reply to ``command`` (upper case), in seconds."""
        return {"INIT": self.init_s, "PINIT": self.pinit_s, "TSTART": self.tstart_s,
                "RESET": self.reset_s}.get(command, 0.0)
