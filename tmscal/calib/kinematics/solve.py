"""The calibration with the arm's kinematics estimated (``tmscal.calib.solve(A, B, C,
method="ml", joints=q, arm=ARM, kinematics="estimate")``; ``tmscal solve --kinematics
estimate``): maximum likelihood over X, Y, Z and the arm's deviations from a session's tracker
poses and recorded joints (:mod:`.estimate`), returned as a ``Calibration`` that carries the
identified arm (``Calibration.arm``, :class:`.calibrated.ArmCalibration`). Pure numerics.

Frames: A = base_from_flange as the controller reported it (its frame), B =
tracker_from_marker, C = tracker_from_probe, X = flange_from_marker, Y = flange_from_probe,
Z = base_from_tracker in the controller's frame; 4×4 mm; joints rad.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...errors import CalibrationError
from ..calibration import Applied, Calibration
from ..methods import solve
from ..ml_model import DISTORTION_MODELS, tool_moment
from .calibrated import ArmCalibration, controller_frame, spread_seeds
from .estimate import LEVELS, KinematicFit, Progress, Tolerances, estimate_kinematics
from .model import Arm, base_from_flange
from .wrench import WRENCH_NAMES, WRENCH_UNITS, WrenchData

__all__ = ["solve_with_kinematics", "NOISE_DEFAULTS", "wrench_summary"]

#: the noise model's defaults (ml's): robot repeatability and one tracker sample
NOISE_DEFAULTS = {"robot_sigma_mm": 0.05, "robot_sigma_deg": 0.03, "tracker_sigma_mm": 0.025,
                  "tracker_sigma_deg": 0.05}


def _joints(joints: Any, arm: Arm, n: int) -> np.ndarray:
    if joints is None:
        raise CalibrationError("kinematics estimate: the joint angles of every pose are "
                               "needed ('joints'; a session records them as joints_rad)")
    q = np.asarray(joints, dtype=float)
    if q.shape != (n, arm.n_joints) or not np.all(np.isfinite(q)):
        raise CalibrationError(f"kinematics estimate: joints must be ({n}, {arm.n_joints}) "
                               f"finite angles (rad) for the {arm.name} arm, got shape "
                               f"{q.shape}")
    return q


def _report(fit: KinematicFit, res: Any, tol: Tolerances) -> dict[str, Any]:
    def combos(cs: list[Any]) -> list[dict[str, Any]]:
        return [{"terms": c.terms, "sigma_data": c.sigma_data, "estimate": c.estimate,
                 "sd": c.sd, "reason": c.reason, "text": c.describe()} for c in cs]
    return {"level": fit.level, "reason": res.reason,
            "tolerances": {"length_mm": tol.length_mm, "angle_deg": tol.angle_deg},
            "deviations": {n: float(v) for n, v in zip(fit.names, fit.delta, strict=True)},
            "sd": {n: float(v) for n, v in zip(fit.names, fit.sd, strict=True)},
            "identified": combos(fit.identified), "weak": combos(fit.weak),
            "unidentified": combos(fit.unidentified),
            "cv": {lv: c for lv, c in res.cv.items()},
            "variance_factor": fit.variance_factor, "iterations": fit.iterations,
            "wrench": wrench_summary(fit)}


def wrench_summary(fit: KinematicFit) -> dict[str, Any] | None:
    """The wrench rows' parameters for the report: estimate and SD by name (rad, N, mm,
    N·m), the tool mass (kg), the rows and their χ²; None without wrench rows."""
    w = fit.wrench
    if w is None:
        return None
    from ..gravity import G_STANDARD

    return {"estimate": w["estimate"], "sd": w["sd"], "units": dict(zip(WRENCH_NAMES,
                                                                         WRENCH_UNITS,
                                                                         strict=True)),
            "tool_mass_kg": w["estimate"]["mg"] / G_STANDARD,
            "flange_R_sensor": w["params"].R_fs.tolist(), "rows": w["rows"],
            "chi2": w["chi2"]}


def _arm(arm: Any) -> Arm:
    from .arms import arm_by_name

    if isinstance(arm, Arm):
        return arm
    if arm is None:
        raise CalibrationError("kinematics estimate: name the nominal arm model ('arm', "
                               "e.g. 'ur5e'; a session records it as devices.robot.arm)")
    try:
        return arm_by_name(arm, "arm")
    except Exception as e:  # ConfigError from the registry: the same message, typed here
        raise CalibrationError(str(e)) from None


def _moments(tools_mm: Any, nb: int) -> list[np.ndarray | None] | None:
    if tools_mm is None:
        return None
    names = ["marker", "probe"][:nb]
    if isinstance(tools_mm, dict):
        return [None if tools_mm.get(n) is None else tool_moment(tools_mm[n]) for n in names]
    return [tool_moment(tools_mm)] * nb


def solve_with_kinematics(A: np.ndarray, B: np.ndarray, C: np.ndarray | None, *, joints: Any,
                          arm: Any, level: str = "auto", tolerances: Tolerances | None = None,
                          folds: int = 5, distortion: str = "none", tools_mm: Any = None,
                          robot_sigma_mm: float | None = None,
                          robot_sigma_deg: float | None = None,
                          tracker_sigma_mm: float | None = None,
                          tracker_sigma_deg: float | None = None, tracker_cov: Any = None,
                          spreads: Any = None, orthonormal: bool = True,
                          noise: str = "estimate", wrench: Any = None,
                          wrench_sigma: Any = None, progress: Progress | None = None
                          ) -> Calibration:
    """X, Y (with C), Z and the arm's deviations from robot poses A (the controller's, used
    only to find the frame it reports in), tracker poses B (and C), joints ``joints`` (n, dof)
    rad and the nominal ``arm`` (an Arm or a registry name); ``level`` "auto", "none",
    "offsets" or "full" (docs/kinematics.md); ``tolerances`` the prior; ``distortion`` a fixed
    tracker distortion model of ``ml`` estimated with the rest ("none" by default);
    ``tools_mm`` the tools' fiducials; the noise as ``ml``'s options: ``noise`` "estimate"
    (default) estimates the robot's rotation and translation noise (and the tracker's level
    without ``spreads`` or ``tracker_cov``) from the fit's residuals, the sigmas only the
    start (:mod:`.noise`); "given" takes them as given. ``extra["noise"]`` reports the noise
    used (σ mm, degrees; degrees of freedom of the estimated components). ``wrench`` (n, 6)
    [Fx, Fy, Fz N, Tx, Ty, Tz N·m]: the wrist sensor's averaged wrench at every pose, whose
    gravity wrench rows then join the likelihood (docs/kinematics.md, "Wrench rows"), with
    ``wrench_sigma`` its σ (a number, (6,) or (n, 6) N, N·m; None: the default of
    :mod:`.wrench`). ``progress``: called as the fits go (:data:`.estimate.Progress`: fits
    done, of how many, which one and its iteration), e.g. for a progress bar. Raises
    CalibrationError for missing joints, a wrong arm, a malformed
    wrench, or too few poses."""
    arm = _arm(arm)
    if distortion not in DISTORTION_MODELS:
        raise CalibrationError(f"kinematics estimate: distortion must be one of "
                               f"{', '.join(DISTORTION_MODELS)} (a fixed model; 'auto' is not "
                               f"searched with the arm), got {distortion!r}")
    if level not in ("auto", *LEVELS):
        raise CalibrationError(f"kinematics: unknown level {level!r}; expected auto, "
                               f"{', '.join(LEVELS)}")
    tol = tolerances or Tolerances()
    q = _joints(joints, arm, len(A))
    wdata = None if wrench is None else WrenchData.make(wrench, wrench_sigma, len(A))
    M = controller_frame(arm, A, q)
    A0 = base_from_flange(arm, q)
    start = solve(A0, B, C, method="qr24" if C is None else "qr36")
    Ws0 = [start.X] if C is None else [start.X, start.Y]
    mode = noise
    noise = dict(NOISE_DEFAULTS)
    given = {"robot_sigma_mm": robot_sigma_mm, "robot_sigma_deg": robot_sigma_deg,
             "tracker_sigma_mm": tracker_sigma_mm, "tracker_sigma_deg": tracker_sigma_deg}
    noise.update({k: v for k, v in given.items() if v is not None})
    noise.update(tracker_cov=tracker_cov, spreads=spreads)
    bodies = [B] if C is None else [B, C]
    moments = _moments(tools_mm, len(bodies))
    res = estimate_kinematics(q, bodies, arm, (Ws0, start.Z), noise, level, tol, folds,
                              distortion=distortion, moments=moments, wrench=wdata,
                              noise_mode=mode, progress=progress)
    fit = res.fit
    Z = M @ fit.Z
    G4 = np.eye(4)
    G4[:3, :3] = fit.G
    cal = Calibration("ml", len(A), X=fit.X, Z=Z, X_raw=fit.X.copy(), Z_raw=Z @ G4,
                      Y=fit.Y, Y_raw=None if fit.Y is None else fit.Y.copy(),
                      applied=Applied.ORTHONORMAL if orthonormal else Applied.RAW,
                      covariance=fit.covariance)
    if distortion != "none":
        D = np.linalg.inv(fit.G)
        cal.distortion = {"model": distortion, "matrix": D, "undistort": fit.G,
                          "scale_percent": float((np.cbrt(np.linalg.det(D)) - 1.0) * 100.0),
                          "axis_scale_percent": (np.diag(D) - 1.0) * 100.0,
                          "tool_moments": dict(zip(["marker", "probe"], moments or
                                                   [None] * len(bodies), strict=False))}
    cal.arm = ArmCalibration(nominal=arm, arm=fit.chain, controller_frame=M,
                             seeds=spread_seeds(q), report=_report(fit, res, tol))
    n_xyz = 6 * (len(bodies) + 1)
    names = [f"{T}.{k}" for T in ["X", "Y"][:len(bodies)] + ["Z"]
             for k in ("rx (rad)", "ry (rad)", "rz (rad)", "tx (mm)", "ty (mm)", "tz (mm)")]
    names += [f"G.{i} (1)" for i in range(len(fit.G.ravel()) if distortion != "none" else 0)
              ][:DISTORTION_MODELS[distortion]]
    if fit.wrench is not None:
        names += [f"{n} ({u})" for n, u in zip(WRENCH_NAMES, WRENCH_UNITS, strict=True)]
    units = ["mm" if n.startswith(("d_", "a_")) else "rad" for n in fit.names]
    cal.extra = {"parameters": names + [f"{n} ({u})" for n, u in zip(fit.names, units,
                                                                        strict=True)],
                 "kinematics": fit.level, "start": start.method, "chi2": fit.chi2,
                 "residuals": fit.m, "variance_factor": fit.variance_factor,
                 "iterations": fit.iterations, "n_xyz": n_xyz,
                 "wrench_rows": fit.wrench is not None,
                 "noise": fit.noise}
    return cal
