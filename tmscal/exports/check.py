"""The daily check: a stored calibration evaluated on a new session, without fitting
(``tmscal solve SESSION --calib CALIB``).

Every usable pose of the session is a hold-out pose for the stored X, Y, Z: the errors of
Wang et al. (2018) (docs/methods.md) as ``Calibration.errors`` computes them, the per-pose
errors with the outlier rule of ``tmscal solve``, the coil placement error against the truth
when the session has one (simulated sessions), and the calibration's provenance beside the
errors it was stored with. A calibration that carries an identified arm (docs/kinematics.md,
"Using it") recomputes the session's robot poses from its joints with that arm before
anything is evaluated, and says how far the controller's frame is from the one it was
calibrated in. Given tolerances, the check decides (:func:`verdict`): PASS when the total
hold-out errors e_t (mm) and θ_t (degrees) are each within theirs, else FAIL. Units mm and
degrees.
"""

from __future__ import annotations

import textwrap
from typing import Any

import numpy as np

from ..calib.kinematics.calibrated import controller_frame
from ..errors import CalibrationError
from ..escape import visible
from ..geometry import rotation_angle
from ..session import Session
from ..solving.kinematics import applied_arrays
from ..solving.outliers import find_outliers
from ..solving.solve import pose_residuals, truth_errors_of
from .calibfile import CalibrationFile

__all__ = ["check_calibration", "format_check", "verdict", "verdict_line", "FRAME_MOVED_MM",
           "FRAME_MOVED_DEG"]

#: the controller's frame on the checked session this far from the calibration's is reported
#: as moved (mm, deg): a tenth of what ``controller_frame`` tolerates within one session
FRAME_MOVED_MM = 0.1
FRAME_MOVED_DEG = 0.01


