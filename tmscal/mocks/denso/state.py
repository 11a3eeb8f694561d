"""The DENSO mock's data: injected faults (:class:`DensoFaults`), a motion in progress
(:class:`Job`), one client connection (:class:`Session`) and the record of an executed move
(:class:`Executed`)."""

from __future__ import annotations

import socket
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...drivers.denso.hresult import E_EMERGENCY_STOP
from ...drivers.denso.packet import FUNCTION_NAMES, PacketFramer, encode_packet
from ...drivers.denso.variant import Variant
from ...motion import Trapezoid
from ...sim.rig import straight_path

#: Values of ``DensoFaults.bad_curpos``.
BAD_CURPOS = ("nan", "inf", "short", "long", "bstr", "bool_array", "empty", "nested_bstr")


@dataclass(frozen=True)
class DensoFaults:
    """Injected faults, counted over all connections of one mock (1-based).

    ``fail_move_at``: the k-th Robot_Move is refused with ``fail_move_hresult`` (default
    0x83500178, not executable during emergency stop); ``move_fail_rate``: probability that
    any move is refused the same way. ``drop_at_request``: at the k-th request the mock
    closes that connection instead of answering; ``drop_rate``: probability per request.
    Random faults draw from ``numpy.random.default_rng(seed)``.
    ``bad_curpos``: every CurPos (and ``@CURRENT_POSITION``) reply is corrupted the named way:
    "nan" / "inf" (x is NaN / +inf), "short" (5 values), "long" (9 values), "bstr" (a BSTR),
    "bool_array" (a BOOL array), "empty" (EMPTY), "nested_bstr" (a VARIANT array with a BSTR
    in it). None (default): correct replies. The mock reads its ``faults`` at every request,
    so a test may swap them (``dataclasses.replace``) while it serves.
    ``hold_move_at``: the k-th Robot_Move does not end by itself (a stalled or very slow arm):
    its connection stays busy until a Robot_Halt, on either clock. ``latched_error``: an error
    HRESULT the controller holds when the mock starts (one left over from before, e.g. an
    emergency stop that was released): TakeArm, Motor on and Robot_Move are refused with it
    until ``Controller_Execute("ClearError")`` (read once, when the mock is built).
    ``stuck_functions``: b-CAP function names (``"Robot_Halt"``, ``"Service_Start"`` …) whose
    requests are never answered: the connection sends an S_EXECUTING keep-alive for the
    request every ``stuck_keepalive_s`` seconds (wall clock) instead, for as long as it
    lives, as a controller stuck executing would (read at each request).
    """

    fail_move_at: int | None = None
    fail_move_hresult: int = E_EMERGENCY_STOP
    move_fail_rate: float = 0.0
    drop_at_request: int | None = None
    drop_rate: float = 0.0
    seed: int = 0
    bad_curpos: str | None = None
    hold_move_at: int | None = None
    latched_error: int | None = None
    stuck_functions: tuple[str, ...] = ()
    stuck_keepalive_s: float = 0.05

    def __post_init__(self) -> None:
        if self.bad_curpos is not None and self.bad_curpos not in BAD_CURPOS:
            raise ValueError(f"bad_curpos must be one of {', '.join(BAD_CURPOS)} or None, got "
                             f"{self.bad_curpos!r}")
        unknown = sorted(set(self.stuck_functions) - set(FUNCTION_NAMES.values()))
        if isinstance(self.stuck_functions, str) or unknown:
            raise ValueError(f"stuck_functions must be a tuple of b-CAP function names "
                             f"({', '.join(sorted(FUNCTION_NAMES.values()))}), got "
                             f"{self.stuck_functions!r}")
        if not 0 < self.stuck_keepalive_s <= 10:  # also refuses NaN
            raise ValueError(f"stuck_keepalive_s must be in (0, 10] s, got "
                             f"{self.stuck_keepalive_s!r}")


@dataclass(frozen=True, eq=False)
class Executed:
    """A move the mock executed: the flange from ``start`` to ``target`` (base_from_flange
    4×4 mm) on the straight line and the rotation geodesic, its share of the way following
    ``profile`` (the translation's trapezoid) stretched to ``duration_s`` (the modelled
    duration, ``motion_time_s`` when set), on both clocks."""

    start: np.ndarray
    target: np.ndarray
    profile: Trapezoid
    duration_s: float

    def pose_at_time(self, t: float) -> np.ndarray:
        """base_from_flange (mm) ``t`` s after the move started (the fast clock too)."""
        if self.duration_s <= 0 or self.profile.duration <= 0:
            f = 1.0 if t > 0 or self.duration_s <= 0 else 0.0
        else:
            f = self.profile.fraction(t * self.profile.duration / self.duration_s)
        return straight_path(self.start, self.target, f)


@dataclass(eq=False)
class Job:
    """A motion in progress on one connection (times on the mock's clock, s). ``end`` is
    when the reply is due and the connection is free again (``inf``: only a Robot_Halt ends
    it); ``settle_s``: the arm is still this long after ``end`` (a pass or ``@P`` move: the
    reply comes before the arm is still); ``halted``: set by Robot_Halt from any
    connection, the owning connection then ends the job."""

    target: np.ndarray  # base_from_flange 4×4 mm
    start: float
    end: float
    serial: int | None  # blocking move: reply pending with this serial; None for NEXT
    wdt_s: float | None
    next_keepalive: float = 0.0
    settle_s: float = 0.0
    halted: bool = False

    def __post_init__(self) -> None:
        if self.wdt_s:
            self.next_keepalive = self.start + self.wdt_s


@dataclass
class Session:
    """One client connection: its handles, whether it holds the arm, its watchdog period
    and the motion it runs."""

    sock: socket.socket
    peer: str
    handles: dict[int, tuple[str, Any]] = field(default_factory=dict)
    arm: bool = False
    wdt_s: float | None = None
    job: Job | None = None
    framer: PacketFramer = field(default_factory=PacketFramer)
    #: a request left unanswered (``DensoFaults.stuck_functions``): its serial, and when the
    #: next keep-alive for it is due (monotonic seconds)
    stuck: tuple[int, float] | None = None

    def reply(self, serial: int, code: int, value: Variant | None = None) -> None:
        """Send one reply packet (in one ``sendall``)."""
        self.sock.sendall(encode_packet(serial, code, [] if value is None else [value]))


__all__ = ["BAD_CURPOS", "DensoFaults", "Job", "Session"]
