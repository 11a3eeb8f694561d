"""The daily check: a stored calibration evaluated on a new session, without fitting
(``tmscal solve SESSION --calib CALIB``).

Every usable pose of the session is a hold-out pose for the stored X, Y, Z: the errors of Wang
et al. (2018) (docs/methods.md) as ``Calibration.errors`` computes them, the per-pose errors
with the outlier rule of ``tmscal solve``, the coil placement error against the truth when the
session has one (simulated sessions), and the calibration's provenance beside the errors it was
stored with; a session acquired elsewhere than the calibration's P0 is warned about with the
distance (:func:`p0_check`, docs/safety.md). A calibration that carries an identified arm
(docs/kinematics.md, "Using it") recomputes the session's robot poses from its joints with that
arm before anything is evaluated, and says how far the controller's frame is from the one it was
calibrated in. Given tolerances, the check decides (:func:`verdict`): PASS when the total
hold-out errors e_t (mm) and θ_t (degrees) are each within theirs, else FAIL. Units mm and degrees.
"""

from __future__ import annotations

import shlex
import textwrap
from typing import Any

import numpy as np

from .calib import diagnose as dg
from .calib.kinematics.calibrated import controller_frame
from .errors import CalibrationError
from .escape import visible
from .formats.calibfile import CalibrationFile, calibration_p0
from .geometry import rotation_angle
from .safety.origin import p0_distance
from .session import Session
from .solving.kinematics import applied_arrays, session_frames
from .solving.outliers import find_outliers
from .solving.solve import pose_residuals, truth_errors_of

__all__ = ["check_calibration", "format_check", "verdict", "verdict_line", "FRAME_MOVED_MM",
           "FRAME_MOVED_DEG", "UPDATE_OF", "noise_of", "next_command",
           "format_diagnosis", "update_calibration", "format_update", "p0_check", "p0_lines"]

#: the ``--update`` that repairs each diagnosed change
UPDATE_OF = {"tracker": "z", "marker": "x", "coil_centre": "y", "coil": "coil"}

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
    None without either), "diagnosis" and "suggested_tolerances" (docs/lab-day.md), "p0"
    (:func:`p0_check`). Raises CalibrationError when the session has no usable pose or lacks the
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
    fr = session_frames(session, cf.calibration)
    noise = noise_of(cf, fr.bodies)
    try:
        dx = dg.diagnose(fr, noise)
        diagnosis = dict(dx.to_json(), noise_model=noise.source,
                         next_command=next_command(dx.changed, str(session.path),
                                                   str(cf.path)))
    except (CalibrationError, np.linalg.LinAlgError) as e:
        diagnosis = {"changed": None, "error": str(e), "noise_model": noise.source}
    suggested = None
    if tolerance_mm is None and tolerance_deg is None:
        st = cf.doc.get("errors") or {}
        on = str((cf.doc.get("poses") or {}).get("errors_on", ""))
        stored_e = ({k: float(st[k]) for k in ("e_t_mm", "theta_t_deg") if k in st}
                    if on.startswith("cross-validated") and fr.bodies == ("marker", "probe")
                    and "e_z_mm" not in st else None)
        suggested = dg.suggested_tolerances(noise, len(A), fr=fr, stored=stored_e)
        suggested["from"] = noise.source
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
        "diagnosis": diagnosis,
        "suggested_tolerances": suggested,
        "p0": p0_check(session, cf),
    }


def p0_check(session: Session, cf: CalibrationFile) -> dict[str, Any] | None:
    """Whether ``session`` was acquired where the calibration was made
    (``safety.origin``, docs/safety.md): {"calibration_p0", "session_p0" (flange origins,
    base frame mm), "mm", "deg" (their distance), "same" (within ``P0_TOL_MM``/``P0_TOL_DEG``),
    "warning" (None when the same)}; None when either does not record a P0 (a calibration
    written before P0 was stored, a simulated session)."""
    cp = cf.p0
    sp = calibration_p0(session)
    if cp is None or sp is None:
        return None
    mm, deg = p0_distance(cp.pose, sp.pose)
    warning = cp.elsewhere(sp.pose, "this session's P0")
    return {"calibration_p0": cp.pose[:3, 3].tolist(), "session_p0": sp.pose[:3, 3].tolist(),
            "mm": mm, "deg": deg, "same": warning is None, "warning": warning}


def p0_lines(p: dict[str, Any] | None) -> list[str]:
    """The P0 warning of a check or an update, wrapped (none when the same place)."""
    if not p or p["same"]:
        return []
    return textwrap.wrap("  WARNING: " + p["warning"], 98, subsequent_indent="    ")


