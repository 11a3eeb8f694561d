"""What every kind of run checks before it continues a session (``--resume``), and the command
line that resumes one. The engine (:mod:`.engine`) applies the same checks to the plan, the
adaptive and the self-calibration run, in this order, before anything moves:

* ``check_same_rig``: the session was recorded with the configured drivers and bodies;
* ``check_same_plan``: the header's poses are the plan RE-DERIVED from the config and what the
  header records of the rig (P0, a seed; each strategy's ``rederive``), never taken as written;
* ``check_recorded``: every recorded pose was commanded where that plan puts it;
* the plan against the config's envelope around the recorded P0 (``plan.check_plan``);
* ``check_where_run_stopped``: the flange is where an interrupted run leaves it, in position
  AND orientation: near P0, or on the path from the last commanded pose to the next (the
  straight line and the slerp of a linear move), within ``RESUME_TOLERANCE_MM`` and
  ``RESUME_TOLERANCE_DEG`` (else the header's P0 is not this rig's, or the arm was moved);
  and inside the envelope;
* ``resume_command``: ``tmscal acquire …`` or ``tmscal selfcal acquire …`` with ``--resume``
  and the device overrides (the plan and sampling come from the session header).

Poses are base_from_flange 4×4 in mm; angles in degrees.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from ..config import RigConfig
from ..errors import SessionError
from ..geometry import angle_between, matrix_from_rotvec, rotvec_from_matrix

__all__ = ["RESUME_TOLERANCE_MM", "RESUME_TOLERANCE_DEG", "POSE_TOL_MM", "RESUME_HINT",
           "check_same_rig", "check_same_plan", "check_recorded", "check_where_run_stopped",
           "distance_to_segment", "rotation_to_path", "resume_command"]

#: on --resume the flange must be this close (mm) to P0 or to the path from the last recorded
#: pose to the next one: where an interrupted run left it
RESUME_TOLERANCE_MM = 50.0
#: … and its orientation this close (deg) to P0's or to the path's (an interrupted linear move
#: stops on its slerp; 20° moves a coil point 110 mm below the flange by about 38 mm)
RESUME_TOLERANCE_DEG = 20.0
#: orientations sampled along a path's slerp: the distance to it is overestimated by at most
#: half a step, 180° / (2 · 360) = 0.25°
_SLERP_SAMPLES = 361
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
    bodies the config's tracker tools (a force-torque run: ["ft"]); a tracker run that
    recorded wrenches (the header's devices.ft) resumes only with that force-torque sensor
    in the config, and one that did not, only without one (every pose has a wrench, or
    none). Raises SessionError."""
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
    if sensor == "tracker":
        _check_same_ft(cfg, devs.get("ft"), where)
    if sensor == "tracker" and cfg.tracker is not None:
        if session.bodies != list(cfg.tracker.tools):
            raise SessionError(f"{where}: the session's bodies {session.bodies} differ from the "
                               f"config's tracker.tools {list(cfg.tracker.tools)}; {RESUME_HINT}")
    elif sensor == "ft" and session.bodies != ["ft"]:
        raise SessionError(f"{where}: the session's bodies {session.bodies} are not a "
                           f"force-torque session's ['ft']; {RESUME_HINT}")


def _check_same_ft(cfg: RigConfig, rec: Any, where: str) -> None:
    """A tracker session's force-torque sensor (header devices.ft) against the config's."""
    rec_driver = rec.get("driver") if isinstance(rec, dict) else None
    cfg_driver = cfg.ft.driver if cfg.ft is not None else None
    if rec_driver == cfg_driver:
        return
    if cfg_driver is None:
        raise SessionError(f"{where}: the session recorded a wrench at every pose (ft driver "
                           f"{rec_driver!r}); {cfg.path} has no ft section; {RESUME_HINT}")
    if rec_driver is None:
        raise SessionError(f"{where}: the session recorded no wrench; {cfg.path} configures "
                           f"a force-torque sensor (ft driver {cfg_driver!r}): resume with "
                           f"the config it was recorded with, or start a new session")
    raise SessionError(f"{where}: the session was recorded with ft driver {rec_driver!r}; "
                       f"{cfg.path} configures {cfg_driver!r}; {RESUME_HINT}")


def _at(poses: np.ndarray, i: int) -> list[float]:
    return np.round(poses[i][:3, 3], 1).tolist()


