"""Acquisition plans: the poses of a plan of any kind (``plan_poses``: the one place a plan's
poses are made; a ``joints`` plan's parameters from the robot, ``joints_spec``), the safety
check of a whole plan before anything moves (``check_plan``, every pose;
``check_plan_moves``, the way between them) and the dry run's summary (``plan_summary``), all
as values: nothing here prints. Poses are base_from_flange 4×4 in mm; which poses a plan
visits (``PlanSpec``) and the pose generators live in :mod:`tmscal.poses`, the joints plan's
sampler in :mod:`tmscal.calib.kinematics.excite`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..drivers.base import ConfigError, Envelope, SafetyError
from ..errors import SessionError
from ..poses import JOINTS_KIND, MAX_PLAN_POSES, JointsSpec, PlanSpec, make_plan
from ..safety import DEFAULT_LAW, MotionLaw, check_path, plan_move

__all__ = ["MAX_PLAN_POSES", "PlanSpec", "JointsSpec", "check_plan", "check_plan_moves",
           "plan_summary", "make_plan", "plan_poses", "joints_spec"]

#: a joints plan's q0 must put the nominal arm at its P0 to this (mm, and rotation entries)
Q0_TOL_MM = 1e-3


def plan_poses(spec: PlanSpec, envelope: Envelope | None) -> np.ndarray:
    """The poses (n, 4, 4) base_from_flange mm of the plan ``spec``: ``spec.poses()`` for the
    pose kinds; for ``joints`` the configurations of its arm spread inside ``envelope``
    (:func:`tmscal.calib.kinematics.excite.joints_plan`: ConfigError when too few are
    inside). SessionError when a joints plan's recorded q0 does not put the nominal arm at
    its P0 (an edited header)."""
    if spec.kind != JOINTS_KIND:
        return spec.poses()
    from ..calib.kinematics import arm_by_name, base_from_flange
    from ..calib.kinematics.excite import joints_plan

    j = spec.joints
    if j is None:
        raise SessionError("a joints plan without its 'joints' entry (arm, q0_rad, frame)")
    arm = arm_by_name(j.arm, "the plan's joints.arm")
    if len(j.q0) != arm.n_joints:
        raise SessionError(f"the plan's joints.q0_rad has {len(j.q0)} joints; the {arm.name} "
                           f"arm has {arm.n_joints}")
    at = j.frame @ base_from_flange(arm, j.q0)
    if not float(np.abs(at - spec.p0).max()) <= Q0_TOL_MM:
        raise SessionError(f"the plan's joints.q0_rad put the {arm.name} arm's flange at "
                           f"{np.round(at[:3, 3], 3).tolist()} mm, not at its P0 "
                           f"{np.round(spec.p0[:3, 3], 3).tolist()} mm: the plan was edited")
    return joints_plan(arm, j.q0, j.frame, spec.p0, spec.n, spec.seed, j.pool, j.span_deg,
                       spec.radius_mm, spec.rotation_deg, envelope).poses


def joints_spec(cfg: Any, robot: Any, p0: np.ndarray) -> JointsSpec:
    """A new joints plan's parameters (:class:`JointsSpec`) for the config ``cfg`` (its
    ``plan`` section) on ``robot`` (a connected driver) around ``p0`` (base_from_flange 4×4
    mm): the arm ``plan.arm``, else the one the driver reports; the robot's joints (rad) and
    flange pose now give the controller frame and the joints of P0. ConfigError naming
    ``plan.arm`` when no arm is known or P0 is out of its reach, ``robot.driver`` when the
    driver reports no joints."""
    from ..calib.kinematics import arm_by_name
    from ..calib.kinematics.arms import ARM_NAMES
    from ..calib.kinematics.excite import start_joints

    plan = cfg.plan
    name = plan.arm or (robot.identity() or {}).get("arm")
    if not name:
        raise ConfigError(f"{cfg.path}: key 'plan.arm': the robot driver does not say which "
                          f"arm it is; name it for the joints plan (one of "
                          f"{', '.join(ARM_NAMES)})")
    arm = arm_by_name(name, f"{cfg.path}: key 'plan.arm'")
    try:
        q_now = np.asarray(robot.joint_positions(), dtype=float)
    except NotImplementedError as e:
        raise ConfigError(f"{cfg.path}: key 'robot.driver': {e}; the joints plan needs the "
                          "joint angles") from None
    try:
        q0, frame = start_joints(arm, p0, q_now, robot.flange_pose())
    except ConfigError as e:
        raise ConfigError(f"{cfg.path}: {e}") from None
    return JointsSpec(arm.name, q0, frame, float(plan.span_deg), int(plan.pool))


def check_plan(poses: np.ndarray, envelope: Envelope) -> None:
    """Check every pose of a plan against the envelope before anything moves. Raises
    SafetyError naming the first offending pose (index, position in mm) and the limits."""
    for i, P in enumerate(poses):
        v = envelope.violations(P)
        if v:
            pos = np.round(P[:3, 3], 1).tolist()
            raise SafetyError(f"plan pose {i} (flange at {pos} mm in the base frame) leaves "
                              f"the safety envelope: {'; '.join(v)}. Nothing was moved.")


def check_plan_moves(poses: np.ndarray, envelope: Envelope, start: np.ndarray,
                     law: MotionLaw = DEFAULT_LAW) -> tuple[list[int], list[str]]:
    """The way between a plan's poses (from ``start``, P0, through every pose in order; 4×4
    base_from_flange mm) looked at before the run, as the flange's straight path: (the moves
    whose straight path leaves the envelope and will be split through P0, the refusals of the
    moves for which no split route stays inside either). Judged with ``law``, by default the
    most cautious one (a straight flange move that turns only while translating:
    docs/safety.md) for a dry run that knows no controller; a new run gives its robot's own
    ``motion_law()``, and each move is planned again before it is sent. Moves are numbered by
    the pose they go to."""
    split: list[int] = []
    refused: list[str] = []
    prev = np.asarray(start, dtype=np.float64)
    for i, P in enumerate(np.asarray(poses, dtype=np.float64)):
        if not envelope.violations(prev) and not envelope.violations(P) \
                and check_path(envelope, prev, P, law.path) is not None:
            try:
                plan_move(envelope, prev, P, law, 1.0, 1.0, f"move to plan pose {i}")
                split.append(i)
            except SafetyError as e:
                refused.append(str(e))
        prev = P
    return split, refused


def plan_summary(poses: np.ndarray, p0: np.ndarray, speed_mm_s: float, settle_s: float,
                 samples: int, frame_rate_hz: float, start: np.ndarray | None = None,
                 envelope: Envelope | None = None) -> dict[str, Any]:
    """Extent of a plan and an estimate of its duration (for ``--dry-run``).

    Offsets are flange positions relative to P0 (mm, base frame), rotations relative to P0
    (deg). Duration = straight-line travel at ``speed_mm_s`` (from ``start``, default P0,
    through every pose) + settle + samples / frame rate, per pose (s).

    In the robot base frame (mm): ``box_min_mm``/``box_max_mm`` the envelope's workspace box
    (None without an envelope or box); ``flange_min_mm``/``flange_max_mm`` the extent of the
    flange origins over the plan; ``tool_min_mm``/``tool_max_mm`` the extent of the
    envelope's tool points (flange frame, carried by every pose), or None without them.
    Lists of 3 floats [x, y, z]."""
    from ..geometry import angle_between

    d = poses[:, :3, 3] - p0[:3, 3]
    rot = np.degrees(angle_between(p0, poses))
    path = np.concatenate([[(p0 if start is None else start)[:3, 3]], poses[:, :3, 3]])
    travel = float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())
    per_pose = settle_s + samples / frame_rate_hz
    flange = poses[:, :3, 3]
    # an Envelope has both box corners or neither
    box_min = None if envelope is None else envelope.box_min_mm
    box_max = None if envelope is None else envelope.box_max_mm
    tools = None
    if envelope is not None and envelope.tool_points_mm is not None and len(poses):
        q = np.asarray(envelope.tool_points_mm, dtype=np.float64)
        tools = (np.einsum("nij,kj->nki", poses[:, :3, :3], q)
                 + poses[:, None, :3, 3]).reshape(-1, 3)

    def extent(a: np.ndarray | None, f: Any) -> list[float] | None:
        return None if a is None or not len(a) else [float(x) for x in f(a, axis=0)]

    return {
        "poses": int(len(poses)),
        "offset_max_mm": float(np.linalg.norm(d, axis=1).max()) if len(d) else 0.0,
        "x_range_mm": (float(d[:, 0].min()), float(d[:, 0].max())),
        "y_range_mm": (float(d[:, 1].min()), float(d[:, 1].max())),
        "z_range_mm": (float(d[:, 2].min()), float(d[:, 2].max())),
        "rotation_max_deg": float(rot.max()) if len(rot) else 0.0,
        "travel_mm": travel,
        "motion_s": travel / speed_mm_s,
        "sampling_s": per_pose * len(poses),
        "duration_s": travel / speed_mm_s + per_pose * len(poses),
        "box_min_mm": None if box_min is None else [float(x) for x in box_min],
        "box_max_mm": None if box_max is None else [float(x) for x in box_max],
        "flange_min_mm": extent(flange, np.min),
        "flange_max_mm": extent(flange, np.max),
        "tool_min_mm": extent(tools, np.min),
        "tool_max_mm": extent(tools, np.max),
    }
