"""The adequacy of a solve on its session (``SolveResult.adequacy``, docs/adequacy.md): the
rules of :mod:`tmscal.calib.adequacy` run on the session's usable poses as the calibration
applies them (its arm, its tracker distortion undone; ``kinematics.session_frames``), the
verdict, the likely cause in words and the command that fixes it.

Frames: A = base_from_flange, B = tracker_from_marker, C = tracker_from_probe,
X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker; 4×4 mm.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..calib import Calibration
from ..calib import adequacy as aq
from ..calib import diagnose as dg
from ..calib import solve as solve_arrays
from ..errors import CalibrationError
from ..session import Session
from .kinematics import choose_arm, recorded_arm, session_frames, usable_joints

__all__ = ["session_adequacy", "cause_text"]


def _rigid_solver(A: np.ndarray, B: np.ndarray, C: np.ndarray | None) -> Calibration:
    return solve_arrays(A, B, C, method="qr24" if C is None else "qr36", orthonormal=True)


def cause_text(adequacy: dict[str, Any], session: str = "SESSION") -> tuple[str, str] | None:
    """(what is wrong, the fix with its command) for an inadequate verdict (the ``adequacy``
    object of ``SolveResult.to_json``; ``session`` names the file in the commands); None
    when adequate."""
    cause = adequacy.get("likely_cause")
    if cause is None:
        return None
    rule: dict[str, Any] = next((r for r in adequacy.get("rules", [])
                                 if r.get("cause") == cause), {})
    s = session
    if cause == "repeated":
        pairs = ", ".join(f"pose {a} repeats pose {b}" for a, b in rule.get("poses", []))
        return (f"a stale tracker frame: {pairs} (the same reading bit for bit while the robot "
                "moved)", "re-record those poses (the tracker did not refresh its frame; wait "
                "for a new frame after the robot settles, acquisition's settle options)")
    if cause in aq.MISTAKES:
        what = aq.MISTAKES[cause]
        fix = {"inverted_tracker": "invert every tracker pose (B, C) before solving: check the "
                                   "tracker driver's or the export's convention",
               "inverted_robot": "invert every robot pose A before solving: check the robot "
                                 "driver's or the export's convention",
               "metres_tracker": "multiply the tracker poses' translations by 1000 (the "
                                 "session format is in mm, docs/session-format.md)",
               "metres_robot": "multiply the robot poses' translations by 1000 (the session "
                               "format is in mm, docs/session-format.md)",
               "late_frames": "pair each robot pose with the next tracker reading, or "
                              "re-record with a longer settle before each reading",
               "early_frames": "pair each robot pose with the previous tracker reading"}[cause]
        return (f"{what} (corrected, they are explained)", fix)
    if cause == "tool_moved":
        names = {"tracker": "the tracker", "coil": "the coil on the flange",
                 "marker": "the marker on the coil", "coil_centre": "the coil's centre (probe)"}
        moved = names.get(str(rule.get("moved")), "a tool")
        k = rule.get("pose")
        ru = rule.get("runner_up") or {}
        alt = ""
        if ru and ru.get("statistic", 0) > 0.8 * float(rule.get("statistic") or 0):
            alt = (f"; or {names.get(str(ru.get('moved')), 'another tool')}, nearly as "
                   f"likely: F {ru['statistic']:.3g} against {rule.get('statistic'):.3g}")
        return (f"a step in time: {moved} moved at pose {k} (by {rule.get('delta_mm', 0):.2f} "
                f"mm, {rule.get('delta_deg', 0):.2f}°{alt})",
                f"fix it in place and re-record from pose {k}, or solve the poses on one side "
                f"only (tmscal solve {s} --train {rule.get('position')} holds out the rest)")
    if cause == "kinematics":
        return (f"residuals that follow the joints (held out, the arm's '{rule.get('level')}' "
                f"deviations leave {rule.get('ratio') or 0:.2f}× less χ² than the rigid model)",
                f"tmscal solve {s} --method ml --kinematics estimate (docs/kinematics.md)")
    if cause == "tracker":
        return (f"a scale pattern in the tracker's frame (ml's '{rule.get('model')}' "
                "distortion model explains it; without joints the arm's kinematics can look "
                "the same)",
                f"tmscal solve {s} --method ml --option distortion=auto (docs/methods.md); "
                "record joints to test the arm")
    return (cause, "")


def session_adequacy(session: Session, cal: Calibration) -> dict[str, Any]:
    """The adequacy of calibration ``cal`` on the usable poses of ``session`` (the poses it
    was solved on, as it applies them): ``calib.adequacy.decide`` of the repeated-frame,
    mistake, step, joint and tracker-distortion rules, as plain types with ``message`` and
    ``fix`` (:func:`cause_text`; None when adequate). A rule that cannot run (too few
    poses, no joints) is left out and named in ``notes``."""
    notes: list[str] = []
    try:
        fr = session_frames(session, cal)
    except CalibrationError as e:
        return {"chi2_per_dof": None, "p_value": 1.0, "verdict": "not tested",
                "likely_cause": None, "rules": [], "notes": [str(e)], "message": None,
                "fix": None}
    noise = aq.noise_of(fr)
    with_probe = "probe" in fr.N
    A0, B0, C0, idx = session.arrays(need_probe=with_probe)
    C0 = C0 if with_probe else None
    rules: list[aq.Rule | None] = [aq.repeated_rule(A0, B0, idx)]
    as_solved = aq._rss_t(_rigid_solver, A0, B0, C0)
    for name in aq.MISTAKES:
        rules.append(aq.mistake_rule(name, A0, B0, C0, _rigid_solver, as_solved))
    step = aq.step_rule(fr, noise)
    if step is None:
        notes.append(f"tool_moved: not tested ({fr.n} poses: too few for two segments of "
                     f"{aq.MIN_SEGMENT}, or no change determined by them)")
    rules.append(step)
    rules.append(_kinematics(session, cal, A0, B0, C0, idx, notes))
    rules.append(_distortion(cal, fr, noise, notes))
    out = aq.decide(rules, notes).to_json()
    said = cause_text(out, str(session.path or "SESSION"))
    out["message"], out["fix"] = (None, None) if said is None else said
    return out


def _kinematics(session: Session, cal: Calibration, A: np.ndarray, B: np.ndarray,
                C: np.ndarray | None, idx: list[int], notes: list[str]) -> aq.Rule | None:
    """The kinematics rule: the kinematic estimate's held-out table (the calibration's own
    when it estimated the arm, else one ``ml`` solve with ``kinematics="estimate"`` on the
    poses as recorded, the session's arm); None without joints or a recorded arm."""
    rep = cal.arm.report if cal.arm is not None else None
    if rep and "deviations" in rep:
        notes.append("kinematics: the calibration estimated the arm "
                     f"(level {rep.get('level')})")
        return None
    q = usable_joints(session, idx)
    if q is None or recorded_arm(session) is None:
        notes.append("kinematics: not tested (the session records no joints, or no arm; "
                     "record joints with the arm named to test it)")
        return None
    try:
        nominal, _ = choose_arm(session, None)
        if q.shape[1] != nominal.n_joints:
            raise CalibrationError(f"{q.shape[1]} joints, the {nominal.name} has "
                                   f"{nominal.n_joints}")
        kc = solve_arrays(A, B, C, method="ml", orthonormal=True, kinematics="estimate",
                          joints=q, arm=nominal, level="auto")
    except (CalibrationError, np.linalg.LinAlgError, ValueError) as e:
        notes.append(f"kinematics: not tested ({e})")
        return None
    cv = (kc.arm.report or {}).get("cv") if kc.arm is not None else None
    rule = aq.kinematics_rule(cv or {})
    if rule is None:
        notes.append("kinematics: the estimate's levels could not be scored")
    return rule


