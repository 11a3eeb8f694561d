"""What every kind of run checks before it continues a session (``--resume``), and the command
line that resumes one.

* ``check_same_rig``: the session was recorded with the configured drivers and bodies;
* ``check_where_run_stopped``: the flange is where an interrupted run leaves it, near P0 or
  on the straight path from the last commanded pose to the next (else the header's P0 is not
  this rig's, or the arm was moved);
* ``resume_command``: ``tmscal acquire …`` or ``tmscal selfcal acquire …`` with ``--resume``
  and the device overrides (the plan and sampling come from the session header).

Poses are base_from_flange 4×4 in mm.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..config import RigConfig
from ..errors import SessionError

__all__ = ["RESUME_TOLERANCE_MM", "POSE_TOL_MM", "RESUME_HINT", "check_same_rig",
           "check_where_run_stopped", "distance_to_segment", "resume_command"]

#: on --resume the flange must be this close (mm) to P0 or to the path from the last recorded
#: pose to the next one: where an interrupted run left it
RESUME_TOLERANCE_MM = 50.0
#: a recorded commanded pose matches the header's plan to this (mm, and the rotation entries)
POSE_TOL_MM = 1e-6
#: how every refusal to resume into a different rig or plan ends
RESUME_HINT = "resume with the config the session was recorded with, or start a new session"


def resume_command(config: str | Path | None, out: str | Path,
                   tracker_port: str | None = None, robot_host: str | None = None,
                   ft_host: str | None = None, command: str = "acquire") -> str:
    """The command that resumes a run: ``tmscal <command> CONFIG -o OUT --resume`` (command
    "acquire" for a plan or adaptive run, "selfcal acquire" for self-calibration) with the
    device overrides repeated (``ft_host`` as HOST[:PORT]); the plan and the sampling settings
    need not be, as a resumed run takes them from the session header."""
    cmd = f"tmscal {command} {config} -o {out} --resume"
    for flag, value in (("--tracker-port", tracker_port), ("--robot-host", robot_host),
                        ("--ft-host", ft_host)):
        if value:
            cmd += f" {flag} {value}"
    return cmd


def check_same_rig(cfg: RigConfig, session: Any, sensor: str) -> None:
    """Refuse to resume a session into a different rig: the header's robot driver and that of
    the ``sensor`` beside it ("tracker" or "ft") must be the config's, and the session's
    bodies the config's tracker tools (a force-torque run: ["ft"]). Raises SessionError."""
    where = f"{session.path}"
    devs = session.header.get("devices")
    devs = devs if isinstance(devs, dict) else {}
    for role in ("robot", sensor):
        sec = getattr(cfg, role)
        rec = devs.get(role)
        rec_driver = rec.get("driver") if isinstance(rec, dict) else None
        if sec is not None and rec_driver != sec.driver:
            raise SessionError(f"{where}: the session was recorded with {role} driver "
                               f"{rec_driver!r}; {cfg.path} configures {sec.driver!r}; "
                               f"{RESUME_HINT}")
    if sensor == "tracker" and cfg.tracker is not None:
        if session.bodies != list(cfg.tracker.tools):
            raise SessionError(f"{where}: the session's bodies {session.bodies} differ from the "
                               f"config's tracker.tools {list(cfg.tracker.tools)}; {RESUME_HINT}")
    elif sensor == "ft" and session.bodies != ["ft"]:
        raise SessionError(f"{where}: the session's bodies {session.bodies} are not a "
                           f"force-torque session's ['ft']; {RESUME_HINT}")


def distance_to_segment(x: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Distance (mm) from point x to the segment a–b (3-vectors, mm)."""
    ab = b - a
    den = float(ab @ ab)
    u = 0.0 if den == 0 else float(np.clip((x - a) @ ab / den, 0.0, 1.0))
    return float(np.linalg.norm(x - (a + u * ab)))


def check_where_run_stopped(here: np.ndarray, plan: np.ndarray, p0: np.ndarray,
                            done: set[int], path: Any) -> None:
    """On resume, the flange ``here`` (base_from_flange, mm) must be near P0, or near the
    straight path from the last recorded pose of ``plan`` (indices ``done``) to the next
    one, as an interrupted run leaves it; otherwise the header's P0 is not this rig's (or
    the arm was moved): SessionError naming the session ``path``."""
    x = here[:3, 3]
    last = max((i for i in done if i < len(plan)), default=-1)
    a = p0[:3, 3] if last < 0 else plan[last][:3, 3]
    b = plan[min(last + 1, len(plan) - 1)][:3, 3]
    d = min(float(np.linalg.norm(x - p0[:3, 3])), distance_to_segment(x, a, b))
    if not d <= RESUME_TOLERANCE_MM:
        raise SessionError(
            f"{path}: the flange is at {np.round(x, 1).tolist()} mm, {d:.1f} mm from both the "
            f"session's P0 {np.round(p0[:3, 3], 1).tolist()} mm and where the run stopped "
            f"(tolerance {RESUME_TOLERANCE_MM:g} mm): the session belongs to another set-up, "
            "or the arm was moved; move it back near P0 to resume. Nothing was moved.")
