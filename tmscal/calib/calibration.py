"""The result of a solve: ``Calibration`` (X, Y, Z and the raw linear solution; 4×4 mm), which
matrices it applies (``Applied``), its hold-out errors and the placement of the coil it
commands (docs/methods.md).

Frames: A = base_from_flange, B = tracker_from_marker, C = tracker_from_probe,
X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np

from ..errors import CalibrationError
from ..geometry import invert, orthonormalize
from .metrics import holdout_errors
from .ml_model import undistort

if TYPE_CHECKING:
    from .kinematics.calibrated import ArmCalibration

__all__ = ["Applied", "Calibration", "Matrices"]


class Matrices(TypedDict):
    """The matrices a calibration applies or exports (4×4 mm): X = flange_from_marker, Y =
    flange_from_probe (None for marker-only data), Z = base_from_tracker, Z_probe = QR24's
    separate base_from_tracker of the probe (None otherwise)."""

    X: np.ndarray
    Y: np.ndarray | None
    Z: np.ndarray
    Z_probe: np.ndarray | None


class Applied(StrEnum):
    """Which matrices a calibration applies: the raw linear solution (the paper's way: raw
    matrices, the product orthonormalised) or the orthonormal ones."""

    RAW = "raw"
    ORTHONORMAL = "orthonormal"


@dataclass
class Calibration:
    """Result of a solve. All 4×4, mm.

    ``X``, ``Y``, ``Z``: orthonormal (rotations projected to SO(3), translations re-solved).
    ``X_raw``, ``Y_raw``, ``Z_raw``: the linear solution, general 3×4 (last row 0001).
    ``Z_probe_raw`` / ``Z_probe``: QR24 on two bodies solves the probe separately; this is its Z.
    ``applied``: "raw" (the paper's way: raw matrices, orthonormalise the product) or
    "orthonormal" — which set :meth:`used` returns and :meth:`errors` applies.
    Y is None for marker-only data.
    """

    method: str
    n_poses: int
    X: np.ndarray
    Z: np.ndarray
    X_raw: np.ndarray
    Z_raw: np.ndarray
    Y: np.ndarray | None = None
    Y_raw: np.ndarray | None = None
    Z_probe: np.ndarray | None = None
    Z_probe_raw: np.ndarray | None = None
    applied: Applied = Applied.RAW
    #: parameter covariance of a statistical solver (e.g. ``ml``), in the order and units its
    #: ``extra["parameters"]`` names; None for the closed-form methods
    covariance: np.ndarray | None = None
    #: predicted uncertainty, e.g. {"coil_centre_mm": {"sigma": …, "p95": …},
    #: "coil_axis_deg": {…}}; None when the method gives none
    uncertainty: dict[str, Any] | None = None
    #: the tracker distortion a solver found, e.g. {"model": "scale", "matrix": 3×3,
    #: "scale_percent": 0.08}; None when not modelled
    distortion: dict[str, Any] | None = None
    #: method-specific facts (iterations, restarts, the information criterion, …)
    extra: dict[str, Any] = field(default_factory=dict)
    #: the arm's kinematics identified with X, Y, Z (``tmscal solve --kinematics estimate``,
    #: docs/kinematics.md): robot poses from joints, and the flange pose to command; None
    #: when the calibration takes the controller's poses as they are
    arm: ArmCalibration | None = None

    def used(self) -> Matrices:
        """The matrices applied: {"X", "Y", "Z", "Z_probe"} (raw or orthonormal).

        With a tracker ``distortion`` (measured positions = D · true), the applied Z undoes
        it: Z · G with G = D⁻¹ on the 3×3 block (a solver that reports a distortion already
        puts G into its Z_raw), so Z N of a measured N is the undistorted pose."""
        if self.applied == Applied.RAW:
            return {"X": self.X_raw, "Y": self.Y_raw, "Z": self.Z_raw,
                    "Z_probe": self.Z_probe_raw}
        out: Matrices = {"X": self.X, "Y": self.Y, "Z": self.Z, "Z_probe": self.Z_probe}
        if self.distortion is not None and self.distortion.get("matrix") is not None:
            G4 = np.eye(4)
            G4[:3, :3] = np.linalg.inv(np.asarray(self.distortion["matrix"], dtype=float))
            ZP = out["Z_probe"]
            out["Z"], out["Z_probe"] = out["Z"] @ G4, None if ZP is None else ZP @ G4
        return out

    def exported(self) -> Matrices:
        """The matrices that leave tmscal: {"X", "Y", "Z", "Z_probe"}, the orthonormal ones
        (rigid 4×4 mm: rotations projected to SO(3), translations re-solved), whichever set
        the calibration :attr:`applied`. Every export format, ``tmscal stream`` and the
        matrices ``tmscal solve`` prints carry these (docs/exports.md, "Which matrices leave
        tmscal"); the raw matrices and a tracker distortion's correction stay with tmscal
        (the calibration file's ``raw`` and ``distortion``, which :meth:`errors` and
        :meth:`placement` apply)."""
        return {"X": self.X, "Y": self.Y, "Z": self.Z, "Z_probe": self.Z_probe}

    def marker_from_coil(self) -> np.ndarray:
        """marker ← coil centre (4×4 mm, rigid): X⁻¹ · Y of the exported (orthonormal) X and
        Y (:meth:`exported`), where the coil's effective centre sits in the marker's frame.
        With it the marker alone gives the coil: tracker ← coil = B · X⁻¹ · Y
        (docs/streaming.md, "Navigation without the probe"). CalibrationError for a
        marker-only calibration (no Y)."""
        if self.Y is None:
            raise CalibrationError("a marker-only calibration has no coil (Y): the coil "
                                   "cannot be derived from the marker")
        return invert(self.X) @ self.Y

    def placement(self, C: np.ndarray, body: str = "probe"
                  ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
        """(targets, Y, Z) with which a robot places the coil at measured tracker poses C
        (n, 4, 4) mm of ``body``: the applied Y and Z; with a tracker ``distortion``, the
        poses undistorted first (``ml_model.undistort``) and the rigid Y, Z, so that no scale
        of the distortion leaks into the commanded flange pose Z C Y⁻¹. ``body`` "probe":
        C are probe poses, the coil's own (targets = C'); "marker": C are marker poses B and
        the targets are the coil on them, B' · X⁻¹ · Y (:meth:`marker_from_coil`; B'
        undistorted, the marker ← coil offset rigid as calibrated). Y is None for a
        marker-only calibration (body "probe"; "marker" raises CalibrationError)."""
        if body not in ("probe", "marker"):
            raise ValueError(f"body must be 'probe' or 'marker', got {body!r}")
        C = np.asarray(C, dtype=float)
        d = self.distortion
        if d and d.get("matrix") is not None and d.get("model") != "none":
            G = np.linalg.inv(np.asarray(d["matrix"], dtype=float))
            targets, Y, Z = undistort(C, G, "affine"), self.Y, self.Z
        else:
            u = self.used()
            targets, Y, Z = C, u["Y"], u["Z"]
        if body == "marker":
            targets = targets @ self.marker_from_coil()
        return targets, Y, Z

    def flange_command(self, C: np.ndarray, seeds: Any = None, body: str = "probe"
                       ) -> np.ndarray:
        """The flange poses to command (n, 4, 4), base_from_flange mm in the controller's
        frame, so that the coil (probe frame) lands where the tracker would see the probe at
        poses C (n, 4, 4) mm: A = (Ẑ C' Ŷ⁻¹)⊥ with C', Ŷ, Ẑ as :meth:`placement` gives them
        (a robot takes rigid poses); ``body`` "marker": C are marker poses and C' the coil on
        them (:meth:`placement`). With an identified arm (:attr:`arm`), the pose the
        controller's nominal kinematics must be told so that the real arm reaches A (inverse
        kinematics on the identified arm, forward on the nominal one; ``seeds``: joint
        configurations, rad, tried first). CalibrationError for a marker-only calibration or
        a pose the arm cannot reach."""
        if self.Y is None:
            raise CalibrationError("a marker-only calibration has no coil (Y): it cannot "
                                   "place the coil")
        targets, Y, Z = self.placement(np.asarray(C, dtype=float).reshape(-1, 4, 4), body)
        # self.Y is set, and with it the raw Y the RAW calibration applies: every solver and
        # parse_calibration (a missing raw.Y is the rigid one) set Y_raw with Y
        assert Y is not None
        A = orthonormalize(Z @ targets @ np.linalg.inv(Y))
        return A if self.arm is None else self.arm.command(A, seeds)

    def robot_poses(self, A: np.ndarray, joints: Any = None) -> np.ndarray:
        """The robot poses (n, 4, 4) base_from_flange mm, controller's frame, this
        calibration applies: with an identified arm, recomputed from ``joints`` (n, dof) rad
        (the controller's A are its nominal kinematics); otherwise ``A`` as given.
        CalibrationError when the arm needs joints that are not given."""
        if self.arm is None:
            return np.asarray(A, dtype=float)
        if joints is None:
            raise CalibrationError(f"the calibration carries an identified "
                                   f"{self.arm.nominal.name} arm: the robot poses are "
                                   "recomputed from the joints, which are missing")
        return self.arm.robot_poses(joints)

    def holdout_frames(self, B: np.ndarray, C: np.ndarray | None = None
                       ) -> tuple[np.ndarray, np.ndarray | None, Matrices]:
        """(B, C, matrices) as :meth:`errors` compares them: the measured tracker poses B, C
        (n, 4, 4) mm and the applied matrices {"X", "Y", "Z", "Z_probe"} (:meth:`used`);
        with a tracker ``distortion`` the poses undistorted (positions by D⁻¹, orientations
        as the tracker's rigid fit of the tool distorted them, with the tool moments when the
        solver had them) and Z without the G it carries, so that E = (A X)⁻¹ Z B compares
        like with like."""
        u = self.used()
        d = self.distortion
        if d is not None and d.get("matrix") is not None and d.get("model") != "none":
            # the tracker's rigid fit of distorted fiducials, undone
            G = np.linalg.inv(np.asarray(d["matrix"], dtype=float))
            G4 = np.eye(4)
            G4[:3, :3] = np.linalg.inv(G)
            M = d.get("tool_moments") or {}
            B = undistort(B, G, "affine", M.get("marker"))
            C = None if C is None else undistort(C, G, "affine", M.get("probe"))
            ZP = u["Z_probe"]  # Z without the G it carries (a new dict: used()'s stays as it is)
            u = {**u, "Z": u["Z"] @ G4, "Z_probe": None if ZP is None else ZP @ G4}
        return B, C, u

    def errors(self, A: np.ndarray, B: np.ndarray, C: np.ndarray | None = None
               ) -> dict[str, Any]:
        """Hold-out errors of Wang et al. (2018) on the poses given (n, 4, 4), as defined in
        docs/methods.md: per body "trans_mm", "rot_deg";
        with a ``distortion`` the measured poses are undistorted first (positions by D⁻¹,
        orientations as the tracker's rigid fit of the tool distorted them, with the tool
        moments when the solver had them) and Z is applied without the G it carries;
        "e_t_mm", "theta_t_deg"; "e_z_mm", "theta_z_deg" for QR24 on two bodies."""
        B, C, u = self.holdout_frames(B, C)
        bodies = {"marker": B}
        X_of = {"marker": u["X"]}
        Z_of = {"marker": u["Z"]}
        if C is not None and u["Y"] is not None:
            bodies["probe"] = C
            X_of["probe"] = u["Y"]
            Z_of["probe"] = u["Z_probe"] if u["Z_probe"] is not None else u["Z"]
        return holdout_errors(A, bodies, X_of, Z_of)
