"""The adaptive acquisition's session header entry and its interpretation: the settings a
session was recorded with (``adaptive_header``, ``settings_from_header``), the prediction's
inputs, the robot time by phase, and the prediction recomputed from any session with a plan
(``predict_session``; docs/adaptive.md).

Frames: A = base_from_flange, B = tracker_from_marker, C = tracker_from_probe; 4×4 mm.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..calib.methods import solve
from ..calib.prediction import PREDICTION_DISTORTION, AdaptiveSettings, predict
from ..errors import CalibrationError, SessionError
from ..poses import JOINTS_KIND, PlanSpec
from ..session import Session
from .kinematics import usable_joints

__all__ = ["PHASES", "ADAPTIVE_OVERRIDES", "adaptive_header", "settings_from_header",
           "prediction_inputs", "robot_time_of", "predict_session", "placement_region",
           "arm_error_counts", "predict_calibration", "calibration_prediction",
           "RUN_METHOD", "model_error_hint"]

#: the calibration an adaptive run's prediction is about, and so the one ``demo --adaptive``
#: solves and ``acquire --adaptive`` tells to solve: ml with its distortion fixed
RUN_METHOD: dict[str, Any] = {"method": "ml", "options": {"distortion": PREDICTION_DISTORTION}}
#: the phases of a pose that count as robot time (docs/adaptive.md)
PHASES = ("moving", "settling", "sampling")
_ADAPTIVE_KEYS = ("target_mm", "confidence", "max_poses", "bootstrap", "pool", "region")
#: what a resume may change in an adaptive session's settings (the pool and region are the
#: session's: they fix which poses were candidates)
ADAPTIVE_OVERRIDES = ("target_mm", "confidence", "max_poses", "bootstrap")


def adaptive_header(settings: Any) -> dict[str, Any]:
    """The session header's ``adaptive`` entry: the settings of the run (``AdaptiveSettings``
    fields; ``pool`` is also the plan's length, ``region`` its first poses)."""
    return {k: getattr(settings, k) for k in _ADAPTIVE_KEYS}


def settings_from_header(header: dict[str, Any], default: Any,
                         overrides: dict[str, Any] | None = None) -> tuple[Any, list[str]]:
    """(AdaptiveSettings, notes) of an adaptive session: the header's ``adaptive`` entry,
    with ``overrides`` (``ADAPTIVE_OVERRIDES``, not None) winning and named in the notes.
    ``default`` (an AdaptiveSettings) fills keys the header lacks. SessionError for a session
    without the entry or with invalid values."""
    rec = header.get("adaptive")
    if not isinstance(rec, dict):
        raise SessionError("the session header has no 'adaptive' entry: it was not recorded "
                           "by tmscal acquire --adaptive (resume it without --adaptive)")
    vals = {k: rec.get(k, getattr(default, k)) for k in _ADAPTIVE_KEYS}
    notes = []
    for k, v in (overrides or {}).items():
        if v is None or k not in ADAPTIVE_OVERRIDES:
            continue
        if v != vals[k]:
            notes.append(f"adaptive.{k} {v} from the command line (the session was recorded "
                         f"with {vals[k]})")
        vals[k] = v
    try:
        return AdaptiveSettings(**vals), notes
    except (TypeError, ValueError) as e:
        raise SessionError(f"the session header's 'adaptive' entry is invalid ({e})") from None