def check_same_plan(header: np.ndarray, derived: np.ndarray, path: Any, unit: str,
                    source: str) -> None:
    """The header's poses ``header`` (n, 4, 4) must be the plan ``derived`` from ``source``
    (the config and what the header records of the rig), to ``POSE_TOL_MM`` (mm, and the
    rotation entries). Raises SessionError naming the first ``unit`` that differs."""
    if len(header) != len(derived):
        raise SessionError(f"{path}: the header's plan has {len(header)} {unit}s; the plan "
                           f"re-derived from {source} has {len(derived)}: the header was "
                           f"edited or belongs to another run; {RESUME_HINT}")
    for i, (P, Q) in enumerate(zip(header, derived, strict=True)):
        if not float(np.abs(P - Q).max()) <= POSE_TOL_MM:
            raise SessionError(
                f"{path}: {unit} {i} of the header's plan is at {_at(header, i)} mm, but the "
                f"plan re-derived from {source} puts it at {_at(derived, i)} mm: the header "
                f"was edited or belongs to another run; {RESUME_HINT}")


def check_recorded(records: Iterable[Any], planned: Callable[[Any], np.ndarray | None],
                   path: Any, unit: str) -> None:
    """Every recorded pose was commanded where the plan puts it (``planned(record)``, None:
    the plan does not say, e.g. a pose beyond a plan that was shortened), to
    ``POSE_TOL_MM``: an edited or foreign header would not reproduce them. SessionError."""
    for rec in records:
        P = planned(rec) if rec.commanded is not None else None
        if P is None:
            continue
        if not float(np.abs(rec.commanded - P).max()) <= POSE_TOL_MM:
            raise SessionError(
                f"{path}: {unit} {rec.index} was commanded to "
                f"{np.round(rec.commanded[:3, 3], 1).tolist()} mm but the plan puts it at "
                f"{np.round(P[:3, 3], 1).tolist()} mm: the header was edited or belongs to "
                "another run; refusing to resume")


def rotation_to_path(here: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Angle (deg) from the orientation of ``here`` to the nearest orientation on the slerp
    from ``a`` to ``b`` (poses or rotations; the orientations a linear move passes), to
    within 0.25°."""
    Ra, Rb = np.asarray(a, float)[:3, :3], np.asarray(b, float)[:3, :3]
    rv = rotvec_from_matrix(Ra.T @ Rb)
    u = np.linspace(0.0, 1.0, _SLERP_SAMPLES)[:, None]
    path = Ra @ matrix_from_rotvec(u * rv)
    return float(np.degrees(angle_between(path, np.asarray(here, float)[:3, :3]).min()))


def distance_to_segment(x: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Distance (mm) from point x to the segment a–b (3-vectors, mm)."""
    ab = b - a
    den = float(ab @ ab)
    u = 0.0 if den == 0 else float(np.clip((x - a) @ ab / den, 0.0, 1.0))
    return float(np.linalg.norm(x - (a + u * ab)))


def check_where_run_stopped(here: np.ndarray, plan: np.ndarray, p0: np.ndarray,
                            done: set[int], path: Any) -> None:
    """On resume, the flange ``here`` (base_from_flange, mm) must be where an interrupted run
    leaves it, in position and orientation: near P0 (within ``RESUME_TOLERANCE_MM`` and
    ``RESUME_TOLERANCE_DEG``), or near the path from the last recorded pose of ``plan``
    (indices ``done``; P0 before the first) to the next one, the straight line for the
    position and the slerp for the orientation. Otherwise the header's P0 is not this rig's
    (or the arm was moved or turned): SessionError naming the session ``path``, the flange's
    distance and angle from both."""
    x = here[:3, 3]
    last = max((i for i in done if i < len(plan)), default=-1)
    a = p0 if last < 0 else plan[last]
    b = plan[min(last + 1, len(plan) - 1)]
    d0 = float(np.linalg.norm(x - p0[:3, 3]))
    r0 = float(np.degrees(angle_between(p0, here)))
    d1 = distance_to_segment(x, a[:3, 3], b[:3, 3])
    r1 = rotation_to_path(here, a, b)

    def near(d: float, r: float) -> bool:
        return d <= RESUME_TOLERANCE_MM and r <= RESUME_TOLERANCE_DEG

    if not (near(d0, r0) or near(d1, r1)):
        raise SessionError(
            f"{path}: the flange is at {np.round(x, 1).tolist()} mm, {d0:.1f} mm and {r0:.1f}° "
            f"from the session's P0 {np.round(p0[:3, 3], 1).tolist()} mm and {d1:.1f} mm and "
            f"{r1:.1f}° from the path where the run stopped (tolerance "
            f"{RESUME_TOLERANCE_MM:g} mm and {RESUME_TOLERANCE_DEG:g}°): the session belongs "
            "to another set-up, or the arm was moved or turned; move it back near P0, in "
            "position and orientation, to resume. Nothing was moved.")
