"""The dry run of ``tmscal acquire --dry-run``, as a value: the run that will happen (the plan
around P0, its extent and estimated duration; for an adaptive run its bootstrap, its pose
limit, its target and its robot time at most), whether every pose is inside the safety
envelope, and the offline checks of the tracker section (its address, its tool files, its
frame rate). The robot is only asked where it is (when the plan starts at the current pose);
nothing moves, and no tracker is opened. Without an answer from the robot the dry run checks
what does not depend on P0 and says what it could not check. The CLI prints the result.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..calib.prediction import AdaptiveSettings
from ..config import RigConfig
from ..config.values import with_line
from ..errors import ConfigError, DeviceError, SafetyError
from ..motion import trapezoid_duration
from ..poses import JOINTS_KIND
from ..safety import Envelope
from ..safety.origin import CalibratedP0
from .devices import envelope_for, make_robot
from .plan import (
    PlanSpec,
    check_plan,
    check_plan_moves,
    joints_spec,
    plan_poses,
    plan_summary,
)

__all__ = ["DryRun", "AdaptiveRun", "dry_run", "tracker_checks"]


@dataclass(frozen=True)
class AdaptiveRun:
    """What an adaptive run will do, from its settings and its candidates (the plan with
    ``pool`` poses): ``bootstrap`` well-spread poses first, then one chosen pose at a time
    until the predicted coil-placement error is at most ``target_mm`` (mm) at
    ``confidence``, and never more than ``max_poses`` poses. ``per_pose_s`` is a pose's
    settling and sampling at most (``sampling.settle_s`` + ``samples`` frames at the
    tracker's frame rate, s); ``longest_move_s`` bounds any one move between candidates
    (twice the trapezoidal move from P0 to the farthest candidate: a straight move between
    two candidates is no longer, and neither is one split through P0; s);
    ``robot_time_max_s`` = ``max_poses`` × (``longest_move_s`` + ``per_pose_s``), the robot
    time of a run that reaches its pose limit with every pose measured once (s)."""

    pool: int
    bootstrap: int
    max_poses: int
    target_mm: float
    confidence: float
    per_pose_s: float
    longest_move_s: float
    robot_time_max_s: float


@dataclass(frozen=True)
class DryRun:
    """A plan looked at before it runs. ``spec`` fixes the plan (P0 base_from_flange 4×4
    mm; None for a joints plan whose robot did not answer: its poses come from the robot's
    joints); ``p0_source`` says where P0 came from; ``summary`` is ``plan_summary``'s dict
    (offsets and ranges mm, rotation deg, durations s; the box and the flange's and tool
    points' extent in the base frame, mm; without P0 the offsets are in P0's own flange
    frame and the base-frame extents are None), or {} without a plan; ``refusal`` is None
    when every pose is inside the config's safety envelope (as far as it could be checked),
    else the reason the run would be refused; ``split_moves`` the moves (by the plan pose
    they go to) whose straight path leaves the envelope and that will go through P0,
    ``blocked_moves`` why the moves that cannot are refused (``check_plan_moves``).
    ``adaptive``: what an adaptive run will do (None: a plan run). ``tracker``: the
    offline checks of the tracker section, one line each (:func:`tracker_checks`).
    ``not_checked``: what the dry run could not check, and why (the robot did not answer,
    so P0 is not known)."""

    spec: PlanSpec | None
    p0_source: str
    speed_mm_s: float
    summary: dict[str, Any]
    refusal: str | None
    split_moves: tuple[int, ...] = ()
    blocked_moves: tuple[str, ...] = ()
    adaptive: AdaptiveRun | None = None
    tracker: tuple[str, ...] = ()
    not_checked: tuple[str, ...] = ()

    @property
    def p0_known(self) -> bool:
        """True when P0 is the robot's pose or ``plan.start``, False when the robot did not
        answer and the plan was looked at around a stand-in P0."""
        return not self.not_checked


def tracker_checks(cfg: RigConfig, port: str | None = None) -> tuple[str, ...]:
    """The offline checks of the config's tracker section, one line per thing checked: the
    address (``port`` overrides it, checked as ``--tracker-port`` is), what the driver's
    settings check without the device (``preflight``: an NDI tracker's ROM files), and the
    frame rate (Hz) against the driver's range. ConfigError naming the key for a problem;
    () without a tracker section."""
    t = cfg.tracker
    if t is None:
        return ()
    settings = t.settings.with_address(port) if port else t.settings
    try:
        lines = [f"driver {t.driver}"] + settings.preflight()
    except ConfigError as e:  # with the key's line, as when the config was read
        if cfg.path is None:
            raise
        try:
            text = Path(cfg.path).read_text(encoding="utf-8", errors="replace")
        except OSError:
            raise e from None
        raise with_line(e, str(cfg.path), text) from None
    rng = type(settings).FRAME_RATE_HZ
    lines.append(f"frame rate {t.frame_rate_hz:g} Hz"
                 + (f" (the {t.driver} driver's devices: {rng[0]:g}…{rng[1]:g} Hz)" if rng
                    else ""))
    return tuple(lines)


def _relative_envelope(cfg: RigConfig, p0: np.ndarray) -> Envelope:
    """The config's limits that do not depend on where P0 is: the offset and rotation from
    P0 (mm, deg) and the speed caps, around ``p0``; no workspace box, no tool points."""
    s = cfg.safety
    return Envelope(center=p0, max_offset_mm=s.max_offset_mm,
                    max_rotation_deg=s.max_rotation_deg, max_speed_mm_s=s.max_speed_mm_s,
                    max_accel_mm_s2=s.max_accel_mm_s2)


def _adaptive_run(cfg: RigConfig, settings: AdaptiveSettings, summary: dict[str, Any],
                  speed: float, per_pose_s: float) -> AdaptiveRun:
    accel = cfg.robot.accel_mm_s2 if cfg.robot else 1000.0
    longest = 2.0 * trapezoid_duration(summary["offset_max_mm"], speed, accel)
    return AdaptiveRun(pool=settings.pool, bootstrap=settings.bootstrap_poses(2),
                       max_poses=settings.max_poses, target_mm=settings.target_mm,
                       confidence=settings.confidence, per_pose_s=per_pose_s,
                       longest_move_s=longest,
                       robot_time_max_s=settings.max_poses * (longest + per_pose_s))


def dry_run(cfg: RigConfig, poses: int | None = None, samples: int | None = None,
            robot_host: str | None = None, adaptive: AdaptiveSettings | None = None,
            tracker_port: str | None = None, origin: CalibratedP0 | None = None) -> DryRun:
    """The plan of ``cfg`` (``poses``/``samples`` override it; with ``adaptive`` the plan is
    the run's candidates, ``adaptive.pool`` poses) around P0: the robot's current flange
    pose (read through the configured driver; nothing moves) or ``plan.start``; a joints
    plan also reads the robot's joints (and its arm, unless ``plan.arm`` names it). The
    tracker section is checked offline first (:func:`tracker_checks`, ``tracker_port``
    overriding its address; ConfigError for a problem).

    When the robot does not answer (a ``DeviceError``: refused, no answer, no route), the
    dry run goes on without P0: a pose plan is looked at around a stand-in P0 (the identity)
    for what does not depend on it (offsets and rotations against the limits from P0,
    travel, duration) and ``not_checked`` says what needs P0 (the workspace box for the
    flange and the coil points, the paths between the poses); a joints plan, whose poses
    come from the robot's joints, is not looked at.

    ``origin`` (a calibration's P0, ``acquire --calib``): with ``plan.start: current`` the
    plan is around it, as the run will be, and a pose plan needs no robot for that."""
    checks = tracker_checks(cfg, tracker_port)
    if adaptive is not None:
        poses = adaptive.pool
    joints = None
    offline: str | None = None
    p0: np.ndarray | None = None
    src = "plan.start"
    current = isinstance(cfg.plan.start, str)
    fixed = None if current else np.asarray(cfg.plan.start, dtype=float)
    if current and origin is not None:
        fixed, current = np.array(origin.pose, dtype=float), False
        src = "the calibration's, --calib"
    if current or cfg.plan.kind == JOINTS_KIND:
        try:
            with make_robot(cfg, envelope_for(cfg, None), robot_host) as rb:
                if current:
                    p0, src = rb.flange_pose(), "current flange pose"
                else:
                    # not current: plan.start is a pose, or the calibration's origin set it
                    assert fixed is not None
                    p0 = fixed
                if cfg.plan.kind == JOINTS_KIND:
                    joints = joints_spec(cfg, rb, p0)
        except DeviceError as e:
            offline = str(e)
    else:
        p0 = fixed
    speed = cfg.robot.speed_mm_s if cfg.robot else 100.0
    rate = cfg.tracker.frame_rate_hz if cfg.tracker else 60.0
    n_samples = samples or cfg.sampling.samples
    per_pose_s = cfg.sampling.settle_s + n_samples / rate
    if offline is not None and cfg.plan.kind == JOINTS_KIND:
        return DryRun(spec=None, p0_source="not known (the robot did not answer)",
                      speed_mm_s=speed, summary={}, refusal=None, tracker=checks,
                      not_checked=(f"robot: did not answer: {offline}",
                                   "not checked without the robot: the joints plan (its "
                                   "poses come from the robot's joint angles and arm)"))
    not_checked: tuple[str, ...] = ()
    if offline is not None:
        p0 = np.eye(4)
        src = "plan.start: current, not known without the robot"
        envelope = _relative_envelope(cfg, p0)
        not_checked = (f"robot: did not answer: {offline}",
                       "not checked without the robot: the workspace box for the flange and "
                       "the coil's points, and the paths between the poses (they need P0, "
                       "the flange pose when the run starts); checked: the offsets and "
                       "rotations from P0 against max_offset_mm and max_rotation_deg, the "
                       "travel and the duration, which do not depend on where P0 is")
    else:
        assert p0 is not None
        envelope = envelope_for(cfg, p0)
    spec = PlanSpec.from_config(cfg.plan, p0, poses, joints)
    plan = plan_poses(spec, envelope)
    summary = plan_summary(plan, p0, speed, cfg.sampling.settle_s, n_samples, rate,
                           envelope=envelope)
    try:
        check_plan(plan, envelope)
        refusal = None
    except SafetyError as e:
        refusal = str(e)
    split: list[int] = []
    blocked: list[str] = []
    if offline is None:
        split, blocked = check_plan_moves(plan, envelope, p0)
    if refusal is None and blocked:
        refusal = blocked[0]
    run = None if adaptive is None else _adaptive_run(cfg, adaptive, summary, speed,
                                                      per_pose_s)
    return DryRun(spec=spec, p0_source=src, speed_mm_s=speed, summary=summary,
                  refusal=refusal, split_moves=tuple(split), blocked_moves=tuple(blocked),
                  adaptive=run, tracker=checks, not_checked=not_checked)
