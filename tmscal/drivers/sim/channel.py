"""The sim rigs of this process, by channel name: a sim robot and a sim tracker that name one
``channel`` share one :class:`~tmscal.sim.SimRig`, so the tracker sees exactly where the robot
put the coil (as buses on one channel of python-can's ``virtual`` interface hear each other).

A channel's rig is made when the first driver on it opens, from the rig options that driver
was given (``RigSpec``: seed, truth, arm), and dropped when the last one closes; a driver
that opens on a channel whose rig was made from other rig options is refused
(``ConfigError``), so a robot and a tracker can never silently run two different rigs.
Poses 4×4 mm: the rig's truth X = flange_from_marker, Y = flange_from_probe, Z =
base_from_tracker.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, fields

import numpy as np

from ...errors import ConfigError
from ...sim import TMS_RIG_P0, SimRig, Truth, Unreachable, facing_start, make_arm, tms_rig_truth

__all__ = ["RigSpec", "attach", "detach", "rig_on", "open_channels"]


@dataclass(frozen=True)
class RigSpec:
    """What makes a channel's rig: the ``seed`` of its random numbers, its ``truth`` ("tms":
    the built-in TMS rig, the flange at ``TMS_RIG_P0``; "random": X, Y, Z drawn from the
    seed, the flange facing the tracker) and its serial ``arm`` (a registered name, None: no
    arm) with the hidden ``arm_errors`` (drawn from the seed)."""

    seed: int = 0
    truth: str = "tms"
    arm: str | None = None
    arm_errors: str = "paper"

    def build(self, kind: str) -> SimRig:
        """A new rig (default noise: the driver sets its own side's); ``ConfigError`` naming
        ``<kind>.options.arm`` when the arm cannot reach the start pose."""
        rng = np.random.default_rng(self.seed)
        if self.truth == "random":
            truth = Truth.random(rng)
            start = facing_start(truth)
        else:
            truth, start = tms_rig_truth(), TMS_RIG_P0
        arm = None if self.arm is None else make_arm(self.arm, self.arm_errors, self.seed)
        try:
            return SimRig(truth, rng=rng, start=start, arm=arm)
        except Unreachable as e:
            raise ConfigError(f"sim rig: key '{kind}.options.arm': {e}") from None

    def differences(self, other: RigSpec) -> list[str]:
        """``name self vs other`` for every field that differs."""
        return [f"{f.name} {getattr(self, f.name)!r} vs {getattr(other, f.name)!r}"
                for f in fields(self) if getattr(self, f.name) != getattr(other, f.name)]


@dataclass
class _Channel:
    spec: RigSpec
    rig: SimRig
    maker: str
    users: int = 0


_CHANNELS: dict[str, _Channel] = {}
_lock = threading.Lock()


def attach(name: str, spec: RigSpec, kind: str) -> SimRig:
    """The rig of channel ``name``, made from ``spec`` if no driver holds the channel; one
    more holder. ``kind`` ("robot", "tracker") is the driver's, for messages. A channel whose
    rig was made from another spec is a ``ConfigError`` naming the options that differ."""
    with _lock:
        ch = _CHANNELS.get(name)
        if ch is None:
            ch = _Channel(spec, spec.build(kind), kind)
            _CHANNELS[name] = ch
        elif ch.spec != spec:
            diff = "; ".join(ch.spec.differences(spec))
            raise ConfigError(f"sim channel {name!r}: key '{kind}.options': the {ch.maker} "
                              f"opened this channel's rig with other rig options ({ch.maker} "
                              f"vs {kind}: {diff}); give robot.options and tracker.options "
                              "the same channel, seed, truth, arm and arm_errors")
        ch.users += 1
        return ch.rig


def detach(name: str, rig: SimRig) -> None:
    """One holder of channel ``name`` fewer (``rig``: the one it was given); the channel and
    its rig go with the last."""
    with _lock:
        ch = _CHANNELS.get(name)
        if ch is None or ch.rig is not rig:
            return
        ch.users -= 1
        if ch.users <= 0:
            del _CHANNELS[name]


def rig_on(name: str = "default") -> SimRig | None:
    """The rig of channel ``name`` while a driver on it is open (its ``truth`` is the ground
    truth, 4×4 mm), else None: for notebooks and tests."""
    with _lock:
        ch = _CHANNELS.get(name)
        return None if ch is None else ch.rig


def open_channels() -> list[str]:
    """The names of the channels a driver holds now."""
    with _lock:
        return sorted(_CHANNELS)
