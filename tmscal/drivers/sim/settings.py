"""The in-process sim drivers' options (``robot: {driver: sim}``, ``tracker: {driver: sim}``),
read by the config parser through the driver registry (``tmscal.config.settings``, the
settings protocol), each declared once here.

The rig's own options (``RIG_OPTIONS``: the channel, seed, truth and arm) are declared once
and taken by both drivers: a robot and a tracker on one ``channel`` share one sim rig, and
must then give it the same seed, truth and arm (refused when they are opened otherwise).
Each driver adds the noise and faults of its own side: the robot's positioning error per
move (``rot_sigma_deg`` degrees, ``trans_sigma_mm`` mm), the jitter of its reported pose per
read (``read_rot_sigma_deg``, ``read_trans_sigma_mm``) and a fault after k motions; the
tracker's fiducial noise (``fiducial_sigma_mm`` mm) and a tool dropped after k motions.

The sim tracker's ``tools`` map our tool name to a body of the rig (``marker`` or
``probe``; null: the body of that name). Neither driver has an address: ``host`` and
``port`` of the robot section are accepted and ignored. docs/devices.md, "sim (in-process)".
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Self

from ...calib.kinematics.arms import ARM_NAMES
from ...config.settings import Option, RobotSettings, TrackerSettings
from ...config.values import INT_BOUND, err, show

__all__ = ["RIG_OPTIONS", "RIG_BODIES", "TRUTHS", "ARM_ERRORS", "FAULTS",
           "SimRobotSettings", "SimTrackerSettings"]

#: the truths a sim rig can have: the built-in TMS rig (``tmscal.sim.tms_rig_truth``, the
#: flange at ``TMS_RIG_P0``) or one drawn from the seed (``Truth.random``, the flange facing
#: the tracker, ``facing_start``)
TRUTHS = ("tms", "random")
#: the hidden arm errors of ``arm`` (``tmscal.sim.arm.ERROR_PROTOCOLS``)
ARM_ERRORS = ("paper", "all", "none", "realistic")
#: what the robot's injected fault raises: a protective stop (``RobotFault``: the run stops)
#: or a dropped connection (``ConnectionLost``: the run reconnects)
FAULTS = ("protective_stop", "connection_lost")
#: the rig remembers this many motions (``SimRig.moves``), so a tool can be dropped at most
#: this many motions in
MAX_MOVES_SEEN = 100_000
#: the bodies the sim rig tracks (the marker on the coil, the probe at the coil's centre)
RIG_BODIES = ("marker", "probe")

#: the rig's options, declared once, taken by the robot and the tracker alike
RIG_OPTIONS: Mapping[str, Option] = {
    "channel": Option(str, default="default",
                      help="the rig's name in this process: a robot and a tracker on one "
                           "channel share one sim rig (python-can's virtual bus channel); the "
                           "rig lives while a driver on it is open"),
    "seed": Option(int, lo=0, hi=INT_BOUND - 1, default=0,
                   help="the seed of the rig's random numbers (noise, a random truth, the "
                        "arm's hidden errors)"),
    "truth": Option(str, choices=TRUTHS, default="tms",
                    help="`tms`: the built-in TMS rig (coil below the flange, tracker 1.5 m "
                         "away); `random`: X, Y, Z drawn from the seed"),
    "arm": Option(str, choices=ARM_NAMES, null=True, default=None,
                  help="a serial arm (a registered name): the robot moves in joint space, "
                       "reports joint angles and the nominal model's flange pose; null: no "
                       "arm"),
    "arm_errors": Option(str, choices=ARM_ERRORS, default="paper",
                         help="the arm's hidden kinematic errors (docs/selfcal.md)"),
}


def _noise(help: str, unit: str, hi: float, default: float = 0.05) -> Option:
    """A noise σ option in 0…``hi`` ``unit`` (default: Wang et al. 2018's 0.05)."""
    return Option(float, lo=0, hi=hi, default=default, unit=unit, help=help)


@dataclass(frozen=True)
class SimRobotSettings(RobotSettings):
    """The sim robot's options: the rig's (``RIG_OPTIONS``), its positioning error per move,
    the jitter of its reported pose per read, and a fault after ``fail_after_moves``
    motions. No keys of its own."""

    OPTIONS: ClassVar[Mapping[str, Option]] = {
        **RIG_OPTIONS,
        "rot_sigma_deg": _noise("the robot's positioning error per move: a rotation about a "
                                "random axis, N(0, σ) degrees (Wang et al. 2018)", "deg", 10),
        "trans_sigma_mm": _noise("the robot's positioning error per move: a translation, "
                                 "N(0, σ) mm per axis", "mm", 10),
        "read_rot_sigma_deg": _noise("jitter of every reported flange pose: a rotation about a "
                                     "random axis, N(0, σ) degrees, drawn per read", "deg", 10,
                                     0.0),
        "read_trans_sigma_mm": _noise("jitter of every reported flange pose: a translation, "
                                      "N(0, σ) mm per axis, drawn per read", "mm", 10, 0.0),
        "fail_after_moves": Option(int, lo=0, hi=INT_BOUND - 1, null=True, default=None,
                                   help="inject a fault: after this many motions since "
                                        "`open()` (a move split through P0 is three) the "
                                        "next one fails and nothing moves; null: never"),
        "fault": Option(str, choices=FAULTS, default="protective_stop",
                        help="what the injected fault is: `protective_stop` (a robot fault: "
                             "the run stops) or `connection_lost` (the run reconnects)"),
    }


@dataclass(frozen=True)
class SimTrackerSettings(TrackerSettings):
    """The sim tracker's options: the rig's (``RIG_OPTIONS``), the fiducial noise, and a
    tool dropped after ``drop_after_moves`` motions; each tool's value is the rig body it
    is (``parse_tool``)."""

    OPTIONS: ClassVar[Mapping[str, Option]] = {
        **RIG_OPTIONS,
        "fiducial_sigma_mm": _noise("the tracker's noise: N(0, σ) mm on every sphere of a "
                                    "four-sphere tool, the pose fitted by Horn's method (Wang "
                                    "et al. 2018)", "mm", 5),
        "drop_tool": Option(str, null=True, default=None,
                            help="inject a fault: this tool (one of `tools`) is reported "
                                 "missing once the rig has made more than "
                                 "`drop_after_moves` motions; null: none"),
        "drop_after_moves": Option(int, lo=0, hi=MAX_MOVES_SEEN, default=0,
                                   help="with `drop_tool`: the rig's motions (since it was "
                                        "made) the tool is still seen after; a plan from P0 "
                                        "sees it at its first k poses"),
    }

    @classmethod
    def parse(cls, section: Mapping[str, Any], src: str, base_dir: Path | None,
              check_files: bool) -> Self:
        """As ``TrackerSettings.parse``; and ``options.drop_tool``, when given, is one of
        the section's tools (ConfigError naming ``tracker.options.drop_tool``)."""
        s = super().parse(section, src, base_dir, check_files)
        options = section.get("options")
        drop = options.get("drop_tool") if isinstance(options, Mapping) else None
        if drop is not None and drop not in s.tools:
            raise err(src, "tracker.options.drop_tool", f"expected one of the tools "
                      f"({', '.join(s.tools)}), got {show(drop)}")
        return s

    @classmethod
    def parse_tool(cls, name: str, value: Any, src: str, base_dir: Path | None,
                   check_files: bool) -> str:
        """Tool ``name``'s rig body: ``value`` (``marker`` or ``probe``), or ``name`` itself
        when the value is null; ConfigError naming ``tracker.tools.<name>`` otherwise."""
        body = name if value is None else value
        if body not in RIG_BODIES:
            raise err(src, f"tracker.tools.{name}", f"expected a body of the sim rig "
                      f"({' or '.join(RIG_BODIES)}; null: the tool's own name), got "
                      f"{show(value) if value is not None else repr(name) + ' (its name)'}")
        return str(body)
