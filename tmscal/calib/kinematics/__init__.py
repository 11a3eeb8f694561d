"""Serial-arm kinematics: the arm model (standard or modified DH, base, flange, joint limits)
and its batched forward kinematics (:mod:`.model`), the pose Jacobian with respect to the
geometric parameters (:mod:`.jacobian`) and the one registry of nominal arms (:mod:`.arms`);
the estimator with hand/eye (:mod:`.estimate`, its identifiability in :mod:`.identifiability`).
Pure numerics, no I/O; docs/kinematics.md."""

from .arms import ARM_NAMES, ARMS, ArmSpec, arm_by_name, find_arm, spec_by_name
from .jacobian import joint_jacobian, pose_jacobian
from .model import (
    CONVENTIONS,
    Arm,
    base_from_flange,
    forward,
    joint_frames,
    pose_from_rpy,
    rpy_from_matrix,
)

__all__ = ["Arm", "CONVENTIONS", "forward", "base_from_flange", "joint_frames",
           "pose_from_rpy", "rpy_from_matrix", "pose_jacobian", "joint_jacobian", "ArmSpec",
           "ARMS", "ARM_NAMES", "arm_by_name", "spec_by_name", "find_arm"]