def _distortion(cal: Calibration, fr: dg.Frames, noise: dg.NoiseModel,
                notes: list[str]) -> aq.Rule | None:
    """The tracker rule: ml's distortion tests (the calibration's own when it is an ml solve
    that selected among them, else one ml solve on the frames' poses); None when the
    calibration already models a distortion."""
    d = cal.distortion or {}
    if d.get("model", "none") != "none":
        notes.append(f"tracker: the calibration models a '{d['model']}' distortion")
        return None
    lrt = cal.extra.get("lrt") if cal.method == "ml" else None
    ml_cal = None
    if not isinstance(lrt, dict):
        try:
            ml_cal = solve_arrays(fr.A, fr.N["marker"], fr.N.get("probe"), method="ml",
                                  orthonormal=True, distortion="auto")
        except (CalibrationError, np.linalg.LinAlgError, ValueError) as e:
            notes.append(f"tracker: not tested ({e})")
            return None
        lrt = ml_cal.extra.get("lrt")
        if not isinstance(lrt, dict):
            return None
    ratio = float("nan")
    if ml_cal is not None and (ml_cal.distortion or {}).get("model", "none") != "none":
        try:
            f2 = dg.frames(ml_cal, fr.A, fr.N["marker"], fr.N.get("probe"))
            r0 = dg.fit(fr, noise)
            r1 = dg.fit(f2, noise)
            ratio = (r0.rss / r0.dof) / max(r1.rss / r1.dof, 1e-300)
        except (CalibrationError, np.linalg.LinAlgError, ValueError):
            pass
    return aq.distortion_rule({k: float(v) for k, v in lrt.items()}, ratio)
