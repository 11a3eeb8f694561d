"""The sim tracker (``tracker: {driver: sim}``): an optical tracker that observes the sim rig
of its channel in this process (:mod:`.channel`): every ``read()`` is a new frame with each
tool's tracker_from_<body> (4×4 mm) as the rig's noise model gives it (fiducials of a
four-sphere tool + N(0, ``fiducial_sigma_mm``) mm, pose by Horn's method; Wang et al. 2018).
Frame k is at ``time.monotonic()`` when it is read; the rig has no settling, so no wait is
needed. Options: :class:`~tmscal.drivers.sim.settings.SimTrackerSettings`.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import replace
from typing import Any

from ...sim import SimRig
from ..base import ToolState, Tracker, TrackerFrame
from .channel import RigSpec, attach, detach
from .settings import RIG_BODIES, SimTrackerSettings

__all__ = ["SimTracker"]

#: the options' defaults, declared once in SimTrackerSettings.OPTIONS
_OPT = SimTrackerSettings.defaults()


class SimTracker(Tracker):
    """A tracker on the sim rig of ``channel`` (shared with a sim robot on that channel).

    ``tools``: our tool name → the rig body it is (``marker`` or ``probe``); ``frame_rate_hz``
    (Hz) is nominal (every read is a new frame). ``seed``, ``truth``, ``arm``, ``arm_errors``:
    the rig's, as the robot's (:class:`~tmscal.drivers.sim.channel.RigSpec`);
    ``fiducial_sigma_mm`` (mm): the tracker's noise. ``drop_tool``: a tool reported missing in
    every frame once the rig has made more than ``drop_after_moves`` motions (None: none)."""

    name = "sim"
    real_time = False

    def __init__(self, tools: Mapping[str, str], frame_rate_hz: float = 60.0, *,
                 channel: str = _OPT["channel"], seed: int = _OPT["seed"],
                 truth: str = _OPT["truth"], arm: str | None = _OPT["arm"],
                 arm_errors: str = _OPT["arm_errors"],
                 fiducial_sigma_mm: float = _OPT["fiducial_sigma_mm"],
                 drop_tool: str | None = _OPT["drop_tool"],
                 drop_after_moves: int = _OPT["drop_after_moves"]) -> None:
        o = SimTrackerSettings.check_options(
            "SimTracker", channel=channel, seed=seed, truth=truth, arm=arm,
            arm_errors=arm_errors, fiducial_sigma_mm=fiducial_sigma_mm, drop_tool=drop_tool,
            drop_after_moves=drop_after_moves)
        if not tools:
            raise ValueError("SimTracker needs at least one tool")
        for tool, body in tools.items():
            if body not in RIG_BODIES:
                raise ValueError(f"SimTracker: tool {tool!r}: {body!r} is not a body of the "
                                 f"sim rig ({' or '.join(RIG_BODIES)})")
        if drop_tool is not None and drop_tool not in tools:
            raise ValueError(f"SimTracker: drop_tool: {drop_tool!r} is not one of the tools "
                             f"({', '.join(tools)})")
        super().__init__(list(tools), frame_rate_hz)
        self.bodies = dict(tools)
        self.channel: str = o["channel"]
        #: the rig options as given (the option names), and the rig they make
        self.seed, self.truth, self.arm, self.arm_errors = (o["seed"], o["truth"], o["arm"],
                                                            o["arm_errors"])
        self.spec = RigSpec(self.seed, self.truth, self.arm, self.arm_errors)
        self.fiducial_sigma_mm: float = o["fiducial_sigma_mm"]
        self.drop_tool: str | None = o["drop_tool"]
        self.drop_after_moves: int = o["drop_after_moves"]
        self._rig: SimRig | None = None
        self._frame = 0

    @property
    def rig(self) -> SimRig | None:
        """The :class:`~tmscal.sim.SimRig` observed (None until ``open()``)."""
        return self._rig

    def _open(self) -> None:
        rig = attach(self.channel, self.spec, "tracker")
        rig.noise = replace(rig.noise, fiducial_sigma_mm=self.fiducial_sigma_mm)
        self._rig = rig

    def _close(self) -> None:
        rig, self._rig = self._rig, None
        if rig is not None:
            detach(self.channel, rig)

    def identity(self) -> dict[str, Any]:
        """Driver, channel, the rig's seed and truth, and the tools' rig bodies."""
        return {"driver": self.name, "channel": self.channel, "seed": self.spec.seed,
                "truth": self.spec.truth, "tools": dict(self.bodies)}

    def _read(self) -> TrackerFrame:
        rig = self._rig
        assert rig is not None  # the base class calls the hook only while open
        self._frame += 1
        dropped = (self.drop_tool if self.drop_tool is not None
                   and len(rig.moves) > self.drop_after_moves else None)
        tools = {t: (ToolState(pose=None, missing=True) if t == dropped
                     else ToolState(pose=rig.observe(body)))
                 for t, body in self.bodies.items()}
        return TrackerFrame(frame=self._frame, host_time=time.monotonic(), tools=tools)
