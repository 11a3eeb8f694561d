"""Solve a session and assemble the result object that ``tmscal solve --json`` prints; the
per-pose residuals of a calibration on a session; a session's robot poses recomputed from its
joints under an identified kinematic model.

Frames: A = base_from_flange, B = tracker_from_marker, C = tracker_from_probe,
X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker; 4×4 mm.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..calib import Calibration, coil_placement_errors, solve, truth_errors
from ..calib.metrics import body_errors
from ..calib.study import cross_validate
from ..errors import CalibrationError
from ..session import Session, plain
from .outliers import RULE as OUTLIER_RULE
from .outliers import find_outliers

__all__ = ["SolveResult", "solve_session", "session_arrays", "pose_residuals",
           "with_kinematics", "truth_errors_of", "flat_errors"]


def session_arrays(session: Session, method: str) -> tuple[np.ndarray, np.ndarray,
                                                           np.ndarray | None]:
    """(A, B, C) of the usable poses of a session, in index order; C None for marker-only
    sessions. Raises CalibrationError when qr36 is asked of marker-only data (other methods
    that need probe poses say so themselves when solved)."""
    need_probe = method == "qr36"
    if "marker" not in session.bodies:
        raise CalibrationError(f"{session.path}: no tracker poses to calibrate from (bodies: "
                               f"{', '.join(session.bodies) or 'none'}): a self-calibration "
                               "session is read by tmscal selfcal identify")
    if need_probe and "probe" not in session.bodies:
        raise CalibrationError(f"{session.path}: marker-only session (bodies: "
                               f"{', '.join(session.bodies)}); qr36 needs a probe — use "
                               "--method qr24")
    A, B, C, _ = session.arrays(need_probe=need_probe)
    return A, B, C


def _mat(M: np.ndarray | None) -> list | None:
    return None if M is None else np.asarray(M, dtype=float).tolist()


@dataclass(frozen=True)
class SolveResult:
    """What ``tmscal solve`` reports. ``method`` and ``applied`` ("raw" or "orthonormal"
    matrices); the poses the reported calibration was solved on (``n_solve``) and the poses the
    errors were computed on (``n_test``), ``errors_on`` ("cross-validated (k folds)", "held-out"
    for ``--train`` or "in-sample"), poses skipped at acquisition (``n_skipped``); X =
    flange_from_marker, Y = flange_from_probe (None for marker-only), Z = base_from_tracker
    (orthonormal 4×4 mm) and ``raw`` (the solver's matrices by name); ``errors`` (e_t_mm,
    theta_t_deg, per body trans_mm/rot_deg, e_z_mm/theta_z_deg for QR24 with a probe; the mean
    over folds when cross-validated); ``errors_sd`` (the same keys: the SD over folds, None
    unless cross-validated); ``cv`` (folds, split, fold_sizes); ``truth`` ({X, Y, Z: {trans_mm,
    rot_deg}}, coil_placement_mm, coil_placement_max_mm, coil_placement_n) when the session
    knows the truth; ``outliers`` (solving.outliers.find_outliers on the per-pose errors of the
    reported calibration). ``to_json()`` is the ``--json`` object."""

    method: str
    applied: str
    n_solve: int
    n_test: int
    errors_on: str
    n_skipped: int
    X: np.ndarray | None
    Y: np.ndarray | None
    Z: np.ndarray | None
    raw: dict[str, np.ndarray | None]
    errors: dict[str, Any]
    Z_probe: np.ndarray | None = None
    truth: dict[str, Any] | None = field(default=None)
    errors_sd: dict[str, Any] | None = None
    cv: dict[str, Any] | None = None
    outliers: list[dict[str, Any]] = field(default_factory=list)
    #: a statistical solver's predicted uncertainty and tracker distortion
    #: (``Calibration.uncertainty`` / ``.distortion``, docs/methods.md); None otherwise
    uncertainty: dict[str, Any] | None = None
    distortion: dict[str, Any] | None = None
    #: the method options the calibration was solved with (e.g. the handheld measurement)
    options: dict[str, Any] | None = None

    def to_json(self) -> dict[str, Any]:
        """The result as plain JSON types (matrices as nested lists, mm)."""
        out: dict[str, Any] = {
            "method": self.method, "applied": str(self.applied), "n_solve": self.n_solve,
            "n_test": self.n_test, "errors_on": self.errors_on, "n_skipped": self.n_skipped,
            "X": _mat(self.X), "Y": _mat(self.Y), "Z": _mat(self.Z),
            "raw": {k: _mat(v) for k, v in self.raw.items()}, "errors": self.errors,
            "errors_sd": self.errors_sd, "cv": self.cv, "outliers": self.outliers,
            "outlier_rule": OUTLIER_RULE,
        }
        if self.Z_probe is not None:
            out["Z_probe"] = _mat(self.Z_probe)
        if self.truth is not None:
            out["truth"] = self.truth
        for k in ("uncertainty", "distortion", "options"):
            if getattr(self, k) is not None:
                out[k] = plain(getattr(self, k))
        return out


def with_kinematics(session: Session, model: Any, source: str = "the kinematics") -> Session:
    """A copy of ``session`` whose robot poses are recomputed from the recorded joints:
    A = base⁻¹ · forward(``model``, joints_rad), the flange in the robot's base frame
    (base_from_flange 4×4 mm; ``model`` an ``ArmModel``, e.g. identified by ``tmscal
    selfcal identify``, whose ``base`` is world ← robot base) for every usable pose,
    so that the robot's kinematic error corrected by self-calibration no longer reaches X,
    Y, Z (docs/selfcal.md). Skipped poses are kept as they are. Raises CalibrationError
    naming the first usable pose without joint angles, or with another number of joints
    than the model (``source`` names the model in the message)."""
    from dataclasses import replace

    from ..calib.selfcal.model import forward

    n = model.n_joints
    base_inv = np.linalg.inv(np.asarray(model.base, dtype=np.float64))
    poses = []
    for p in session.poses:
        if p.skipped is None and p.A is not None:
            if p.joints_rad is None:
                raise CalibrationError(
                    f"{session.path or 'session'}: pose {p.index} has no joint angles "
                    f"('joints_rad'); --kinematics recomputes A from them, so every pose "
                    "must have them (record with a robot driver that reports joints)")
            if len(p.joints_rad) != n:
                raise CalibrationError(
                    f"{session.path or 'session'}: pose {p.index} has "
                    f"{len(p.joints_rad)} joint angles; {source} ({model.name}) has {n} joints")
            A = base_inv @ forward(model, np.asarray(p.joints_rad, dtype=np.float64))
            p = replace(p, A=A)
        poses.append(p)
    return replace(session, poses=poses)


def solve_session(session: Session, method: str = "qr36", train: int | None = None,
                  orthonormal: bool = False, folds: int = 5, in_sample: bool = False,
                  options: dict[str, Any] | None = None) -> tuple[Calibration, SolveResult]:
    """Solve a session and estimate its errors (docs/methods.md).

    The reported calibration is solved on poses [0, train) (default: all). Its errors are:
    with ``train``, held out on the poses after it; with ``in_sample``, on the poses it was
    solved on (optimistic); by default, ``folds``-fold cross-validated
    (``calib.study.cross_validate``: contiguous folds, mean and SD over folds). Returns the
    Calibration and a ``SolveResult`` (also the errors against the truth when the session has
    one, and the outlier poses). ``options`` go to the method (``calib.solve``). Raises
    CalibrationError for unusable data or bad counts."""
    A, B, C = session_arrays(session, method)
    options = dict(options or {})
    n = len(A)
    if n == 0:
        raise CalibrationError(f"{session.path}: no usable poses in the session")
    if train is not None and in_sample:
        raise CalibrationError("--train and --in-sample exclude each other (--train holds "
                               "out the poses after N; --in-sample holds out none)")
    n_solve = n if train is None else train
    if n_solve < 3:
        raise CalibrationError(f"--train {train}: need at least 3 poses to solve")
    if n_solve > n:
        raise CalibrationError(f"--train {train}: the session has only {n} usable poses")
    cal = solve(A[:n_solve], B[:n_solve], None if C is None else C[:n_solve], method=method,
                orthonormal=orthonormal, **options)
    sd = cv = None
    if train is None and not in_sample:
        r = cross_validate(A, B, C, method=method, k=folds, orthonormal=orthonormal,
                           **options)
        errors, sd = _nest(r["mean"]), _nest(r["sd"])
        cv = {"folds": r["folds"], "split": r["split"], "fold_sizes": r["fold_sizes"]}
        errors_on, n_test = f"cross-validated ({r['folds']} folds)", n
    elif n_solve < n:
        errors = flat_errors(cal.errors(A[n_solve:], B[n_solve:],
                                         None if C is None else C[n_solve:]))
        errors_on, n_test = "held-out", n - n_solve
    else:
        errors = flat_errors(cal.errors(A, B, C))
        errors_on, n_test = "in-sample", n
    raw = {"X": cal.X_raw, "Y": cal.Y_raw, "Z": cal.Z_raw}
    if cal.Z_probe is not None:
        raw["Z_probe"] = cal.Z_probe_raw
    res = SolveResult(
        method=cal.method, applied=cal.applied, n_solve=int(n_solve), n_test=int(n_test),
        errors_on=errors_on, n_skipped=sum(p.skipped is not None for p in session.poses),
        X=cal.X, Y=cal.Y, Z=cal.Z, raw=raw, errors=errors, Z_probe=cal.Z_probe,
        truth=truth_errors_of(session, cal, C), errors_sd=sd, cv=cv,
        outliers=find_outliers(pose_residuals(session, cal)),
        uncertainty=cal.uncertainty, distortion=cal.distortion,
        options={k: plain(v) for k, v in options.items()} or None)
    return cal, res


def truth_errors_of(session: Session, cal: Calibration,
                  C: np.ndarray | None) -> dict[str, Any] | None:
    """Errors of X, Y, Z against a session's truth, and the coil placement error (mean and
    max over every usable pose's probe pose as a target, mm); None without truth. The robot is
    commanded as ``Calibration.placement`` says (targets undistorted when the calibration
    found a tracker distortion), as ``tmscal compare`` does."""
    truth = session.truth
    if not truth:
        return None
    out: dict[str, Any] = dict(truth_errors({"X": cal.X, "Y": cal.Y, "Z": cal.Z}, truth))
    if C is not None and cal.Y is not None and "Y" in truth:
        C_cmd, Y_cmd, Z_cmd = cal.placement(C)
        coil = coil_placement_errors(C, Y_cmd, Z_cmd, truth["Y"], truth["Z"], C_cmd=C_cmd)
        out["coil_placement_mm"] = float(coil.mean())
        out["coil_placement_max_mm"] = float(coil.max())
        out["coil_placement_n"] = int(len(coil))
    return out


def _nest(flat: dict[str, float]) -> dict[str, Any]:
    """Flat study keys ("marker_trans_mm", …) back to the ``errors`` layout of SolveResult."""
    out: dict[str, Any] = {"e_t_mm": flat["e_t_mm"], "theta_t_deg": flat["theta_t_deg"]}
    for b in ("marker", "probe"):
        if f"{b}_trans_mm" in flat:
            out[b] = {"trans_mm": flat[f"{b}_trans_mm"], "rot_deg": flat[f"{b}_rot_deg"]}
    for k in ("e_z_mm", "theta_z_deg"):
        if k in flat:
            out[k] = flat[k]
    return out


def flat_errors(err: dict[str, Any]) -> dict[str, Any]:
    """``Calibration.errors`` output in the ``errors`` layout of SolveResult (e_t_mm,
    theta_t_deg, per body {trans_mm, rot_deg}, e_z_mm/theta_z_deg for QR24 with a probe)."""
    out: dict[str, Any] = {"e_t_mm": err["e_t_mm"], "theta_t_deg": err["theta_t_deg"]}
    for b, d in err["bodies"].items():
        out[b] = {"trans_mm": d["trans_mm"], "rot_deg": d["rot_deg"]}
    for k in ("e_z_mm", "theta_z_deg"):
        if k in err:
            out[k] = err[k]
    return out


def pose_residuals(session: Session, cal: Calibration) -> dict[str, Any]:
    """Per-pose errors of a calibration on every usable pose of a session (to spot bad poses):
    {"index": [...], "<body>": {"trans_mm": [...], "rot_deg": [...]}} with E = (A X)⁻¹ Z N for
    each body, the matrices applied as the calibration says."""
    A, B, C, idx = session.arrays(need_probe=cal.Y is not None and "probe" in session.bodies)
    u = cal.used()
    out: dict[str, Any] = {"index": idx}
    pairs = [("marker", B, u["X"], u["Z"])]
    if C is not None and u["Y"] is not None:
        pairs.append(("probe", C, u["Y"], u["Z_probe"] if u["Z_probe"] is not None else u["Z"]))
    for name, N, Xb, Zb in pairs:
        e, th = body_errors(A, N, Xb, Zb)
        out[name] = {"trans_mm": e.tolist(), "rot_deg": np.abs(th).tolist()}
    return out


# --- adaptive acquisition: its header entry, the prediction's inputs, robot time ------------