def prediction_inputs(poses: list[Any], bodies: list[str]
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
    """(A, B, C, ml options) of the usable poses (marker and probe seen), in index order:
    ``spreads`` (each pose's sample spreads and counts, the tracker noise per pose) when every
    pose recorded spreads for both bodies; otherwise ml's default noise."""
    use = [p for p in sorted(poses, key=lambda p: p.index)
           if p.skipped is None and p.A is not None and p.B is not None and p.C is not None]
    if not use:
        z = np.zeros((0, 4, 4))
        return z, z, z, {}
    A, B, C = (np.stack([getattr(p, k) for p in use]) for k in "ABC")
    names = [b for b in ("marker", "probe") if b in bodies]
    opts: dict[str, Any] = {}
    if all(all(b in p.spread for b in names) for p in use):
        opts["spreads"] = [{"spread": p.spread, "samples": p.samples} for p in use]
    return A, B, C, opts


def robot_time_of(poses: list[Any]) -> dict[str, float]:
    """Robot time (s) of the poses that recorded it (``robot_s``, adaptive sessions), by
    phase (moving, settling, sampling) and in total."""
    out = {k: 0.0 for k in PHASES}
    for p in poses:
        for k in PHASES:
            out[k] += float((p.robot_s or {}).get(k, 0.0))
    out["total"] = sum(out[k] for k in PHASES)
    return out


def placement_region(session: Session, settings: Any = None
                     ) -> tuple[np.ndarray, str, bool]:
    """Where a session's calibration will place coils (docs/adaptive.md): (flange poses
    (R, 4, 4) base_from_flange mm, its description, whether it is the plan's). The first
    ``region`` poses of the plan the header records (the header's ``adaptive`` settings,
    else ``settings``, else the defaults); without a plan, the session's own usable poses
    (their reported flange poses)."""
    default = settings or AdaptiveSettings()
    if isinstance(session.header.get("adaptive"), dict):
        settings, _ = settings_from_header(session.header, default)
    else:
        settings = default
    try:
        spec = PlanSpec.from_header(session.header)
    except SessionError:
        spec = None
    if spec is None or spec.kind == JOINTS_KIND:  # a joints plan's poses need the arm
        A = np.stack([p.A for p in sorted(session.poses, key=lambda p: p.index)
                      if p.skipped is None and p.A is not None] or [np.eye(4)])
        why = "no plan in the header" if spec is None else "a joints plan"
        return A, f"the session's {len(A)} usable poses ({why})", False
    region = spec.with_n(settings.region).poses()
    return region, (f"the first {settings.region} poses of the session's {spec.kind} plan "
                    f"(seed {spec.seed}, ±{spec.radius_mm:g} mm, ±{spec.rotation_deg:g}°)"), True


def arm_error_counts(session: Session) -> bool:
    """Whether the robot's per-pose error counts as model error in the prediction: the
    session was recorded by an arm (the header names it, ``devices.robot.arm``) whose
    recorded joints follow its nominal kinematics (one controller frame maps them onto the
    reported poses), so the error its residuals show is, in part, the arm's kinematic error,
    which recurs where the coil is placed; the prediction's calibration does not estimate
    the arm (``solve --kinematics estimate`` does, docs/kinematics.md)."""
    from ..calib.kinematics.calibrated import controller_frame
    from .kinematics import choose_arm, recorded_arm, usable_joints

    if recorded_arm(session) is None:
        return False
    A, _, _, idx = session.arrays(need_probe=False)
    q = usable_joints(session, idx) if len(A) else None
    if q is None or len(q) < 3:
        return False
    try:
        nominal, _ = choose_arm(session, None)
        if q.shape[1] != nominal.n_joints:
            return False
        controller_frame(nominal, A, q, str(session.path or "session"))
    except CalibrationError:
        return False
    return True


def predict_session(session: Session, settings: Any = None) -> tuple[Any, dict[str, Any]]:
    """The adaptive prediction (``calib.prediction.predict``: QR36 then ml, the predicted
    coil-placement error at a confidence) recomputed from a session, over
    :func:`placement_region` (the plan's when the header records one, else the session's own
    poses); the robot's error counts as model error when :func:`arm_error_counts`. Returns
    (Prediction, info: region, settings, robot_time_s, the poses' count, model_error).
    CalibrationError with too few usable poses."""
    default = settings or AdaptiveSettings()
    if isinstance(session.header.get("adaptive"), dict):
        settings, _ = settings_from_header(session.header, default)
    else:
        settings = default
    region, where, _ = placement_region(session, settings)
    A, B, C, opts = prediction_inputs(session.poses, session.bodies)
    if len(A) < 3:
        raise CalibrationError(f"{session.path}: {len(A)} usable poses with marker and probe; "
                               "the prediction needs at least 3")
    model_error = arm_error_counts(session)
    pred = predict(A, B, C, region, settings, model_error=model_error, **opts)
    info = {"region": where, "settings": settings,
            "robot_time_s": robot_time_of(session.poses), "poses": len(A),
            "model_error": model_error}
    return pred, info


def _settings_of(session: Session, settings: Any) -> Any:
    default = settings or AdaptiveSettings()
    if isinstance(session.header.get("adaptive"), dict):
        return settings_from_header(session.header, default)[0]
    return default


def _arm_of(cal: Any) -> dict[str, Any] | None:
    """The arm a calibration applies, as ``arm_summary`` names it: {nominal, source}
    ("estimated" or the kinematics file); None for the controller's poses as recorded."""
    if cal.arm is None:
        return None
    rep = cal.arm.report or {}
    return {"nominal": cal.arm.nominal.name,
            "source": "estimated" if "deviations" in rep else rep.get("source", "given")}


def predict_calibration(session: Session, cal: Any, n_solve: int | None = None,
                        options: dict[str, Any] | None = None, settings: Any = None
                        ) -> tuple[Any, dict[str, Any]]:
    """The predicted coil-placement error of the calibration ``cal`` solved on the first
    ``n_solve`` usable poses (marker and probe seen; default all) of ``session`` with the
    method ``options``: the one place that decides which prediction belongs to which
    calibration (docs/methods.md, "Which prediction"). Over :func:`placement_region`, at the
    settings' confidence (the header's adaptive settings, else ``settings``, else the
    defaults). Returns (Prediction, info: region, how, arm, model_error, settings).

    * ``ml`` without an arm: its own (``calib.prediction.predict`` with ``calibration=cal``:
      its covariance, its distortion model, its noise).
    * any other method (QR36, QR24, the classic ones; they have no error model of their own):
      ml's prediction (distortion scale, the poses' sample spreads) on the same poses with
      ``placed=cal``: ml's error plus where ``cal`` places the coil relative to ml's estimate.
    * a calibration with an arm (``--kinematics estimate`` or a kinematics file): as the
      previous, on the robot poses that arm gives (A recomputed from the joints), its
      deviations taken as exact; the arm's kinematic error counts as model error only for a
      calibration on the controller's poses as recorded (:func:`arm_error_counts`).

    CalibrationError with fewer than 3 usable poses or a marker-only calibration."""
    settings = _settings_of(session, settings)
    region, where, _ = placement_region(session, settings)
    if cal.Y is None:
        raise CalibrationError("a marker-only calibration has no coil (Y): nothing to place")
    use = [p for p in sorted(session.poses, key=lambda p: p.index)
           if p.skipped is None and p.A is not None and p.B is not None and p.C is not None]
    A, B, C, opts = prediction_inputs(use, session.bodies)
    n = len(A) if n_solve is None else min(n_solve, len(A))
    if n < 3:
        raise CalibrationError(f"{session.path}: {n} usable poses with marker and probe; "
                               "the prediction needs at least 3")
    A, B, C = A[:n], B[:n], C[:n]
    if "spreads" in opts:
        opts["spreads"] = opts["spreads"][:n]
    arm = _arm_of(cal)
    model_error = arm is None and arm_error_counts(session)
    name = cal.method.upper()
    if arm is not None and arm["source"] == "estimated":
        q = usable_joints(session, [p.index for p in use][:n])
        A = cal.robot_poses(A, q)
    if cal.method == "ml" and cal.arm is None and "covariance_parts" in cal.extra:
        ml_opts = {k: v for k, v in (options or {}).items()
                   if k in ("tracker_cov", "spreads", "tracker_sigma_mm",
                            "tracker_sigma_deg")}
        pred = predict(A, B, C, region, settings, model_error=model_error, calibration=cal,
                       **ml_opts)
        model = (cal.distortion or {}).get("model", "none")
        noise = ("estimated from the residuals" if cal.extra["noise"].get("mode") == "estimate"
                 else "as given")
        how = (f"ML's own: its covariance (distortion {model}, the noise {noise}) "
               "propagated to the coil centre at every target, Monte Carlo")
    else:
        pred = predict(A, B, C, region, settings, model_error=model_error, placed=cal,
                       **opts)
        on = ("the same poses" if arm is None else
              f"the robot poses of the {arm['source']} {arm['nominal']} arm, its deviations "
              "taken as exact (their own uncertainty is not counted)")
        own = ("it has no error model of its own" if cal.method != "ml" else
               "ml with an arm has no coil-placement prediction of its own" if arm else
               "this ml calibration carries no error model of its own")
        how = (f"{name}: {own}; ml's prediction (distortion {PREDICTION_DISTORTION}) on "
               f"{on}, plus where the {name} calibration places the coil relative to ml's "
               "estimate")
    return pred, {"region": where, "how": how, "arm": arm, "model_error": model_error,
                  "settings": settings}


def calibration_prediction(session: Session, cal: Any, n_solve: int | None = None,
                           options: dict[str, Any] | None = None,
                           settings: Any = None) -> dict[str, Any]:
    """What ``tmscal solve --json`` reports as ``prediction``: :func:`predict_calibration`
    of the calibration it writes, as {method, arm (None or {nominal, source}),
    coil_placement_mm (the mean over the region at the confidence), confidence, region,
    how (how it was obtained), sigma_mm (RMS), n_poses, robot_sigma_mm, robot_sigma_deg (the
    robot's noise from the residuals), model_error_mm, model_error}; ``coil_placement_mm``
    None and a ``reason`` when there is none (a marker-only calibration, fewer than 3 poses
    with marker and probe)."""
    settings = _settings_of(session, settings)
    head = {"method": cal.method, "arm": _arm_of(cal)}
    try:
        pred, info = predict_calibration(session, cal, n_solve, options, settings)
    except (CalibrationError, np.linalg.LinAlgError) as e:
        return {**head, "coil_placement_mm": None, "confidence": settings.confidence,
                "region": placement_region(session, settings)[1], "reason": str(e)}
    d = pred.as_dict()
    return {**head, "coil_placement_mm": pred.coil_mm, "confidence": pred.confidence,
            "region": info["region"], "how": info["how"], "sigma_mm": pred.sigma_mm,
            "n_poses": pred.n_poses, "robot_sigma_mm": d["robot_sigma_mm"],
            "robot_sigma_deg": d["robot_sigma_deg"], "model_error_mm": pred.model_error_mm,
            "model_error": "the arm's kinematic error (not estimated) counts" if
            info["model_error"] else ("none (the calibration's arm)" if head["arm"] else
                                      "none (no arm whose joints follow its kinematics)")}


#: the mean norm of an isotropic 3-D Gaussian error per its RMS norm, √(8 / 3π): the part of
#: a prediction (mean over the region) that the model error alone accounts for
_MEAN_PER_RMS = float(np.sqrt(8.0 / (3.0 * np.pi)))


def model_error_hint(session: Session, pred: Any, settings: Any) -> str | None:
    """Why an adaptive run that stopped above its target (max_poses, the pool tried) could
    not reach it, when the cause is model error that more poses do not remove, and the
    command that models it (docs/adaptive.md, "When the target is out of reach"); None when
    the prediction is above the target for want of poses only.

    * the arm: the robot's per-pose error counts as model error (:func:`arm_error_counts`)
      and alone accounts for at least half the target (the mean norm of that error over the
      region, √(8/3π) × its RMS ``pred.model_error_mm``): ``tmscal solve S --kinematics
      estimate`` estimates the arm with X, Y, Z (docs/kinematics.md);
    * a tracker distortion the prediction does not fit: ml's test (distortion "auto") on
      the poses prefers an axis or affine model to the prediction's scale, and what a scale
      cannot fit of it (the anisotropy of D times the region's RMS extent, mm) is at least
      half the target: ``tmscal solve S --method ml --option distortion=MODEL``."""
    path = session.path or "SESSION"
    floor = _MEAN_PER_RMS * float(pred.model_error_mm)
    if pred.model_error_mm > 0 and floor >= 0.5 * settings.target_mm:
        return (f"the arm's kinematic error, which more poses do not reduce, alone accounts "
                f"for {floor:.3g} mm of the prediction (the prediction's ml does not estimate "
                f"the arm): estimate it with tmscal solve {path} --kinematics estimate "
                "(docs/kinematics.md)")
    A, B, C, opts = prediction_inputs(session.poses, session.bodies)
    try:
        d = solve(A, B, C, method="ml", distortion="auto", **opts).distortion or {}
    except (CalibrationError, np.linalg.LinAlgError):
        return None
    model = d.get("model", "none")
    if model in ("none", PREDICTION_DISTORTION) or d.get("matrix") is None:
        return None
    # what the scale cannot fit, across the region: the anisotropy of D (its spectral
    # distance from the nearest isotropic scale) times the region's RMS extent (mm)
    D = np.asarray(d["matrix"], dtype=float)
    aniso = float(np.linalg.norm(D / np.cbrt(np.linalg.det(D)) - np.eye(3), 2))
    t = placement_region(session, settings)[0][:, :3, 3]
    extent = float(np.sqrt(np.mean(np.sum((t - t.mean(0)) ** 2, axis=1))))
    if aniso * extent < 0.5 * settings.target_mm:
        return None
    return (f"the tracker's distortion: ml's test on these poses finds an {model} distortion "
            f"({aniso * 100:.2g} % beyond a scale, {aniso * extent:.2g} mm across the region), "
            f"which the prediction (distortion {PREDICTION_DISTORTION}) does not model: solve "
            f"with tmscal solve {path} --method ml --option distortion={model}")
