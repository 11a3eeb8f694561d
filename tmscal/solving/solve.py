"""Solve a session and assemble the result object that ``tmscal solve --json`` prints, the
arm's kinematics estimated with X, Y, Z or given as a model when asked (docs/kinematics.md,
"Using it"); the per-pose residuals of a calibration on a session; a session's robot poses
recomputed from its joints under an identified kinematic model.

Frames: A = base_from_flange, B = tracker_from_marker, C = tracker_from_probe,
X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker; 4×4 mm.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..calib import Calibration, truth_errors
from ..calib import solve as solve_arrays
from ..calib.diagnose import calibration_noise
from ..calib.kinematics.calibrated import ArmCalibration
from ..calib.kinematics.estimate import Tolerances
from ..calib.kinematics.model import Arm
from ..calib.kinematics.wrench import SIGMA_FLOOR
from ..calib.metrics import body_errors
from ..calib.study import cross_validate, per_pose_options
from ..errors import CalibrationError
from ..session import Session, plain
from .adequacy import session_adequacy
from .kinematics import (
    applied_arrays,
    choose_arm,
    coil_placement,
    given_arm,
    session_joints,
    truth_arm_of,
    usable_joints,
)
from .outliers import RULE as OUTLIER_RULE
from .outliers import find_outliers
from .predict import calibration_prediction, placement_region

__all__ = ["SolveResult", "solve", "session_arrays", "pose_residuals",
           "with_kinematics", "truth_errors_of", "flat_errors", "arm_summary"]


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
                               "method='qr24'")
    A, B, C, _ = session.arrays(need_probe=need_probe)
    return A, B, C


def arm_summary(ac: ArmCalibration, named_by: str | None = None) -> dict[str, Any]:
    """What ``tmscal solve`` reports of a calibration's arm (plain types): "nominal" (its
    registry name), "named_by" (the ``arm`` argument, "arm=", or the session header),
    "source" ("estimated" or the kinematics file), "controller_frame" (4×4 mm), "seeds" (how
    many), and for an estimated arm its report: level and reason, the held-out table "cv"
    {level: {e_t_mm, se_mm, folds}}, the tolerances, the identified / weak / unidentified
    combinations (text, σ in tolerance units), the deviations (rad, mm) and their SD
    (docs/kinematics.md)."""
    rep = dict(ac.report or {})
    out: dict[str, Any] = {"nominal": ac.nominal.name,
                           "source": "estimated" if "deviations" in rep else
                           rep.pop("source", "given")}
    if named_by is not None:
        out["named_by"] = named_by
    out["controller_frame"] = _mat(ac.controller_frame)
    out["seeds"] = 0 if ac.seeds is None else int(len(ac.seeds))
    return plain({**out, **rep})


def _mat(M: np.ndarray | None) -> list | None:
    return None if M is None else np.asarray(M, dtype=float).tolist()


@dataclass(frozen=True)
class SolveResult:
    """What ``tmscal solve`` reports. ``method`` and ``applied`` ("raw" or "orthonormal"
    matrices); the poses the reported calibration was solved on (``n_solve``) and the poses the
    errors were computed on (``n_test``), ``errors_on`` ("cross-validated (k folds)", "held-out"
    for ``train`` or "in-sample"), poses skipped at acquisition (``n_skipped``); X =
    flange_from_marker, Y = flange_from_probe (None for marker-only), Z = base_from_tracker
    (orthonormal 4×4 mm) and ``raw`` (the solver's matrices by name); ``errors`` (e_t_mm,
    theta_t_deg, per body trans_mm/rot_deg, e_z_mm/theta_z_deg for QR24 with a probe; the mean
    over folds when cross-validated); ``errors_sd`` (the same keys: the SD over folds, None
    unless cross-validated); ``cv`` (folds, split, fold_sizes); ``truth`` ({X, Y, Z: {trans_mm,
    rot_deg}}, coil_placement_mm, coil_placement_max_mm, coil_placement_n) when the session
    knows the truth; ``outliers`` (solving.outliers.find_outliers on the per-pose errors of the
    reported calibration); ``calibration``, the :class:`~tmscal.calib.Calibration` itself (what
    ``formats.calibfile.calibration_yaml`` stores; not part of ``to_json``). ``to_json()`` is
    the ``--json`` object."""

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
    #: the calibration's arm (``arm_summary``: estimated with X, Y, Z, or given as a
    #: kinematics file; docs/kinematics.md); None when the controller's poses are taken as
    #: they are
    arm: dict[str, Any] | None = None
    #: with an arm (``kinematics``): the same solve on the controller's poses as recorded
    #: (the nominal kinematics), the "before" of the arm's "after": {errors_on, errors,
    #: errors_sd, truth} in this result's units; None without an arm
    nominal: dict[str, Any] | None = None
    #: the per-pose residuals the outliers were found on (``pose_residuals`` of the poses as
    #: solved, e.g. recomputed from a kinematics file); not part of ``to_json``
    residuals: dict[str, Any] | None = field(default=None, repr=False)
    #: the predicted coil-placement error of this calibration (its method, its arm;
    #: ``predict.calibration_prediction``: coil_placement_mm at confidence, over region, the
    #: same region as the truth's, and how it was obtained)
    prediction: dict[str, Any] | None = None
    #: the calibration's noise model (``calib.diagnose.calibration_noise`` on the poses it
    #: was solved on, ``NoiseModel.to_json``): what the daily check's diagnosis and
    #: ``--update`` test against (docs/lab-day.md); None when it could not be estimated
    noise_model: dict[str, Any] | None = None
    #: can the rigid model explain the session? (``adequacy.session_adequacy``:
    #: chi2_per_dof, p_value, verdict, likely_cause, the rules, message, fix;
    #: docs/adequacy.md); None when not asked (``adequacy=False``)
    adequacy: dict[str, Any] | None = None
    #: the calibration these figures are of (X, Y, Z and everything the solver returned)
    calibration: Calibration | None = field(default=None, repr=False, compare=False)

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
        for k in ("uncertainty", "distortion", "options", "arm", "nominal", "prediction",
                  "noise_model", "adequacy"):
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
                    f"('joints_rad'); kinematics=<an arm> recomputes A from them, so every pose "
                    "must have them (record with a robot driver that reports joints)")
            if len(p.joints_rad) != n:
                raise CalibrationError(
                    f"{session.path or 'session'}: pose {p.index} has "
                    f"{len(p.joints_rad)} joint angles; {source} ({model.name}) has {n} joints")
            A = base_inv @ forward(model, np.asarray(p.joints_rad, dtype=np.float64))
            p = replace(p, A=A)
        poses.append(p)
    return replace(session, poses=poses)


#: ml options that set the tracker's noise (then the poses' spreads are not used)
_TRACKER_NOISE = ("tracker_cov", "spreads", "tracker_sigma_mm", "tracker_sigma_deg")


def _spreads(session: Session, indices: list[int], bodies: list[str]
             ) -> list[dict[str, Any]] | None:
    """Each pose's sample spreads and counts (ml's ``spreads``: the tracker noise per pose)
    when every pose ``indices`` recorded them for ``bodies``; else None."""
    by_index = {p.index: p for p in session.poses}
    use = [by_index[i] for i in indices]
    if not use or not all(all(b in (p.spread or {}) for b in bodies) for p in use):
        return None
    return [{"spread": p.spread, "samples": p.samples} for p in use]


class _Stages:
    """One progress count (``solve``'s ``progress``) over the kinematic estimate's fits and
    the ``folds`` solves of its cross-validated errors (each one fit of the chosen level)."""

    def __init__(self, report: Callable[[int, int, str], None], folds: int) -> None:
        self.report, self.folds, self.fits, self.fold = report, folds, 1, 0

    def estimate(self, done: int, total: int, what: str) -> None:
        self.fits = total
        self.report(done, total + self.folds, f"kinematics: {what}")

    def errors(self, done: int, total: int, what: str) -> None:
        self.report(self.fits + self.fold + done // max(total, 1), self.fits + self.folds,
                    f"errors, fold {min(self.fold + 1, self.folds)}/{self.folds}: {what}")
        if done >= total:
            self.fold += 1


def solve(session: Session, *, method: str = "qr36", kinematics: Any = None,
          arm: str | None = None, level: str = "auto", tolerances: Tolerances | None = None,
          train: int | None = None, folds: int = 5, in_sample: bool = False,
          orthonormal: bool = False, options: dict[str, Any] | None = None,
          kinematics_source: str = "the kinematics file", adequacy: bool = True,
          progress: Callable[[int, int, str], None] | None = None) -> SolveResult:
    """Solve a session and evaluate the calibration (docs/methods.md): the one call of
    ``tmscal solve``, by named arguments, e.g. ``solve(session, method="ml",
    kinematics="estimate")``. Returns one :class:`SolveResult`: the calibration
    (``.calibration``), its errors, the truth errors, the outlier poses and its predicted
    coil-placement error (``.prediction``), each computed once, for that calibration.

    The calibration is solved with ``method`` (``calib.METHODS``; ``options`` go to it, as
    ``calib.solve`` takes them) on poses [0, ``train``) (default: all). Its errors are: with
    ``train``, held out on the poses after it; with ``in_sample``, on the poses it was solved
    on (optimistic); by default, ``folds``-fold cross-validated
    (``calib.study.cross_validate``: contiguous folds, mean and SD over folds). ``ml`` takes
    the tracker noise from the poses' sample spreads when every pose recorded them and
    ``options`` set no tracker noise (as the adaptive run's prediction does).
    ``orthonormal`` applies the orthonormal matrices in the errors instead of the raw ones.

    The prediction (``predict.calibration_prediction``) is the calibration's own for ``ml``
    without an arm; every other method (QR36, QR24, the classic ones) has no error model of
    its own, so its prediction needs one ml fit on the same poses (ml's error plus where
    this calibration places the coil relative to ml's; docs/methods.md, "Which
    prediction"): that fit is the only other solve, and a marker-only calibration has none.

    ``kinematics`` (docs/kinematics.md, "Using it"): ``"estimate"`` estimates the arm's
    kinematic deviations with X, Y, Z (``method`` must be "ml"): the joints of every usable
    pose, the nominal arm ``arm`` (a registry name) or else the one the session header
    records, the ``level`` ("auto", "none", "offsets", "full") and the prior
    ``tolerances``; the tracker noise from the poses' sample spreads when every pose
    recorded them; the wrench rows (docs/kinematics.md, "Wrench rows") when every pose
    recorded a wrench, σ from its spreads (or the default). The errors are computed on the
    robot poses of the identified arm at the held-out joints; the cross-validation folds
    keep the level chosen on all poses. An
    :class:`~tmscal.calib.kinematics.Arm` instead recomputes every robot pose from its joints
    with that arm (``kinematics_source`` names it), which the calibration then carries when
    it is a registered arm the recorded poses follow (``kinematics.given_arm``). With either,
    the result also holds the same solve on the controller's poses as recorded
    (``SolveResult.nominal``: before and after; a second solve, the only one). Raises
    CalibrationError for unusable data, bad counts, a pose without joints, an unknown arm;
    its message names the arguments (``kinematics='estimate'``, ``train=N``), which the CLI
    words as its options.

    ``adequacy`` (default): whether the rigid model explains the session's poses
    (``adequacy.session_adequacy``, docs/adequacy.md: a tool moved during the session,
    residuals that follow the joints, a tracker scale pattern, a stale frame, inverted or
    metre poses), ``SolveResult.adequacy``.

    ``progress(done, total, what)``, with ``kinematics="estimate"``: called as its fits go
    (the estimate's, :data:`tmscal.calib.kinematics.estimate.Progress`, then one per fold of
    its cross-validated errors), counted together, e.g. for a progress bar."""
    options = dict(options or {})
    estimate = isinstance(kinematics, str) and kinematics == "estimate"
    if kinematics is not None and not estimate and not isinstance(kinematics, Arm):
        raise CalibrationError(f"kinematics: expected 'estimate' or an arm model, got "
                               f"{kinematics!r:.40}")
    if estimate and method != "ml":
        raise CalibrationError(f"kinematics='estimate' is the maximum-likelihood solve (ml) "
                               f"of X, Y, Z with the arm; method='{method}' does not estimate "
                               "an arm (use method='ml')")
    if not estimate and (arm is not None or level != "auto" or tolerances is not None):
        raise CalibrationError("arm=, level= and tolerances= go with kinematics='estimate'")
    as_recorded = None
    if kinematics is not None:  # before: the same solve on the controller's poses
        before = solve(session, method=method, train=train, orthonormal=orthonormal,
                       folds=folds, in_sample=in_sample, options=options, adequacy=False)
        as_recorded = {"errors_on": before.errors_on, "errors": before.errors,
                   "errors_sd": before.errors_sd, "truth": before.truth}
    given = None
    if isinstance(kinematics, Arm):
        session, given = given_arm(session, kinematics, kinematics_source)
    A, B, C = session_arrays(session, method)
    idx = session.arrays(need_probe=method == "qr36")[3]
    n = len(A)
    if n == 0:
        raise CalibrationError(f"{session.path}: no usable poses in the session")
    if train is not None and in_sample:
        raise CalibrationError("train=N and in_sample=True exclude each other (train=N holds "
                               "out the poses after N; in_sample=True holds out none)")
    n_solve = n if train is None else train
    if n_solve < 3:
        if train is None:
            raise CalibrationError(f"{session.path}: {n} usable pose{'s' if n != 1 else ''}; "
                                   "a solve needs at least 3")
        raise CalibrationError(f"train={train}: need at least 3 poses to solve")
    if n_solve > n:
        raise CalibrationError(f"train={train}: the session has only {n} usable poses")
    q = None
    named_by = None
    if method == "ml" and not any(k in options for k in _TRACKER_NOISE):
        # ml's tracker noise from the poses' sample spreads when every pose recorded them
        # (as the adaptive run's prediction takes it)
        sp = _spreads(session, idx, ["marker"] + ([] if C is None else ["probe"]))
        if sp is not None:
            options["spreads"] = sp
    if estimate:
        q = session_joints(session, idx, "kinematics='estimate'")
        nominal, named_by = choose_arm(session, arm)
        if q.shape[1] != nominal.n_joints:
            raise CalibrationError(f"{session.path}: the poses have {q.shape[1]} joint angles; "
                                   f"the {nominal.name} arm ({named_by}) has "
                                   f"{nominal.n_joints}")
        options.update(kinematics="estimate", joints=q, arm=nominal, level=level, folds=folds)
        if tolerances is not None:
            options["tolerances"] = tolerances
        ws = session.wrenches(idx)
        if ws is not None and "wrench" not in options:  # the wrench rows (every pose has one)
            options["wrench"] = ws[0]
            if not np.isnan(ws[1]).any():
                options["wrench_sigma"] = np.maximum(ws[1], SIGMA_FLOOR)
    stages = None if progress is None or not estimate else \
        _Stages(progress, folds if train is None and not in_sample else 0)
    cal = solve_arrays(A[:n_solve], B[:n_solve], None if C is None else C[:n_solve], method=method,
                orthonormal=orthonormal, **per_pose_options(options, slice(0, n_solve), n),
                **({} if stages is None else {"progress": stages.estimate}))
    if given is not None:
        cal.arm = given
    A_eval = A if estimate is False else cal.robot_poses(A, q)
    sd = cv = None
    if train is None and not in_sample:
        cv_opts = options if not estimate else {**options, "level": cal.arm.report["level"]}
        if stages is not None:
            cv_opts = {**cv_opts, "progress": stages.errors}
        r = cross_validate(A, B, C, method=method, k=folds, orthonormal=orthonormal,
                           **cv_opts)
        errors, sd = _nest(r["mean"]), _nest(r["sd"])
        cv = {"folds": r["folds"], "split": r["split"], "fold_sizes": r["fold_sizes"]}
        errors_on, n_test = f"cross-validated ({r['folds']} folds)", n
    elif n_solve < n:
        errors = flat_errors(cal.errors(A_eval[n_solve:], B[n_solve:],
                                         None if C is None else C[n_solve:]))
        errors_on, n_test = "held-out", n - n_solve
    else:
        errors = flat_errors(cal.errors(A_eval, B, C))
        errors_on, n_test = "in-sample", n
    raw = {"X": cal.X_raw, "Y": cal.Y_raw, "Z": cal.Z_raw}
    if cal.Z_probe is not None:
        raw["Z_probe"] = cal.Z_probe_raw
    residuals = pose_residuals(session, cal)
    opts_shown = {k: plain(v) for k, v in options.items()
                  if k not in ("kinematics", "joints", "arm", "spreads", "tolerances", "level",
                               "folds", "wrench", "wrench_sigma")}
    res = SolveResult(
        method=cal.method, applied=cal.applied, n_solve=int(n_solve), n_test=int(n_test),
        errors_on=errors_on, n_skipped=sum(p.skipped is not None for p in session.poses),
        X=cal.X, Y=cal.Y, Z=cal.Z, raw=raw, errors=errors, Z_probe=cal.Z_probe,
        truth=truth_errors_of(session, cal, C, q if q is not None
                              else usable_joints(session, idx)),
        errors_sd=sd, cv=cv, outliers=find_outliers(residuals), residuals=residuals,
        uncertainty=cal.uncertainty, distortion=cal.distortion, options=opts_shown or None,
        arm=None if cal.arm is None else arm_summary(cal.arm, named_by),
        nominal=as_recorded,
        prediction=calibration_prediction(session, cal, int(n_solve),
                                          per_pose_options(options, slice(0, n_solve), n)),
        noise_model=_noise_model(cal, A_eval[:n_solve], B[:n_solve],
                                 None if C is None else C[:n_solve]),
        adequacy=session_adequacy(session, cal) if adequacy else None,
        calibration=cal)
    return res


def _noise_model(cal: Calibration, A: np.ndarray, B: np.ndarray, C: np.ndarray | None
                 ) -> dict[str, Any] | None:
    """The calibration's noise model on the poses it was solved on (A, B, C (n, 4, 4) mm, A
    as the calibration applies them), or None when these poses cannot give one."""
    try:
        return calibration_noise(cal, A, B, C, f"residuals of the {len(A)} poses solved "
                                 "on").to_json()
    except (CalibrationError, np.linalg.LinAlgError, ValueError):
        return None


def truth_errors_of(session: Session, cal: Calibration, C: np.ndarray | None,
                    joints: np.ndarray | None = None) -> dict[str, Any] | None:
    """Errors of X, Y, Z against a session's truth, and the coil placement error (mean and
    max over the targets of the prediction's region, ``predict.placement_region``, mm): the
    first poses of the plan the header records, each target where the truth puts the coil
    there (C = Z⁻¹ P Y, true Y, Z), or without a plan every usable pose's probe pose. The
    robot is commanded ``Calibration.flange_command`` (the placement rule: targets
    undistorted when the calibration found a tracker distortion; with an identified arm, the
    pose its controller must be told), as ``tmscal compare`` does; when the truth has an arm
    (``Session.truth_arm``) the flange goes where that arm's controller takes it
    (``kinematics.coil_placement``), from the joints of the session's nearest pose.
    ``joints`` (n, dof) rad: those of the usable poses (default: the session's when every
    one has them). ``coil_placement_region`` names the region."""
    truth = session.truth
    if not truth:
        return None
    out: dict[str, Any] = dict(truth_errors({"X": cal.X, "Y": cal.Y, "Z": cal.Z}, truth))
    if C is not None and cal.Y is not None and "Y" in truth:
        A_use, _, _, idx = session.arrays(need_probe=True)
        if joints is None or len(joints) != len(A_use):
            joints = usable_joints(session, idx)
        region, where, from_plan = placement_region(session)
        targets, seeds = C, joints
        if from_plan:
            Yt, Zt = np.asarray(truth["Y"], dtype=float), np.asarray(truth["Z"], dtype=float)
            targets = np.linalg.inv(Zt)[None] @ region @ Yt[None]
            if joints is not None and len(A_use):
                near = np.argmin(np.linalg.norm(region[:, None, :3, 3] - A_use[None, :, :3, 3],
                                                axis=2), axis=1)
                seeds = joints[near]
        coil = coil_placement(cal, targets, truth, truth_arm_of(session), seeds)
        out["coil_placement_mm"] = float(coil.mean())
        out["coil_placement_max_mm"] = float(coil.max())
        out["coil_placement_n"] = int(len(coil))
        out["coil_placement_region"] = where
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
    each body, the matrices applied as the calibration says (and A recomputed from the
    joints when it carries an identified arm)."""
    A, B, C, idx, _ = applied_arrays(session, cal, need_probe=cal.Y is not None
                                     and "probe" in session.bodies)
    u = cal.used()
    out: dict[str, Any] = {"index": idx}
    pairs = [("marker", B, u["X"], u["Z"])]
    if C is not None and u["Y"] is not None:
        pairs.append(("probe", C, u["Y"], u["Z_probe"] if u["Z_probe"] is not None else u["Z"]))
    for name, N, Xb, Zb in pairs:
        e, th = body_errors(A, N, Xb, Zb)
        out[name] = {"trans_mm": e.tolist(), "rot_deg": np.abs(th).tolist()}
    return out
