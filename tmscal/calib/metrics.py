"""Hold-out error metrics of Wang et al. (2018) and ground-truth errors (docs/methods.md).

Frames: A = base_from_flange, B = tracker_from_marker, C = tracker_from_probe,
X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker; 4×4, mm.

Hold-out error of one body on a pose: E = (A X)⁻¹ Z B (X, Z as applied — raw non-orthogonal
matrices the paper's way, or the orthonormal ones), O = E⊥ (3×3 block projected to SO(3)),
e_trans = ‖t(O)‖ in mm and θ = rotation angle of O in degrees. The reported per-body figure
is the mean over the test poses.

QR36: e_t = e_M + e_P, θ_t = |θ_M| + |θ_P|.
QR24 on two bodies (separate Z_M, Z_P): e_z = ‖t(Z_P) − t(Z_M)‖ and θ_z = angle of
R(Z_P) R(Z_M)ᵀ (the paper's "Z_P − Z_M"), added to e_t and θ_t.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ..geometry import angle_between, orthonormalize, rotation_angle

__all__ = ["body_errors", "holdout_errors", "truth_errors", "coil_placement_errors",
           "placement_errors", "noise_floor"]


def body_errors(A: np.ndarray, N: np.ndarray, X: np.ndarray, Z: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """Per-pose (e_trans mm, θ deg) of E = (A X)⁻¹ Z N for poses A, N (n, 4, 4)."""
    E = np.linalg.inv(A @ X) @ (Z @ N)  # general inverse: raw X, Z are affine, not rigid
    O = orthonormalize(E)
    return np.linalg.norm(O[:, :3, 3], axis=1), np.degrees(rotation_angle(O))


def holdout_errors(A: np.ndarray, bodies: Mapping[str, np.ndarray],
                   X_of: Mapping[str, np.ndarray], Z_of: Mapping[str, np.ndarray]
                   ) -> dict[str, Any]:
    """Mean hold-out errors over the poses given.

    ``bodies`` maps body name → tracker poses (n, 4, 4); ``X_of`` maps body name → its
    flange_from_body as applied; ``Z_of`` maps body name → the base_from_tracker used with
    that body (the same matrix for QR36; Z_M and Z_P for QR24 on two bodies).
    Returns {"bodies": {name: {"trans_mm", "rot_deg"}}, "e_t_mm", "theta_t_deg",
    and "e_z_mm", "theta_z_deg" when the bodies were given different Z}.
    """
    out: dict[str, Any] = {"bodies": {}}
    e_t = 0.0
    th_t = 0.0
    for name, N in bodies.items():
        e, th = body_errors(A, N, X_of[name], Z_of[name])
        out["bodies"][name] = {"trans_mm": float(e.mean()), "rot_deg": float(np.abs(th).mean())}
        e_t += float(e.mean())
        th_t += float(np.abs(th).mean())
    names = list(bodies)
    if len(names) == 2 and Z_of[names[0]] is not Z_of[names[1]]:
        ZM, ZP = Z_of[names[0]], Z_of[names[1]]
        e_z = float(np.linalg.norm(ZP[:3, 3] - ZM[:3, 3]))
        th_z = float(np.degrees(rotation_angle(orthonormalize(ZP[:3, :3])
                                               @ orthonormalize(ZM[:3, :3]).T)))
        out["e_z_mm"] = e_z
        out["theta_z_deg"] = th_z
        e_t += e_z
        th_t += th_z
    out["e_t_mm"] = e_t
    out["theta_t_deg"] = th_t
    return out


def truth_errors(estimates: Mapping[str, np.ndarray | None], truth: Mapping[str, np.ndarray]
                 ) -> dict[str, dict[str, float]]:
    """‖t̂ − t‖ (mm) and the rotation angle between estimate and truth (deg) for each
    transform present in both (e.g. "X", "Y", "Z"); estimates are orthonormalised first."""
    out = {}
    for k, T in truth.items():
        if k not in estimates or estimates[k] is None or T is None:
            continue
        E = orthonormalize(np.asarray(estimates[k], dtype=float))
        T = np.asarray(T, dtype=float)
        out[k] = {"trans_mm": float(np.linalg.norm(E[:3, 3] - T[:3, 3])),
                  "rot_deg": float(np.degrees(angle_between(E, T)))}
    return out


def placement_errors(A_cmd: np.ndarray, C: np.ndarray, Y_true: np.ndarray,
                     Z_true: np.ndarray, reached: Any = None) -> np.ndarray:
    """Coil placement error (mm) per target: the robot is commanded the flange poses A_cmd
    (n, 4, 4) mm (e.g. ``Calibration.flange_command(C)``) to put the coil at the probe poses
    C (n, 4, 4); the flange really reaches ``reached(A_cmd)`` (a callable: the true arm's
    answer to the commands; default: exactly A_cmd), so the coil really sits at that · Y_true
    where Z_true C_i was wanted. Returns ‖t(actual) − t(Z_true C_i)‖."""
    A_act = np.asarray(A_cmd, dtype=float) if reached is None else reached(A_cmd)
    actual = A_act @ Y_true
    desired = Z_true @ C
    return np.linalg.norm(actual[:, :3, 3] - desired[:, :3, 3], axis=1)


def coil_placement_errors(C: np.ndarray, Y_hat: np.ndarray, Z_hat: np.ndarray,
                          Y_true: np.ndarray, Z_true: np.ndarray,
                          C_cmd: np.ndarray | None = None) -> np.ndarray:
    """Coil placement error (mm) per target, the clinically meaningful number.

    The robot is told to put the coil (probe frame) at tracker pose C_i: it commands the
    flange to Â = (Ẑ C_i Ŷ⁻¹)⊥ (orthonormalised: a robot takes rigid poses). The coil then
    really sits at Â Y_true in the base frame, where Z_true C_i was wanted. Returns
    ‖t(Â Y_true) − t(Z_true C_i)‖ for each C_i (n, 4, 4). ``C_cmd`` (default C): the targets
    the robot is commanded with, when they differ from the true ones (e.g. undistorted by a
    calibration that found a tracker distortion, ``Calibration.placement``)."""
    A_cmd = orthonormalize(Z_hat @ (C if C_cmd is None else C_cmd) @ np.linalg.inv(Y_hat))
    return placement_errors(A_cmd, C, Y_true, Z_true)


def noise_floor(A: np.ndarray, bodies: Mapping[str, np.ndarray],
                truth_X: Mapping[str, np.ndarray], Z_true: np.ndarray) -> dict[str, Any]:
    """Hold-out errors of the true transforms on the same poses: the floor set by noise."""
    return holdout_errors(A, bodies, truth_X, {k: Z_true for k in bodies})

