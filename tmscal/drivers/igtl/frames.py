"""From TRANSFORM messages to tracker frames: which transforms make a frame, and which tool
states they give.

A frame is the TRANSFORM messages that share one timestamp (PlusServer stamps every message
of a tracked frame with that frame's time: PlusLib, ``vtkPlusOpenIGTLinkServer::
SendTrackedFrame``). Messages are taken in arrival order:

* a timestamp newer than the newest so far starts a frame (and delivers the one before, if
  it was still open);
* the same timestamp adds to the open frame; the frame is delivered as soon as every
  configured device name has arrived in it, else when the next frame starts;
* an older timestamp is stale: its transform is not this frame's and is ignored (counted in
  ``stale``), so a tool whose latest transform is older than the frame is missing from it.

Every TRANSFORM counts for the frame boundaries, also those of device names no tool is
configured with. Frame numbers count delivered frames (TRANSFORM messages carry none).

A tool is usable only from a transform of the frame's timestamp that is valid. Valid means:
with version-2 metadata ``TransformStatus`` (PlusServer's, PlusLib ``vtkPlusIgtlMessageCommon
::PackTransformMessage``) equal to ``OK``; without it, a finite matrix that is not exactly
the identity (PlusServer sends an invalid transform as the identity matrix when it is set to
send invalid transforms at all: ``GetIgtlMatrix`` starts from the identity and copies nothing
for a status other than OK). Anything else is ``ToolState(pose=None, missing=True)``;
``OUT_OF_VOLUME`` also sets ``out_of_volume``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..base import ToolState, TrackerFrame
from .wire import Transform

__all__ = ["FrameAssembler", "tool_state", "transform_status"]

#: PlusLib's tool status meaning "valid" (igsioCommon::ConvertToolStatusToString)
STATUS_OK = "OK"
_OUT_OF_VOLUME = "OUT_OF_VOLUME"
_IDENTITY = np.eye(4)


def transform_status(t: Transform) -> str | None:
    """The sender's status of ``t`` (upper case), or None when it sends none."""
    s = t.metadata.get("TransformStatus")
    return None if s is None else s.strip().upper()


def tool_state(t: Transform) -> ToolState:
    """The tool state ``t`` gives (the module docstring's validity rule); the pose is
    ``t.matrix`` (the sender's <tool>-to-<reference>, i.e. reference_from_tool, 4×4)."""
    status = transform_status(t)
    m = t.matrix
    if status is not None:
        valid = status == STATUS_OK and bool(np.isfinite(m).all())
    else:
        valid = bool(np.isfinite(m).all()) and not np.array_equal(m, _IDENTITY)
    if valid:
        pose = np.array(m, dtype=np.float64)
        pose.setflags(write=False)
        return ToolState(pose=pose)
    return ToolState(pose=None, missing=True, out_of_volume=status == _OUT_OF_VOLUME)


@dataclass
class _Open:
    stamp: int
    tools: dict[str, ToolState]
    arrival: float


class FrameAssembler:
    """Groups TRANSFORM messages into :class:`TrackerFrame` s (the module docstring's rules).

    ``tools``: our tool name → the device name of its TRANSFORM. :meth:`feed` takes each
    TRANSFORM with its arrival time (``time.monotonic()``, s) and returns the frames it
    delivers (0, 1 or 2). ``first_frame`` is the number the first delivered frame gets."""

    def __init__(self, tools: Mapping[str, str], first_frame: int = 0) -> None:
        self.tools = dict(tools)
        self._tool_of = {dev: tool for tool, dev in self.tools.items()}
        if len(self._tool_of) != len(self.tools):
            raise ValueError(f"two tools share one device name: {self.tools}")
        self.next_frame = int(first_frame)
        #: transforms ignored because they were older than the newest frame
        self.stale = 0
        self._newest: int | None = None
        self._open: _Open | None = None

    def feed(self, t: Transform, arrival: float) -> list[TrackerFrame]:
        """Add one TRANSFORM; the frames it completes, oldest first."""
        out: list[TrackerFrame] = []
        if self._newest is None or t.stamp > self._newest:
            if self._open is not None:
                out.append(self._deliver())
            self._newest = t.stamp
            self._open = _Open(t.stamp, {}, arrival)
        elif t.stamp < self._newest:
            self.stale += 1
            return out
        if self._open is None:  # a late part of a frame already delivered
            return out
        self._open.arrival = arrival
        tool = self._tool_of.get(t.device)
        if tool is not None:
            self._open.tools[tool] = tool_state(t)
        if len(self._open.tools) == len(self.tools):
            out.append(self._deliver())
        return out

    def _deliver(self) -> TrackerFrame:
        assert self._open is not None
        o, self._open = self._open, None
        missing = ToolState(pose=None, missing=True)
        tools = {name: o.tools.get(name, missing) for name in self.tools}
        fr = TrackerFrame(frame=self.next_frame, host_time=o.arrival, tools=tools)
        self.next_frame += 1
        return fr
