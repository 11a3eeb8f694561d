"""ROS easy_handeye / easy_handeye2 calibration YAML (``tmscal export --format easy-handeye``).

Eye-on-base: the tracker ("eye") stands beside the robot. easy_handeye publishes the stored
transform with header frame ``robot_base_frame`` and child frame ``tracking_base_frame``, i.e.
the pose of the tracker in the robot base: tmscal's Z = base_from_tracker itself (not its
inverse), orthonormal, translation in METRES, rotation as a unit quaternion (x, y, z, w) with
w ≥ 0.

* easy_handeye (ROS 1): ``parameters`` {eye_on_hand: false, namespace, move_group_namespace,
  move_group, robot_base_frame, robot_effector_frame, tracking_base_frame,
  tracking_marker_frame} (exactly the arguments of its HandeyeCalibrationParameters, which
  ``from_dict`` passes them to) and ``transformation`` {x, y, z, qx, qy, qz,
  qw}.
* easy_handeye2 (ROS 2; ``--easy-handeye2``): the easy_handeye2_msgs/HandeyeCalibration
  message as YAML: ``parameters`` {name, calibration_type: eye_on_base, robot_base_frame,
  robot_effector_frame, tracking_base_frame, tracking_marker_frame, freehand_robot_movement,
  move_group_namespace, move_group} and ``transform`` {translation {x, y, z}, rotation {x, y, z,
  w}}.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import yaml

from ..escape import visible
from ..formats.calibfile import CalibrationFile
from ..geometry import quaternion_from_matrix

__all__ = ["FRAMES", "transform_m_xyzw", "render"]

#: default tf frame names (override with ``frames``)
FRAMES = {"robot_base_frame": "base_link", "robot_effector_frame": "tool0",
          "tracking_base_frame": "tracker", "tracking_marker_frame": "coil_marker"}


def transform_m_xyzw(Z: np.ndarray) -> tuple[list[float], list[float]]:
    """(translation in metres, quaternion [x, y, z, w] with w ≥ 0) of a rigid 4×4 in mm."""
    q = quaternion_from_matrix(np.asarray(Z, dtype=float)[:3, :3])  # (w, x, y, z), w ≥ 0
    t = (np.asarray(Z, dtype=float)[:3, 3] / 1000.0).tolist()
    return [float(v) for v in t], [float(q[1]), float(q[2]), float(q[3]), float(q[0])]


def render(cf: CalibrationFile, version: int = 1, name: str = "tmscal_eye_on_base",
           frames: dict[str, str] | None = None) -> str:
    """The YAML text for easy_handeye (``version`` 1) or easy_handeye2 (2)."""
    f = {**FRAMES, **(frames or {})}
    t, q = transform_m_xyzw(cf.calibration.exported()["Z"])
    doc: dict[str, Any]
    if version == 1:
        doc = {"parameters": {"eye_on_hand": False, "namespace": f"/{name}/",
                              "move_group_namespace": "/", "move_group": "manipulator", **f},
               "transformation": dict(zip(("x", "y", "z"), t, strict=True))
               | dict(zip(("qx", "qy", "qz", "qw"), q, strict=True))}
    else:
        doc = {"parameters": {"name": name, "calibration_type": "eye_on_base", **f,
                              "freehand_robot_movement": True, "move_group_namespace": "/",
                              "move_group": "manipulator"},
               "transform": {"translation": dict(zip(("x", "y", "z"), t, strict=True)),
                             "rotation": dict(zip(("x", "y", "z", "w"), q, strict=True))}}
    head = (visible(f"# tmscal {cf.calibration.method} calibration {cf.path.name}: "
                    "eye-on-base, the tracker in the robot base") + "\n"
            + visible(f"# (Z = base_from_tracker = {f['robot_base_frame']} <- "
                      f"{f['tracking_base_frame']}), translation in metres, quaternion x y z w")
            + "\n")
    return head + yaml.safe_dump(doc, sort_keys=False, default_flow_style=False)