def _errors(err: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {"e_t_mm": float(err["e_t_mm"]),
                           "theta_t_deg": float(err["theta_t_deg"])}
    for b, d in err["bodies"].items():
        out[b] = {"trans_mm": float(d["trans_mm"]), "rot_deg": float(d["rot_deg"])}
    for k in ("e_z_mm", "theta_z_deg"):
        if k in err:
            out[k] = float(err[k])
    return out


def verdict(errors: dict[str, Any], tolerance_mm: float | None = None,
            tolerance_deg: float | None = None) -> dict[str, Any] | None:
    """The daily check's decision on the hold-out ``errors`` (``check_calibration``'s): the
    total e_t (mm, the sum of the bodies' mean translation errors, and e_z for QR24) within
    ``tolerance_mm`` and θ_t (degrees, likewise) within ``tolerance_deg``, each judged when
    given. None when neither is given; else {"result": "PASS" or "FAIL", "tolerance_mm",
    "tolerance_deg" (None when not given), "e_t_mm", "theta_t_deg", "failed": the keys over
    their tolerance}."""
    if tolerance_mm is None and tolerance_deg is None:
        return None
    for name, tol in (("tolerance_mm", tolerance_mm), ("tolerance_deg", tolerance_deg)):
        if tol is not None and not (np.isfinite(tol) and tol > 0):
            raise CalibrationError(f"{name} must be a finite number > 0, got {tol!r}")
    e_t, th_t = float(errors["e_t_mm"]), float(errors["theta_t_deg"])
    failed = [k for k, v, tol in (("e_t_mm", e_t, tolerance_mm),
                                  ("theta_t_deg", th_t, tolerance_deg))
              if tol is not None and not v <= tol]
    return {"result": "FAIL" if failed else "PASS", "tolerance_mm": tolerance_mm,
            "tolerance_deg": tolerance_deg, "e_t_mm": e_t, "theta_t_deg": th_t,
            "failed": failed}


def check_calibration(session: Session, cf: CalibrationFile,
                      session_sha256: str | None = None, tolerance_mm: float | None = None,
                      tolerance_deg: float | None = None) -> dict[str, Any]:
    """Evaluate the stored calibration ``cf`` (X, Y, Z: 4×4 mm) on every usable pose of
    ``session`` (A, B, C: 4×4 mm), no fitting. Returns plain JSON types, errors in mm and
    degrees: "calibration" (file, method, poses, applied, created,
    session path and SHA-256 it was solved on, the errors it was stored with, the versions
    that wrote it), "session"
    (path, SHA-256, poses used, skipped), "same_session" (True when the SHA-256s match: then
    the errors are in-sample, not a check), "errors" (e_t_mm, theta_t_deg, per body trans_mm
    and rot_deg, e_z/θ_z for QR24), "outliers", "truth" (None without one), and "arm" (None
    without an identified arm): {"nominal", "source", "frame_change_mm", "frame_change_deg":
    how far the controller's frame found on this session (``controller_frame``) is from the
    stored one}, and "verdict" (:func:`verdict` with ``tolerance_mm`` / ``tolerance_deg``;
    None without either). Raises CalibrationError when the session has no usable pose or lacks the
    marker, and, for a calibration with an arm, when a pose has no joints or the recorded
    poses are not that arm's nominal kinematics."""
    cal = cf.calibration
    if "marker" not in session.bodies:
        raise CalibrationError(f"{session.path}: the session has no marker poses (bodies: "
                               f"{', '.join(session.bodies) or 'none'})")
    with_probe = cal.Y is not None and "probe" in session.bodies
    A, B, C, _, q = applied_arrays(session, cal, need_probe=with_probe)
    if len(A) == 0:
        raise CalibrationError(f"{session.path}: no usable poses in the session")
    C = C if with_probe else None
    arm = None
    if cal.arm is not None and q is not None:
        M = controller_frame(cal.arm.nominal, session.arrays(need_probe=with_probe)[0], q,
                             str(session.path or "session"))
        D = np.linalg.inv(cal.arm.controller_frame) @ M
        arm = {"nominal": cal.arm.nominal.name,
               "source": "estimated" if "deviations" in cal.arm.report else
               str(cal.arm.report.get("source", "given")),
               "frame_change_mm": float(np.linalg.norm(D[:3, 3])),
               "frame_change_deg": float(np.degrees(rotation_angle(D[None])[0]))}
    stored = cf.session
    errors = _errors(cal.errors(A, B, C))
    return {
        "calibration": {"file": str(cf.path), "method": cal.method, "n_poses": cal.n_poses,
                        "applied": str(cal.applied), "created": cf.created,
                        "session": stored, "errors": cf.doc.get("errors"),
                        "versions": (cf.doc.get("provenance") or {}).get("versions"),
                        "errors_on": (cf.doc.get("poses") or {}).get("errors_on")},
        "session": {"path": str(session.path), "sha256": session_sha256, "n_poses": len(A),
                    "n_skipped": sum(p.skipped is not None for p in session.poses),
                    "bodies": ["marker", "probe"] if C is not None else ["marker"]},
        "same_session": bool(session_sha256 and stored.get("sha256") == session_sha256),
        "errors": errors,
        "outliers": find_outliers(pose_residuals(session, cal)),
        "truth": truth_errors_of(session, cf.calibration, C, q),
        "arm": arm,
        "verdict": verdict(errors, tolerance_mm, tolerance_deg),
    }


def _row(label: str, t: float, r: float, stored: tuple[float, float] | None = None) -> str:
    s = f"  {label:<36}{t:>12.4f}{r:>12.4f}"
    return s + (f"{stored[0]:>14.4f}{stored[1]:>12.4f}" if stored else "")


def format_check(res: dict[str, Any]) -> str:
    """The human output of ``tmscal solve SESSION --calib CALIB`` (mm and degrees, named in
    the column headers)."""
    c, s, e = res["calibration"], res["session"], res["errors"]
    st = c.get("errors") or {}
    src = c["session"]
    head = [visible(f"stored {c['method'].upper()} calibration {c['file']} checked on "
                    f"{s['path']} (no fitting)"),
            visible(f"  calibration: solved on {c['n_poses']} poses of "
                    f"{src.get('path', '?')} (sha256 {str(src.get('sha256', '?'))[:12]}…), "
                    f"written {c['created'] or '?'}"
                    + (f" by tmscal {c['versions'].get('tmscal')}" if c.get("versions") else "")
                    + f", {c['applied']} matrices applied"),
            f"  this session: {s['n_poses']} usable poses ({', '.join(s['bodies'])})"
            + (f", {s['n_skipped']} skipped at acquisition" if s["n_skipped"] else "")]
    arm = res.get("arm")
    if arm:
        head.append(visible(f"  robot poses recomputed from this session's joints with the "
                            f"calibration's identified {arm['nominal']} arm ({arm['source']}); "
                            f"the controller's frame is {arm['frame_change_mm']:.3f} mm, "
                            f"{arm['frame_change_deg']:.3f}° from the calibration's"))
        if arm["frame_change_mm"] > FRAME_MOVED_MM or arm["frame_change_deg"] > FRAME_MOVED_DEG:
            head.append("  WARNING: the controller's frame has moved since the calibration "
                        "(a new work coordinate system or base mounting?): recalibrate")
    if res["same_session"]:
        head.append("  WARNING: this is the session the calibration was solved on: the "
                    "errors below are in-sample, not a check")
    lines = [w for ln in head for w in textwrap.wrap(ln, 98, subsequent_indent="    ")]
    lines += ["", f"  {'every pose held out':<36}{'trans mm':>12}{'rot deg':>12}"
              f"{'stored mm':>14}{'stored deg':>12}"]

    def stored(key_t: str, key_r: str, sub: str | None = None) -> tuple[float, float] | None:
        d = st.get(sub) if sub else st
        if isinstance(d, dict) and key_t in d and key_r in d:
            return float(d[key_t]), float(d[key_r])
        return None

    for b in ("marker", "probe"):
        if b in e:
            lines.append(_row(b, e[b]["trans_mm"], e[b]["rot_deg"],
                              stored("trans_mm", "rot_deg", b)))
    if "e_z_mm" in e:
        lines.append(_row("Z_P vs Z_M  e_z, θ_z", e["e_z_mm"], e["theta_z_deg"],
                          stored("e_z_mm", "theta_z_deg")))
    # a marker-only session's total is the marker's: beside the stored marker row, not the
    # stored total of two bodies (like with like)
    marker_only = s["bodies"] == ["marker"] and isinstance(st.get("probe"), dict)
    lines.append(_row("total  e_t, θ_t" + (" (marker only)" if marker_only else ""),
                      e["e_t_mm"], e["theta_t_deg"],
                      stored("trans_mm", "rot_deg", "marker") if marker_only
                      else stored("e_t_mm", "theta_t_deg")))
    if marker_only:
        lines += textwrap.wrap("  (this session has no probe poses: its total is the marker's "
                               "alone, so it stands beside the stored marker row, not the "
                               "stored total of marker and probe)", 98,
                               subsequent_indent="   ")
    if c.get("errors_on"):
        lines.append(visible(f"  (stored: the calibration's own errors, {c['errors_on']})"))
    t = res["truth"]
    if t:
        lines.append("")
        for k in ("X", "Y", "Z"):
            if k in t:
                lines.append(f"  {k} against the truth: {t[k]['trans_mm']:.4f} mm, "
                             f"{t[k]['rot_deg']:.4f} deg")
        if "coil_placement_mm" in t:
            lines.append(f"  coil placement error over {t['coil_placement_n']} targets: mean "
                         f"{t['coil_placement_mm']:.4f} mm, max {t['coil_placement_max_mm']:.4f}"
                         " mm")
    lines.append("")
    outl = res["outliers"]
    lines.append("  outlier poses (session pose index): "
                 + (", ".join(str(o["index"]) for o in outl) or "none"))
    lines += textwrap.wrap("  E = (A X)⁻¹ Z B (marker), (A Y)⁻¹ Z C (probe) with the stored "
                           "matrices on every pose of this session; e_trans = ‖t(E)‖ mm, θ its "
                           "rotation angle in degrees, averaged over the poses (Wang et al. "
                           "2018; docs/methods.md). A check error well above the stored one "
                           "means the rig moved: recalibrate.", 98, subsequent_indent="  ")
    if res.get("verdict"):
        lines += ["", verdict_line(res["verdict"])]
    return "\n".join(lines)


def verdict_line(v: dict[str, Any]) -> str:
    """"PASS: …" or "FAIL: …": each judged total against its tolerance (mm, degrees)."""
    parts = []
    for key, label, unit, tol in (("e_t_mm", "e_t", " mm", v["tolerance_mm"]),
                                  ("theta_t_deg", "θ_t", "°", v["tolerance_deg"])):
        if tol is not None:
            op = ">" if key in v["failed"] else "≤"
            parts.append(f"{label} {v[key]:.4f}{unit} {op} {tol:g}{unit}")
    tail = (": recalibrate (tracker, coil mount or robot moved, or a bad session: see the "
            "outlier poses)" if v["result"] == "FAIL" else " (every pose held out)")
    return f"{v['result']}: " + ", ".join(parts) + tail