def noise_of(cf: CalibrationFile, bodies: tuple[str, ...]) -> dg.NoiseModel:
    """The calibration's noise model for ``bodies``: the stored one (``noise_model``), else
    an isotropic one from its stored errors (``calib.diagnose.noise_from_errors``; files
    written before the noise model was stored). CalibrationError when neither exists."""
    nm = cf.noise_model
    if nm is not None and set(bodies) <= set(nm.bodies):
        return nm
    return dg.noise_from_errors(cf.doc.get("errors") or {}, bodies)


def next_command(changed: str | None, session_path: str, calib_path: str) -> str | None:
    """The one command that repairs a diagnosed change (None when nothing changed)."""
    s, c = shlex.quote(session_path), shlex.quote(calib_path)
    if changed in UPDATE_OF:
        new = shlex.quote(str(calib_path).rsplit(".", 1)[0] + "-updated.yaml")
        return f"tmscal solve {s} --calib {c} --update {UPDATE_OF[changed]} -o {new}"
    if changed == "arm":
        return (f"tmscal solve SESSION --method ml --kinematics estimate -o {c} (a full "
                "acquisition: the arm is re-identified with X, Y, Z; docs/kinematics.md)")
    if changed == "unexplained":
        return f"tmscal acquire CONFIG -o SESSION && tmscal solve SESSION -o {c} (recalibrate)"
    return None


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
    p0_warning = p0_lines(res.get("p0"))
    if res["same_session"]:
        head.append("  WARNING: this is the session the calibration was solved on: the "
                    "errors below are in-sample, not a check")
    lines = [w for ln in head for w in textwrap.wrap(ln, 98, subsequent_indent="    ")]
    lines += p0_warning
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
                           "means the rig moved: 'what moved' below says what.", 98,
                           subsequent_indent="  ")
    if res.get("diagnosis"):
        lines += [""] + format_diagnosis(res["diagnosis"])
    sug = res.get("suggested_tolerances")
    if sug:
        lines += textwrap.wrap(
            f"  suggested tolerances for {sug['n_poses']} poses: --tolerance-mm "
            f"{sug['tolerance_mm']:.3g} --tolerance-deg {sug['tolerance_deg']:.3g} (an "
            f"unchanged rig fails {100 * (1 - sug['level']):.0f} % of checks; from the "
            f"calibration's {sug['from']})", 98, subsequent_indent="    ")
    if res.get("verdict"):
        lines += ["", verdict_line(res["verdict"])]
    return "\n".join(lines)


def _size_text(d: dict[str, Any]) -> str:
    if d.get("delta_mm") is None and d.get("delta_deg") is None:
        return ""
    sg = d.get("sigma") or {}
    if d.get("joint"):
        return f"joint {d['joint']} offset {d['delta_deg']:.3f}° ± {sg.get('deg') or 0:.3f}"
    return (f"{d['delta_mm']:.3f} mm ± {sg.get('mm') or 0:.3f}, "
            f"{d['delta_deg']:.3f}° ± {sg.get('deg') or 0:.3f}")


def format_diagnosis(d: dict[str, Any]) -> list[str]:
    """The diagnosis lines of the daily check (what moved, its size with σ, the runner-up's
    evidence ratio, the command that repairs it; docs/lab-day.md)."""
    if d.get("changed") is None:
        return [visible(f"  what moved: not diagnosed ({d.get('error')})")]
    head = f"  what moved: {d['label']}"
    size = _size_text(d)
    if size and d["changed"] != "none":
        head += f": {size}"
    if d["changed"] == "unexplained" and d.get("winner") not in (None, "none"):
        head += f" (the best single change, {d['winner']}, leaves too much: {size})"
    out = [head]
    alts = {a["changed"]: a for a in d.get("alternatives") or []}
    if d["changed"] == "none" and d.get("runner_up") in alts:
        a = alts[d["runner_up"]]
        pv = a.get("p_value")
        out.append(f"    closest change: {d['runner_up']}"
                   + (f" ({_size_text(a)})" if a.get("delta_mm") is not None else "")
                   + (f", p = {pv:.2g} against nothing changed, not significant at "
                      f"{d['test']['alpha']:g} over the hypotheses" if pv is not None else ""))
    elif d.get("runner_up") and d.get("evidence_ratio") is not None:
        out.append(f"    runner-up: {d['runner_up']}, evidence ratio "
                   f"{d['evidence_ratio']:.3g} (AICc)")
    for n in d.get("notes") or []:
        out.append(f"    note: {n}")
    if d.get("next_command"):
        out.append(f"    repair: {d['next_command']}")
    out.append(f"    (noise model: {d.get('noise_model')}; docs/lab-day.md)")
    return [w for ln in out for w in textwrap.wrap(visible(ln), 98, subsequent_indent="      ")]


