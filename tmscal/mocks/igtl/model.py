"""What the OpenIGTLink tracker mock is configured with: the faults it injects, and the
device names it gives the rig's bodies by default."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

__all__ = ["IGTLFaults", "default_device_name"]


def default_device_name(body: str) -> str:
    """PlusServer's naming for a tool's transform: ``marker`` → ``MarkerToTracker``."""
    return f"{body[:1].upper()}{body[1:]}ToTracker"


def _names(name: str, v: Any) -> tuple[str, ...]:
    if isinstance(v, str) or not isinstance(v, Iterable):
        raise ValueError(f"IGTLFaults.{name} must be a list of tool names, got {v!r}")
    out = tuple(v)
    if not all(isinstance(x, str) and x for x in out):
        raise ValueError(f"IGTLFaults.{name} must be a list of tool names, got {v!r}")
    return out


@dataclass(frozen=True)
class IGTLFaults:
    """Injected faults (probabilities in [0, 1], drawn from the mock's seeded RNG; tools are
    the rig's body names).

    ``missing_fraction``: per frame and tool, the tracker does not see the tool (PlusServer
    status ``MISSING``: not sent, or sent as the identity with that status when the mock sends
    invalid transforms). ``drop_tools``: never sent at all, as when PlusServer's
    ``DefaultClientInfo`` does not name them. ``stale_tools``: after the first frame, re-sent
    every frame with that frame's timestamp and pose (a source repeating an old transform).
    ``crc_error_prob``: per message, a corrupted CRC. ``extra_messages``: every frame is
    followed by a ``STATUS`` (PlusServer's keep-alive) and a ``STRING`` message, which a
    client must skip. ``disconnect_after_frames``: each connection is closed after this many
    frames; ``garbage_after_frames``: each connection gets bytes that are not OpenIGTLink
    after this many frames (0: never, for both).
    """

    missing_fraction: float = 0.0
    drop_tools: tuple[str, ...] = ()
    stale_tools: tuple[str, ...] = ()
    crc_error_prob: float = 0.0
    extra_messages: bool = False
    disconnect_after_frames: int = 0
    garbage_after_frames: int = 0

    def __post_init__(self) -> None:
        for name in ("missing_fraction", "crc_error_prob"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not 0.0 <= v <= 1.0:
                raise ValueError(f"IGTLFaults.{name} must be in [0, 1], got {v!r}")
        for name in ("disconnect_after_frames", "garbage_after_frames"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise ValueError(f"IGTLFaults.{name} must be an int >= 0, got {v!r}")
        if not isinstance(self.extra_messages, bool):
            raise ValueError(f"IGTLFaults.extra_messages must be true or false, got "
                             f"{self.extra_messages!r}")
        for name in ("drop_tools", "stale_tools"):
            object.__setattr__(self, name, _names(name, getattr(self, name)))
