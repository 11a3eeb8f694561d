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
           "prediction_inputs", "robot_time_of", "predict_session"]

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


def predict_session(session: Session, settings: Any = None) -> tuple[Any, dict[str, Any]]:
    """The adaptive prediction (``calib.prediction.predict``: QR36 then ml, the predicted
    coil-placement error at a confidence) recomputed from any session whose header records
    a plan: the region is the first ``region`` poses of that plan (the header's ``adaptive``
    settings, else ``settings``, else the defaults). Returns (Prediction, info: region,
    plan kind, settings, robot_time_s, the poses' count). CalibrationError without a plan or
    with too few usable poses."""
    default = settings or AdaptiveSettings()
    if isinstance(session.header.get("adaptive"), dict):
        settings, _ = settings_from_header(session.header, default)
    else:
        settings = default
    try:
        spec = PlanSpec.from_header(session.header)
    except SessionError as e:
        raise CalibrationError(f"{session.path}: no prediction region: {e}") from None
    if spec.kind == JOINTS_KIND:
        raise CalibrationError(f"{session.path}: no prediction region: the session's plan is "
                               "a joints plan (the region is an eq14 or sphere plan's first "
                               "poses)")
    region = spec.with_n(settings.region).poses()
    A, B, C, opts = prediction_inputs(session.poses, session.bodies)
    if len(A) < 3:
        raise CalibrationError(f"{session.path}: {len(A)} usable poses with marker and probe; "
                               "the prediction needs at least 3")
    pred = predict(A, B, C, region, settings, **opts)
    info = {"region": f"the first {settings.region} poses of the session's {spec.kind} plan "
                      f"(seed {spec.seed}, ±{spec.radius_mm:g} mm, ±{spec.rotation_deg:g}°)",
            "settings": settings, "robot_time_s": robot_time_of(session.poses),
            "poses": len(A)}
    return pred, info
