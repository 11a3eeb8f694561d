"""Which arm a DENSO controller drives, from the robot's ``@TYPE_NAME`` variable (b-CAP
``Robot_GetVariable`` on the arm, then ``Variable_GetValue``: a string; DENSO's RC8 provider),
to a registry name (docs/kinematics.md, "Which arm the controller is").

DENSO's own ROS drivers (denso_robot_ros, denso_robot_ros2: ``CheckRobotType``) accept a robot
when its ``@TYPE_NAME`` begins with the model name they were started for (``vs060``,
``cobotta``); this does the same against the registry's DENSO arms, ignoring case, spaces,
hyphens and underscores (``VS-060…`` and ``vs060…`` alike). None when no registered arm's name
begins it (another DENSO model, no answer).
"""

from __future__ import annotations

__all__ = ["denso_arm", "VENDOR"]

#: the vendor name of DENSO arms in the arm registry
VENDOR = "DENSO"


def _key(s: str) -> str:
    return "".join(c for c in s.lower() if c.isalnum())


def denso_arm(type_name: object) -> str | None:
    """The registered DENSO arm (``vs060``, ``cobotta``) whose model name begins the
    controller's ``@TYPE_NAME`` ``type_name``; None when none (or more than one) does."""
    from ...calib.kinematics import ARMS

    if not isinstance(type_name, str) or not _key(type_name):
        return None
    have = _key(type_name)
    hits = [s.name for s in ARMS.values()
            if s.vendor == VENDOR and have.startswith(_key(s.controller_model))]
    return hits[0] if len(hits) == 1 else None