def update_calibration(session: Session, cf: CalibrationFile, names: list[str]
                       ) -> dict[str, Any]:
    """``--update NAMES`` (z, x, y, coil; ``calib.diagnose.update``): the stored calibration with
    only the named transforms re-registered on ``session``, everything else (and the arm) kept.
    Returns {"calibration": the updated Calibration, "noise_model" (its noise model,
    ``calib.diagnose.noise_after``; None without a stored one), "update": the record (blocks,
    changed, Δ per block {mm, deg, sigma}, covariance, placement spread, noise ratio), "errors"
    (in-sample, on the update's poses), "truth" (None without one), "n_poses"}. CalibrationError
    when the session cannot determine the update; ``calib.diagnose.UpdateRefused`` (with its
    diagnosis) when it does not explain the session."""
    fr = session_frames(session, cf.calibration)
    noise = noise_of(cf, fr.bodies)
    try:
        ft = dg.update(fr, noise, names)
    except dg.UpdateRefused as e:
        e.noise_source = noise.source  # type: ignore[attr-defined]
        raise
    cal = dg.updated(cf.calibration, ft)
    stored = cf.noise_model
    after = dg.noise_after(stored, ft) if stored is not None else None
    with_probe = "probe" in fr.bodies
    A, B, C, _, q = applied_arrays(session, cal, need_probe=with_probe)
    deltas = {}
    for b in ft.blocks:
        sz = ft.size(b)
        D = ft.delta(b)
        deltas[b] = {"changed": dg.HYPOTHESIS_OF[b], "mm": sz["mm"], "deg": sz["deg"],
                     "sigma": {"mm": sz["sigma_mm"], "deg": sz["sigma_deg"]},
                     "matrix": D.tolist()}
    spread = dg.placement_spread(ft)
    record = {"blocks": list(ft.blocks), "deltas": deltas, "n_poses": fr.n,
              "covariance": ft.cov.tolist(), "parameters": "per block [v mm (3), ω rad (3)]",
              "noise_ratio": ft.noise_ratio, "noise_model": noise.source,
              "predicted_coil_placement": spread,
              "kept": [k for k in ("z", "x", "y") if k not in ft.blocks
                       and not (k in "xy" and "coil" in ft.blocks)]
              + (["arm"] if cal.arm is not None else [])}
    return {"calibration": cal, "update": record,
            "noise_model": None if after is None else after.to_json(),
            "errors": _errors(cal.errors(A, B, C if with_probe else None)),
            "truth": truth_errors_of(session, cal, C if with_probe else None, q),
            "n_poses": fr.n, "p0": p0_check(session, cf)}


def format_update(res: dict[str, Any], calib_file: str, output: str | None) -> str:
    """The human output of ``--update`` (mm, degrees)."""
    u = res["update"]
    lines = [visible(f"updated {calib_file} on {u['n_poses']} poses: "
                     f"{', '.join(u['blocks'])} re-registered, "
                     f"{', '.join(u['kept']) or 'nothing else'} kept")]
    for b, d in u["deltas"].items():
        lines.append(f"  {b} ({d['changed']}): {d['mm']:.3f} mm ± {d['sigma']['mm']:.3f}, "
                     f"{d['deg']:.3f}° ± {d['sigma']['deg']:.3f}")
    e = res["errors"]
    lines.append(f"  residuals after the update (in-sample): e_t {e['e_t_mm']:.4f} mm, θ_t "
                 f"{e['theta_t_deg']:.4f}°, {u['noise_ratio']:.2f}× the calibration's noise")
    sp = u.get("predicted_coil_placement")
    if sp:
        lines.append(f"  predicted coil-placement error from the update's own uncertainty: "
                     f"mean {sp['mean_mm']:.4f} mm, 95 % {sp['p95_mm']:.4f} mm")
    t = res.get("truth")
    if t and "coil_placement_mm" in t:
        lines.append(f"  coil placement against the truth: mean {t['coil_placement_mm']:.4f} "
                     f"mm, max {t['coil_placement_max_mm']:.4f} mm")
    lines += p0_lines(res.get("p0"))
    lines.append(visible(f"  written to {output}" if output else
                         "  (nothing written: give -o FILE to write the updated calibration)"))
    return "\n".join(lines)


def verdict_line(v: dict[str, Any]) -> str:
    """"PASS: …" or "FAIL: …": each judged total against its tolerance (mm, degrees)."""
    parts = []
    for key, label, unit, tol in (("e_t_mm", "e_t", " mm", v["tolerance_mm"]),
                                  ("theta_t_deg", "θ_t", "°", v["tolerance_deg"])):
        if tol is not None:
            op = ">" if key in v["failed"] else "≤"
            parts.append(f"{label} {v[key]:.4f}{unit} {op} {tol:g}{unit}")
    tail = (": the rig moved or a bad session: see 'what moved' and the outlier poses above"
            if v["result"] == "FAIL" else " (every pose held out)")
    return f"{v['result']}: " + ", ".join(parts) + tail
