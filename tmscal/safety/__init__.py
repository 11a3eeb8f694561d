"""Motion safety: the envelope (limits on a pose), the path a controller takes between two poses
and whether all of it stays inside, the speed of the tool points, and the plan of one move
(checked, split through P0 when needed, timed for the fastest tool point). Pure numerics, no
I/O: ``tmscal.drivers.base.Robot.move_to`` runs :func:`plan_move` before it sends anything.
docs/safety.md says what is checked and what is not.
"""

from __future__ import annotations

from .envelope import LIMIT_TOL, Envelope, positive_finite
from .laws import AxisProfile, SharedProfile, point_bounds, scale
from .paths import (
    SAG_MM,
    AxisPath,
    LinearPath,
    Violation,
    check_axis,
    check_joint_path,
    check_linear,
    check_path,
    linear_flange_poses,
)
from .route import DEFAULT_LAW, Leg, MotionLaw, Route, plan_move, split_waypoints

__all__ = [
    "LIMIT_TOL", "SAG_MM", "DEFAULT_LAW", "Envelope", "positive_finite", "AxisProfile",
    "SharedProfile", "point_bounds", "scale", "AxisPath", "LinearPath", "Violation",
    "check_axis", "check_joint_path", "check_linear", "check_path", "linear_flange_poses",
    "Leg", "MotionLaw", "Route", "plan_move", "split_waypoints",
]
