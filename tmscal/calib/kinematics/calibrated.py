"""An identified arm as a calibration carries it (``Calibration.arm``): the controller's
nominal model, the identified one, the frame the controller reports in, and what the
estimation found (docs/kinematics.md, "Using it"). Pure numerics, no I/O.

Frames: the identified and the nominal arm give base_from_flange in the arm's own DH base
frame; the controller may report in a frame fixed to that base (a work coordinate system, a
mounting offset): ``controller_frame`` M = controller's frame ← DH base (4×4 mm), found from
the session as the mean of A_i · base_from_flange(nominal, q_i)⁻¹ (the identity for a
controller that reports its base frame). The calibration's Z is in the controller's frame,
so everything a user sees (A, Z, commanded poses) is in the frame the controller speaks.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...errors import CalibrationError
from ...geometry import orthonormalize, rotation_angle
from .ik import inverse
from .model import Arm, base_from_flange

__all__ = ["ArmCalibration", "controller_frame", "spread_seeds", "MAX_SEEDS"]

#: joint configurations kept as seeds of the inverse kinematics (spread over the session)
MAX_SEEDS = 8
#: the controller frame's consistency over a session (mm, deg) above which the recorded robot
#: poses are not the nominal arm's forward kinematics of the recorded joints
FRAME_TOL_MM = 1.0
FRAME_TOL_DEG = 0.1


def controller_frame(nominal: Arm, A: np.ndarray, q: np.ndarray, where: str = "session"
                     ) -> np.ndarray:
    """M = controller's frame ← the arm's DH base (4×4 mm) from recorded robot poses A
    (n, 4, 4) and joints q (n, dof): the mean of A_i · base_from_flange(nominal, q_i)⁻¹.
    CalibrationError when these disagree by more than ``FRAME_TOL_MM`` / ``FRAME_TOL_DEG``:
    the recorded poses are then not this arm's nominal kinematics (another arm model, or the
    controller reports a tool frame)."""
    F = base_from_flange(nominal, q)
    Ms = A @ np.linalg.inv(F)
    M = orthonormalize(np.mean(Ms, axis=0))
    M[3] = [0.0, 0.0, 0.0, 1.0]
    dt = float(np.linalg.norm(Ms[:, :3, 3] - M[:3, 3], axis=1).max())
    dr = float(np.degrees(rotation_angle(np.swapaxes(Ms[:, :3, :3], 1, 2) @ M[:3, :3])).max())
    if dt > FRAME_TOL_MM or dr > FRAME_TOL_DEG:
        raise CalibrationError(
            f"{where}: the recorded robot poses are not the {nominal.name} nominal forward "
            f"kinematics of the recorded joints (they differ by up to {dt:.1f} mm / "
            f"{dr:.2f}° beyond one fixed frame): is the arm model right (--arm), and does "
            "the controller report the flange (not a tool frame)?")
    return M


def spread_seeds(q: np.ndarray, k: int = MAX_SEEDS) -> np.ndarray:
    """Up to ``k`` of the joint configurations q (n, dof) rad, spread out (greedy farthest
    point from the median configuration): seeds of the inverse kinematics."""
    q = np.asarray(q, dtype=float)
    med = np.median(q, axis=0)
    chosen = [int(np.argmin(np.abs(q - med).max(axis=1)))]
    d = np.abs(q - q[chosen[0]]).max(axis=1)
    while len(chosen) < min(k, len(q)):
        j = int(np.argmax(d))
        if d[j] == 0:
            break
        chosen.append(j)
        d = np.minimum(d, np.abs(q - q[j]).max(axis=1))
    return q[chosen]


@dataclass(frozen=True)
class ArmCalibration:
    """The arm of a calibration: ``nominal`` (the controller's model), ``arm`` (identified:
    the nominal plus the estimated deviations), ``controller_frame`` (4×4 mm, controller's
    frame ← DH base), ``seeds`` (k, dof) rad joint configurations of the calibration's poses
    (inverse-kinematics seeds) and ``report`` (what the estimation found: level, deviations
    and their σ, identified and unidentified combinations, held-out errors; plain types)."""

    nominal: Arm
    arm: Arm
    controller_frame: np.ndarray = field(default_factory=lambda: np.eye(4))
    seeds: np.ndarray | None = None
    report: dict[str, Any] = field(default_factory=dict)

    def robot_poses(self, q: Any) -> np.ndarray:
        """Where the flange really is at joints q (n, dof) rad, in the controller's frame:
        M · base_from_flange(identified arm, q) (n, 4, 4) mm."""
        return self.controller_frame @ base_from_flange(self.arm, np.atleast_2d(q))

    def command(self, A_true: np.ndarray, seeds: Any = None) -> np.ndarray:
        """The flange poses to COMMAND (controller's frame, its nominal kinematics; (n, 4, 4)
        mm) so that the flange really reaches ``A_true`` (n, 4, 4) mm in the controller's
        frame: q = inverse kinematics of the identified arm, then M · base_from_flange(nominal,
        q). ``seeds`` (k, dof) rad are tried first (e.g. the arm's joints now), then the
        calibration's. CalibrationError naming the pose when the identified arm cannot reach
        it."""
        A_true = np.asarray(A_true, dtype=float).reshape(-1, 4, 4)
        M_inv = np.linalg.inv(self.controller_frame)
        own = [] if self.seeds is None else list(self.seeds)
        given = [] if seeds is None else list(np.atleast_2d(np.asarray(seeds, dtype=float)))
        out = np.empty_like(A_true)
        for i, T in enumerate(A_true):
            target = M_inv @ T
            order = sorted(own, key=lambda s: float(np.linalg.norm(
                base_from_flange(self.arm, s)[:3, 3] - target[:3, 3])))
            q = inverse(self.arm, target, given + order)
            if q is None:
                raise CalibrationError(
                    f"pose {i}: the identified {self.arm.name} arm cannot reach the flange "
                    f"pose {np.round(T[:3, 3], 1).tolist()} mm (no inverse kinematics within "
                    "its joint limits from the calibration's configurations)")
            out[i] = self.controller_frame @ base_from_flange(self.nominal, q)
        return out
