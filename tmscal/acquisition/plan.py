"""Acquisition plans: the safety check of a whole plan before anything moves (``check_plan``,
every pose; ``check_plan_moves``, the way between them) and the dry run's summary
(``plan_summary``), all as values: nothing here prints. Poses are
base_from_flange 4×4 in mm; which poses a plan visits (``PlanSpec``) and the generators live
in :mod:`tmscal.poses`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..drivers.base import Envelope, SafetyError
from ..poses import MAX_PLAN_POSES, PlanSpec, make_plan
from ..safety import DEFAULT_LAW, check_path, plan_move

__all__ = ["MAX_PLAN_POSES", "PlanSpec", "check_plan", "check_plan_moves", "plan_summary",
           "make_plan"]


def check_plan(poses: np.ndarray, envelope: Envelope) -> None:
    """Check every pose of a plan against the envelope before anything moves. Raises
    SafetyError naming the first offending pose (index, position in mm) and the limits."""
    for i, P in enumerate(poses):
        v = envelope.violations(P)
        if v:
            pos = np.round(P[:3, 3], 1).tolist()
            raise SafetyError(f"plan pose {i} (flange at {pos} mm in the base frame) leaves "
                              f"the safety envelope: {'; '.join(v)}. Nothing was moved.")


def check_plan_moves(poses: np.ndarray, envelope: Envelope, start: np.ndarray
                     ) -> tuple[list[int], list[str]]:
    """The way between a plan's poses (from ``start``, P0, through every pose in order; 4×4
    base_from_flange mm) looked at before the run, as the flange's straight path: (the moves
    whose straight path leaves the envelope and will be split through P0, the refusals of the
    moves for which no split route stays inside either). Judged with the most cautious motion
    law (a straight flange move that turns only while translating: docs/safety.md); at run
    time each move is planned again with the controller's own law before it is sent. Moves
    are numbered by the pose they go to."""
    split: list[int] = []
    refused: list[str] = []
    prev = np.asarray(start, dtype=np.float64)
    for i, P in enumerate(np.asarray(poses, dtype=np.float64)):
        if not envelope.violations(prev) and not envelope.violations(P) \
                and check_path(envelope, prev, P, DEFAULT_LAW.path) is not None:
            try:
                plan_move(envelope, prev, P, DEFAULT_LAW, 1.0, 1.0, f"move to plan pose {i}")
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
    box = envelope is not None and envelope.box_min_mm is not None
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
        "box_min_mm": [float(x) for x in envelope.box_min_mm] if box else None,
        "box_max_mm": [float(x) for x in envelope.box_max_mm] if box else None,
        "flange_min_mm": extent(flange, np.min),
        "flange_max_mm": extent(flange, np.max),
        "tool_min_mm": extent(tools, np.min),
        "tool_max_mm": extent(tools, np.max),
    }
