"""The verdict the HTML report opens with (``tmscal report``; docs/report.md, "The verdict"):
what a reader at the rig needs before the tables, in a few lines built from the solve result
alone (:func:`verdict_rows`).

1. The held-out errors against the tolerance: PASS or FAIL when the caller judged them (the
   daily check's rule, ``tmscal.check.verdict``, handed in as a dict: the report
   layer does not import the exports), else the totals and how to choose a tolerance.
2. The predicted coil-placement error (``SolveResult.prediction``) and which calibration it
   belongs to.
3. The adaptive run the session was recorded by (the header's ``adaptive`` entry), with its
   target against the prediction and its robot time; or that it was a fixed plan.
4. The calibration's arm (``SolveResult.arm``): estimated with X, Y, Z, recomputed from a
   kinematics file, or none (the controller's poses as reported).

Units: mm and degrees.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ..escape import visible
from .text import prediction_subject

if TYPE_CHECKING:
    from ..session import Session
    from ..solving.solve import SolveResult

__all__ = ["verdict_rows"]


def _judged_line(judged: dict[str, Any], where: str, stored: bool) -> str:
    parts = []
    for key, label, unit, tol in (("e_t_mm", "e_t", " mm", judged.get("tolerance_mm")),
                                  ("theta_t_deg", "θ_t", "°", judged.get("tolerance_deg"))):
        if tol is not None:
            op = ">" if key in judged.get("failed", []) else "≤"
            parts.append(f"{label} {float(judged[key]):.4f}{unit} {op} {float(tol):g}{unit}")
    if judged["result"] != "FAIL":
        tail = ""
    elif stored:
        tail = ("; recalibrate (the tracker, the coil mount or the robot moved, or a bad "
                "session: see the outlier poses)")
    else:
        tail = ("; this calibration does not hold the tolerance (see the outlier poses, the "
                "sample spreads and the convergence curve: more poses, a steadier rig)")
    return f"{judged['result']}: " + ", ".join(parts) + f" ({where}){tail}"


def _where(res: SolveResult, stored: bool) -> str:
    if res.errors_on == "in-sample":
        return (f"IN-SAMPLE on the {res.n_test} poses solved on: optimistic, not a check"
                if not stored else
                f"IN-SAMPLE: the calibration file was solved on this session's {res.n_test} "
                "poses, not a check")
    if stored:
        return f"the stored calibration on this session's {res.n_test} poses, every one held out"
    if res.errors_on == "held-out":
        return f"held out on {res.n_test} poses"
    return f"{res.errors_on}, {res.n_test} poses"


def _adaptive_line(res: SolveResult, session: Session) -> str:
    from ..solving.predict import robot_time_of

    a = session.header.get("adaptive")
    if not isinstance(a, dict):
        return ("acquisition: not an adaptive run (tmscal acquire --adaptive stops when the "
                "predicted error reaches a target, docs/adaptive.md)")
    n = sum(p.skipped is None for p in session.poses)
    rt = robot_time_of(session.poses)
    line = (f"acquisition: an adaptive run (tmscal acquire --adaptive, docs/adaptive.md), "
            f"target {float(a.get('target_mm', float('nan'))):g} mm at "
            f"{float(a.get('confidence', 0.95)) * 100:g} %, {n} usable poses of at most "
            f"{a.get('max_poses', '?')}, robot time {rt['total']:.1f} s")
    p = res.prediction or {}
    if p.get("coil_placement_mm") is not None and a.get("target_mm") is not None:
        reached = float(p["coil_placement_mm"]) <= float(a["target_mm"])
        line += ("; the prediction above reaches the target" if reached else
                 "; the prediction above is over the target (the run stopped at its pose "
                 "limit, or was stopped)")
    return line


def _arm_line(res: SolveResult) -> str:
    arm = res.arm
    if not arm:
        return ("arm: none: the robot poses are the controller's as reported, with its "
                "nominal kinematics (tmscal solve --kinematics estimate estimates the arm, "
                "docs/kinematics.md)")
    if arm.get("source") == "estimated":
        return (f"arm: {arm['nominal']}, its kinematic deviations estimated with X, Y, Z "
                f"(level {arm.get('level')}); the robot poses are the identified arm's, and "
                "the calibration commands the robot through it (docs/kinematics.md)")
    return (f"arm: {arm['nominal']}, robot poses recomputed from the joints with "
            f"{arm['source']} (docs/kinematics.md)")


def verdict_rows(res: SolveResult, judged: dict[str, Any] | None = None,
                 session: Session | None = None, stored: bool = False) -> list[str]:
    """The verdict lines (module docstring) for the solve result ``res`` of ``session``:
    ``judged`` the daily check's decision on ``res.errors`` (``check.verdict``: result,
    tolerance_mm, tolerance_deg, e_t_mm, theta_t_deg, failed) or None when no tolerance was
    given; ``stored`` True when ``res`` is a stored calibration evaluated on the session
    (``tmscal report --calib``) rather than solved on it. Plain text, one item a line."""
    where = _where(res, stored)
    if judged is not None:
        lines = [_judged_line(judged, where, stored)]
    else:
        lines = [f"held-out errors: e_t {float(res.errors['e_t_mm']):.4f} mm, θ_t "
                 f"{float(res.errors['theta_t_deg']):.4f}° ({where}); no tolerance given "
                 "(--tolerance-mm, --tolerance-deg; docs/first-day.md, \"Choosing the "
                 "tolerances\")"]
    p = res.prediction or {}
    if p.get("coil_placement_mm") is not None:
        lines.append(f"predicted coil-placement error: {float(p['coil_placement_mm']):.3g} mm at "
                     f"{float(p['confidence']) * 100:g} % for the {prediction_subject(p)} "
                     f"of this session's poses, mean over {p['region']}")
    elif p:
        lines.append(f"predicted coil-placement error: none ({p.get('reason', '?')})")
    elif stored:
        lines.append("predicted coil-placement error: none for a stored calibration checked "
                     "on a session (the prediction is of a calibration solved on the poses)")
    if session is not None:
        lines.append(_adaptive_line(res, session))
    lines.append(_arm_line(res))
    return [visible(ln) for ln in lines]
