"""The Polaris mock's tracking data: frame numbers and, per frame, what each enabled port
handle reports (a noisy observation of its rig body, or MISSING, with its port status).

On the real-time clock the frame counter advances at the model's rate; on the fast clock
once per TX/BX request, and ``time_s()`` (frames served / rate) is the tracker's virtual
time, the time base of the sim rig's settling oscillation on that clock. A new noisy
observation (``rig.observe``) is taken only when the frame number changes, so the same frame
always reports the same pose (``mocks.bodies``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ...drivers.ndi import protocol as p
from ...drivers.ndi.codes import PORT_HEALTHY, PortStatus, ReplyOption, SystemStatus
from ...sim.rig import SimRig
from ..bodies import BodyObserver, Visibility
from ..clock import Clock
from .model import MeasurementVolume, PolarisFaults

__all__ = ["FrameSource"]

_VALID, _MISSING, _OUT_OF_VOLUME, _UNOCCUPIED = "valid", "missing", "oov", "unoccupied"
#: per enabled handle: (kind, pose tracker_from_body 4×4 mm or None, port status)
_HandleState = tuple[str, np.ndarray | None, int]


class FrameSource:
    """Frames of the rig's bodies as the tracker sees them.

    ``rig``: the bodies (poses tracker_from_body, mm) and their marker spheres; ``clock``
    and ``rate_hz`` drive the frame counter; ``volume`` (None: unlimited) flags tools out of
    the measurement volume; ``faults`` (its ``missing_fraction`` and
    ``ir_interference_fraction``) draw from ``rng``; every valid record reports ``error_mm``.
    """

    def __init__(self, rig: SimRig, clock: Clock, rate_hz: float,
                 volume: MeasurementVolume | None, faults: PolarisFaults,
                 rng: np.random.Generator, error_mm: float) -> None:
        self.rig = rig
        self.clock = clock
        self.rate_hz = rate_hz
        self.volume = volume
        self.faults = faults
        self.error_mm = error_mm
        self._rng = rng
        self._bodies = BodyObserver(rig, volume)
        self._served = 0   # fast-clock frames served since power-up (TSTART does not reset it)
        self.restart()

    def restart(self, *, observations: bool = True) -> None:
        """Restart the frame counter at 0 (TSTART:80); with ``observations`` also forget the
        cached observations (power-up)."""
        self._t0 = self.clock.now()
        self._fast_frame = 0
        self._frame_cache: tuple[int, dict[int, _HandleState], int] | None = None
        if observations:
            self._bodies.forget()

    def records(self, handles: Sequence[tuple[int, str | None]], options: int
                ) -> tuple[list[p.HandleRecord], int]:
        """The TX/BX records of the enabled ``handles`` ((number, body or None) in handle
        order) for the current frame, and the system status. With ``options`` lacking
        ``ReplyOption.OUT_OF_VOLUME`` a tool out of the volume is reported MISSING."""
        frame = self._current_frame()
        state, sys_status = self._frame_state(frame, handles)
        seen = [(number, pose, self.error_mm, status, frame)
                for number, (kind, pose, status) in state.items()
                if kind == _VALID
                or (kind == _OUT_OF_VOLUME and options & ReplyOption.OUT_OF_VOLUME)]
        valid = {r.handle: r for r in p.records_from_poses(seen)}  # type: ignore[arg-type]
        recs = [valid.get(number)
                or (p.HandleRecord(number, p.RecordStatus.UNOCCUPIED) if kind == _UNOCCUPIED
                    else p.HandleRecord.missing_tool(number, status, frame))
                for number, (kind, _, status) in state.items()]
        return recs, sys_status

    def time_s(self) -> float:
        """The tracker's time in seconds: on the fast clock the frames served since power-up
        divided by the frame rate (so it advances only as frames are requested, and never
        goes back); on the real-time clock the clock's monotonic time."""
        return self._served / self.rate_hz if self.clock.fast else self.clock.now()

    def _current_frame(self) -> int:
        if self.clock.fast:
            self._fast_frame += 1
            self._served += 1
            return self._fast_frame
        return int((self.clock.now() - self._t0) * self.rate_hz) & 0xFFFFFFFF

    def _frame_state(self, frame: int, handles: Sequence[tuple[int, str | None]]
                     ) -> tuple[dict[int, _HandleState], int]:
        """Per enabled handle: (kind, pose, port status) for this frame, computed once per
        frame number (same frame → same observation)."""
        if self._frame_cache is not None and self._frame_cache[0] == frame:
            return self._frame_cache[1], self._frame_cache[2]
        f = self.faults
        rng = self._rng
        ir = f.ir_interference_fraction > 0 and rng.random() < f.ir_interference_fraction
        sys_status = int(SystemStatus.TOO_MUCH_EXTERNAL_INFRARED) if ir else 0
        healthy = int(PORT_HEALTHY) | (int(PortStatus.IR_INTERFERENCE) if ir else 0)
        out: dict[int, _HandleState] = {}
        for number, body in handles:
            if f.unoccupied_fraction > 0 and rng.random() < f.unoccupied_fraction:
                out[number] = (_UNOCCUPIED, None, 0)
                continue
            if body is None or (f.missing_fraction > 0 and rng.random() < f.missing_fraction):
                out[number] = (_MISSING, None, healthy)
                continue
            pose = self._bodies.observe(body)
            kind, bits = self._volume_check(body, pose)
            out[number] = (kind, pose, healthy | bits)
        self._frame_cache = (frame, out, sys_status)
        return out, sys_status

    def _volume_check(self, body: str, pose: np.ndarray) -> tuple[str, int]:
        """(kind, port status bits) of ``body`` at ``pose`` against the measurement volume:
        all spheres inside → valid; some → valid, partially out of volume; none → out of
        volume."""
        seen = self._bodies.visibility(body, pose)
        if seen == Visibility.OUTSIDE:
            return _OUT_OF_VOLUME, int(PortStatus.OUT_OF_VOLUME)
        if seen == Visibility.PARTIAL:
            return _VALID, int(PortStatus.PARTIALLY_OUT_OF_VOLUME)
        return _VALID, 0
