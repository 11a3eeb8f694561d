"""The dry run of ``tmscal acquire --dry-run``, as a value: the plan around P0, its extent and
estimated duration, and whether every pose is inside the safety envelope. The robot is only
asked where it is (when the plan starts at the current pose); nothing moves. The CLI prints
the result.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..config import RigConfig
from ..errors import SafetyError
from ..poses import JOINTS_KIND
from .devices import envelope_for, make_robot
from .plan import (
    PlanSpec,
    check_plan,
    check_plan_moves,
    joints_spec,
    plan_poses,
    plan_summary,
)

__all__ = ["DryRun", "dry_run"]


@dataclass(frozen=True)
class DryRun:
    """A plan looked at before it runs. ``spec`` fixes the plan (P0 base_from_flange 4×4
    mm); ``p0_source`` says where P0 came from; ``summary`` is ``plan_summary``'s dict
    (offsets and ranges mm, rotation deg, durations s; the box and the flange's and tool
    points' extent in the base frame, mm); ``refusal`` is None when every pose is inside the
    config's safety envelope, else the reason the run would be refused; ``split_moves`` the
    moves (by the plan pose they go to) whose straight path leaves the envelope and that
    will go through P0, ``blocked_moves`` why the moves that cannot are refused
    (``check_plan_moves``)."""

    spec: PlanSpec
    p0_source: str
    speed_mm_s: float
    summary: dict[str, Any]
    refusal: str | None
    split_moves: tuple[int, ...] = ()
    blocked_moves: tuple[str, ...] = ()


def dry_run(cfg: RigConfig, poses: int | None = None, samples: int | None = None,
            robot_host: str | None = None) -> DryRun:
    """The plan of ``cfg`` (``poses``/``samples`` override it) around P0: the robot's current
    flange pose (read through the configured driver; nothing moves) or ``plan.start``; a
    joints plan also reads the robot's joints (and its arm, unless ``plan.arm`` names it)."""
    joints = None
    if isinstance(cfg.plan.start, str) or cfg.plan.kind == JOINTS_KIND:
        with make_robot(cfg, envelope_for(cfg, None), robot_host) as rb:
            if isinstance(cfg.plan.start, str):
                p0, src = rb.flange_pose(), "current flange pose"
            else:
                p0, src = np.asarray(cfg.plan.start, dtype=float), "plan.start"
            if cfg.plan.kind == JOINTS_KIND:
                joints = joints_spec(cfg, rb, p0)
    else:
        p0 = np.asarray(cfg.plan.start, dtype=float)
        src = "plan.start"
    spec = PlanSpec.from_config(cfg.plan, p0, poses, joints)
    envelope = envelope_for(cfg, p0)
    plan = plan_poses(spec, envelope)
    speed = cfg.robot.speed_mm_s if cfg.robot else 100.0
    rate = cfg.tracker.frame_rate_hz if cfg.tracker else 60.0
    summary = plan_summary(plan, p0, speed, cfg.sampling.settle_s,
                           samples or cfg.sampling.samples, rate, envelope=envelope)
    try:
        check_plan(plan, envelope)
        refusal = None
    except SafetyError as e:
        refusal = str(e)
    split, blocked = check_plan_moves(plan, envelope, p0)
    if refusal is None and blocked:
        refusal = blocked[0]
    return DryRun(spec=spec, p0_source=src, speed_mm_s=speed, summary=summary,
                  refusal=refusal, split_moves=tuple(split), blocked_moves=tuple(blocked))
