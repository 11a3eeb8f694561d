"""The ``plan`` section (where the robot goes: Eq. 14 of Wang et al. 2018 or a sphere around
P0, or joint configurations spread inside the envelope) and poses written in a config: a 4×4
list in mm or ``{xyz_mm, rpy_deg}``."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from ..poses import ALL_PLAN_KINDS, JOINTS_KIND, MAX_PLAN_POSES
from .safety import COORD_BOUND_MM
from .sections import PlanConfig
from .values import INT_BOUND, build, err, in_range, positive

__all__ = ["pose_from_config", "parse_plan"]


def pose_from_config(value: Any, src: str, key: str) -> np.ndarray:
    """A pose from a config value: a 4×4 list (mm) or {xyz_mm: [..], rpy_deg: [..]} with
    R = Rz·Ry·Rx (DENSO-style fixed axes)."""
    from ..geometry import check_pose, matrix_from_denso_p
    if isinstance(value, Mapping):
        try:
            if set(value) - {"xyz_mm", "rpy_deg"}:
                raise ValueError
            xyz = [float(x) for x in value["xyz_mm"]]
            rpy = [float(x) for x in value.get("rpy_deg", [0, 0, 0])]
            if len(xyz) != 3 or len(rpy) != 3 or not all(map(math.isfinite, xyz + rpy)):
                raise ValueError
        except (KeyError, TypeError, ValueError, OverflowError):
            raise err(src, key, "expected {xyz_mm: [x, y, z], rpy_deg: [rx, ry, rz]}") \
                from None
        return matrix_from_denso_p(xyz + rpy)
    try:
        return check_pose(value, key)
    except (ValueError, TypeError, OverflowError) as e:
        raise err(src, key, f"expected a rigid 4×4 matrix in mm ({e})") from None


def parse_plan(data: Any, src: str) -> PlanConfig:
    """The plan section: kind, pose count, ranges, seed, and start ("current" or a pose)."""
    plan = build(PlanConfig, data, src, "plan")
    if plan.kind not in ALL_PLAN_KINDS:
        known = " or ".join(repr(k) for k in ALL_PLAN_KINDS)
        raise err(src, "plan.kind", f"expected {known}, got {plan.kind!r}")
    _check_joints(plan, src)
    if plan.poses < 3:  # the fewest poses a solve takes (as acquire --poses)
        raise err(src, "plan.poses", f"must be at least 3, the fewest poses a solve takes; "
                  f"got {plan.poses}")
    in_range(src, "plan.poses", plan.poses, 3, 100_000)
    positive(src, "plan.radius_mm", plan.radius_mm, allow_zero=True, at_most=COORD_BOUND_MM)
    positive(src, "plan.rotation_deg", plan.rotation_deg, allow_zero=True, at_most=180.0)
    in_range(src, "plan.seed", plan.seed, 0, INT_BOUND - 1)
    if isinstance(plan.start, str):
        if plan.start != "current":
            raise err(src, "plan.start", f"expected 'current' or a pose, got {plan.start!r}")
    else:
        plan.start = pose_from_config(plan.start, src, "plan.start")
        if not np.all(np.abs(plan.start[:3, 3]) <= COORD_BOUND_MM):
            raise err(src, "plan.start", f"position must be within ±{COORD_BOUND_MM:g} mm")
    return plan


def _check_joints(plan: PlanConfig, src: str) -> None:
    """``plan.arm``, ``span_deg``, ``pool``: only with kind ``joints`` (completed with their
    defaults there); the arm a registered one."""
    keys = ("arm", "span_deg", "pool")
    if plan.kind != JOINTS_KIND:
        for k in keys:
            if getattr(plan, k) is not None:
                raise err(src, f"plan.{k}", f"goes with plan.kind {JOINTS_KIND!r} only")
        return
    from ..calib.kinematics.arms import ARM_NAMES
    from ..calib.kinematics.excite import JOINTS_POOL, JOINTS_SPAN_DEG

    if plan.arm is not None:
        if plan.arm not in ARM_NAMES:
            raise err(src, "plan.arm", f"expected one of {', '.join(ARM_NAMES)}, got "
                      f"{plan.arm!r}")
    if plan.span_deg is None:
        plan.span_deg = JOINTS_SPAN_DEG
    positive(src, "plan.span_deg", plan.span_deg, at_most=180.0)
    if plan.pool is None:
        plan.pool = JOINTS_POOL
    in_range(src, "plan.pool", plan.pool, 1, MAX_PLAN_POSES)
