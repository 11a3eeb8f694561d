"""The adaptive acquisition's session header entry and its interpretation: the settings a
session was recorded with (``adaptive_header``, ``settings_from_header``), the prediction's
inputs, the robot time by phase, and the prediction recomputed from any session with a plan
(``predict_session``; docs/adaptive.md).

Frames: A = base_from_flange, B = tracker_from_marker, C = tracker_from_probe; 4×4 mm.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..calib.prediction import AdaptiveSettings, predict
from ..errors import CalibrationError, SessionError
from ..poses import JOINTS_KIND, PlanSpec
from ..session import Session

__all__ = ["PHASES", "ADAPTIVE_OVERRIDES", "adaptive_header", "settings_from_header",
           "prediction_inputs", "robot_time_of", "predict_session", "placement_region",
           "arm_error_counts", "session_prediction"]

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


def session_prediction(session: Session, settings: Any = None) -> dict[str, Any]:
    """What ``tmscal solve --json`` reports as ``prediction`` for any session: the
    predicted coil-placement error (mean over the region, mm) at the confidence, the
    region, its RMS, the robot's noise estimated from the residuals and the model error
    (:func:`predict_session`); ``coil_placement_mm`` None and a ``reason`` when the session
    does not allow one (fewer than 3 poses with marker and probe)."""
    conf = (settings or AdaptiveSettings()).confidence
    try:
        pred, info = predict_session(session, settings)
    except CalibrationError as e:
        return {"coil_placement_mm": None, "confidence": conf,
                "region": placement_region(session, settings)[1], "reason": str(e)}
    d = pred.as_dict()
    return {"coil_placement_mm": pred.coil_mm, "confidence": pred.confidence,
            "region": info["region"], "sigma_mm": pred.sigma_mm, "n_poses": pred.n_poses,
            "robot_sigma_mm": d["robot_sigma_mm"], "robot_sigma_deg": d["robot_sigma_deg"],
            "model_error_mm": pred.model_error_mm,
            "model_error": "the arm's kinematic error (not estimated) counts" if
            info["model_error"] else "none (no arm whose joints follow its kinematics)"}
