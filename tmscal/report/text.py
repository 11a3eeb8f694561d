"""Human-readable tables (the plots are in :mod:`tmscal.report.plots`, re-exported here; the
calibration file is written by :func:`tmscal.formats.calibfile.calibration_yaml`).

Units: mm and degrees, named in every column header. Text that comes from a file (a method
or distortion model name of a calibration file, its notes) is shown with control characters
and bidirectional overrides as visible escapes (``tmscal.escape.visible``).
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from ..escape import visible
from .plots import plot_residuals, plot_study

if TYPE_CHECKING:
    from ..solving.solve import SolveResult

__all__ = ["format_result", "format_study", "plot_study", "plot_residuals",
           "format_matrix", "format_truth", "distortion_text", "arm_rows", "wrench_fit_rows",
           "before_after_rows", "error_rows", "truth_rows", "arm_summary_rows",
           "largest_deviations",
           "uncertainty_rows", "outlier_lines", "legend_lines", "number", "plain_value"]


def number(v: float, spec: str = "g") -> str:
    """``v`` formatted by ``spec`` (e.g. ".2f"), never as a negative zero: what rounds to
    zero is shown as 0 ("0.00", not "-0.00")."""
    s = format(float(v), spec)
    return format(0.0, spec) if "-" in s and float(s) == 0.0 else s


def plain_value(v: Any, nested: bool = False) -> str:
    """A value from a session header or a device's identity as a reader sees it, never a
    Python repr: None is "none", booleans "yes"/"no", numbers without a negative zero, a
    mapping "key value, key value" (in parentheses when nested), a list "[a, b, c]"."""
    if v is None:
        return "none"
    if isinstance(v, bool | np.bool_):
        return "yes" if v else "no"
    if isinstance(v, int | np.integer):
        return str(int(v))
    if isinstance(v, float | np.floating):
        return number(float(v), "g")
    if isinstance(v, np.ndarray):
        return plain_value(v.tolist(), nested)
    if isinstance(v, Mapping):
        body = ", ".join(f"{k} {plain_value(x, True)}" for k, x in v.items())
        return (f"({body})" if nested else body) if body else "none"
    if isinstance(v, list | tuple):
        return "[" + ", ".join(plain_value(x, True) for x in v) + "]"
    return str(v)


def format_matrix(M: Any, indent: str = "    ") -> str:
    """A 4×4 matrix as aligned rows (mm in the last column); no negative zeros."""
    A = np.asarray(M, dtype=float)
    return "\n".join(indent + "  ".join(number(v, ">11.5f") for v in row) for row in A)


def format_truth(truth: Any) -> str:
    """The mock rig's true X = flange_from_marker, Y = flange_from_probe and Z =
    base_from_tracker (4×4 mm; a ``RigTruth``), under a heading, as the demos print them."""
    lines = ["", "  truth (the mock rig's):"]
    for k, name in (("X", "flange_from_marker"), ("Y", "flange_from_probe"),
                    ("Z", "base_from_tracker")):
        lines += [f"  {k} = {name}", format_matrix(np.asarray(getattr(truth, k)))]
    return "\n".join(lines)


_W = 44  # label column width of the solve table


def _row(label: str, t: float, r: float | None = None) -> str:
    return f"  {label:<{_W}}{t:>15.4f}" + ("" if r is None else f"{r:>15.4f}")


def _errors_on_text(res: SolveResult) -> str:
    """One line that says which poses the errors were computed on and how."""
    if res.cv is not None:
        sizes = sorted(set(res.cv["fold_sizes"]))
        size = "–".join(str(x) for x in (sizes[0], sizes[-1])) if len(sizes) > 1 else sizes[0]
        return (f"errors: {res.cv['folds']}-fold cross-validated: the poses cut in order into "
                f"{res.cv['folds']} contiguous folds of {size},\n  each held out in turn and "
                "tested on a calibration solved on the others; mean over folds ± SD")
    if res.errors_on == "held-out":
        return (f"errors: held out on the {res.n_test} poses after the first {res.n_solve} "
                "(--train)")
    return (f"errors: IN-SAMPLE, on the same {res.n_test} poses the calibration was solved on\n"
            "  (optimistic: not a hold-out estimate)")


def _parts(e: dict[str, Any]) -> str:
    """What the total e_t, θ_t adds up: "marker + probe (+ e_z)"."""
    return " + ".join([b for b in ("marker", "probe") if b in e]
                      + (["e_z"] if "e_z_mm" in e else []))


def error_rows(res: SolveResult) -> list[str]:
    """The hold-out error table: one row per body, e_z (QR24), the total; each followed by
    its SD over folds when cross-validated."""
    e, sd = res.errors, res.errors_sd
    two_z = "e_z_mm" in e
    label = {"marker": "marker   E = (AX)⁻¹ZB",
             "probe": "probe    E = (AY)⁻¹Z_P C" if two_z else "probe    E = (AY)⁻¹ZC"}
    head = ("mean error over the poses solved on" if res.errors_on == "in-sample"
            else "mean error over the held-out poses")
    lines = [f"  {head:<{_W}}{'translation mm':>15}"
             f"{'rotation deg':>15}"]

    def add(lab: str, key_t: str, key_r: str, sub: str | None = None) -> None:
        get = (lambda d, k: d[sub][k]) if sub else (lambda d, k: d[k])
        lines.append(_row(lab, get(e, key_t), get(e, key_r)))
        if sd is not None:
            lines.append(_row(f"  ± SD over {res.cv['folds']} folds" if res.cv else "  ± SD",
                              get(sd, key_t), get(sd, key_r)))

    for b in ("marker", "probe"):
        if b in e:
            add(label[b], "trans_mm", "rot_deg", b)
    if two_z:
        add("Z_P vs Z_M  e_z, θ_z", "e_z_mm", "theta_z_deg")
    add(f"total  e_t, θ_t  (= {_parts(e)})", "e_t_mm", "theta_t_deg")
    return lines


def _wrap(text: str, indent: str = "  ", more: str = "      ") -> list[str]:
    return textwrap.wrap(visible(text), 98, initial_indent=indent, subsequent_indent=more) \
        or [indent]


def arm_rows(arm: dict[str, Any], verbose: bool = True) -> list[str]:
    """The arm of a calibration (``solving.solve.arm_summary``) as text: which arm and where it
    came from; for an estimated one the level chosen and why (the held-out table), the prior,
    the identified combinations of deviations with their σ, the weakly identified ones and
    what could not be identified and why (docs/kinematics.md). Without ``verbose`` the
    combinations are counted, not listed (``tmscal solve -v`` lists them)."""
    named = f", named by {arm['named_by']}" if arm.get("named_by") else ""
    if arm.get("source") != "estimated":
        return _wrap(f"arm: {arm['nominal']}{named}: robot poses recomputed from the joints "
                     f"with {arm['source']}; the calibration carries it and commands the "
                     "robot through it (docs/kinematics.md)")
    lines = _wrap(f"arm: {arm['nominal']}{named}, its kinematic deviations estimated with X, "
                  "Y, Z (maximum likelihood; docs/kinematics.md)")
    lines += _wrap(f"level: {arm.get('level')} ({arm.get('reason', '')})")
    cv = {k: v for k, v in (arm.get("cv") or {}).items() if v}
    if cv:
        k = int(next(iter(cv.values())).get("folds", 0))
        lines.append(f"  {'held-out by level (' + str(k) + ' interleaved folds)':<{_W}}"
                     f"{'e_t mm':>15}{'± SE mm':>15}{'χ² per pose':>15}")
        for lv, c in cv.items():
            mark = "  ← chosen" if lv == arm.get("level") else ""
            chi2 = f"{float(c['chi2']):>15.2f}" if c.get("chi2") is not None else " " * 15
            lines.append(_row(f"  {lv}", float(c["e_t_mm"]), float(c["se_mm"])) + chi2 + mark)
    tol = arm.get("tolerances") or {}
    if tol:
        lines += _wrap(f"prior: each length deviation N(0, ({tol.get('length_mm'):g} mm)²), "
                       f"each angle N(0, ({tol.get('angle_deg'):g}°)²); combinations below in "
                       "tolerance units (deviation / tolerance), ± their posterior σ")
    for key, head in (("identified", "identified (σ_data ≥ 1: the poses know it better than "
                                     "the tolerance)"),
                      ("weak", "weakly identified (the prior decides; spread the joints "
                               "further)"),
                      ("unidentified", "not identifiable, left at the nominal value")):
        combos = arm.get(key) or []
        if not combos:
            continue
        lines.append(f"  {head}: {len(combos)}")
        if verbose:
            lines += [w for c in combos for w in _wrap(c.get("text", "?"), "    ", "        ")]
    if not verbose and any(arm.get(k) for k in ("identified", "weak", "unidentified")):
        lines.append("    (-v lists each combination with its estimate and σ; --json carries "
                     "them as arm)")
    return lines + wrench_fit_rows(arm.get("wrench"))


def _deviation_text(name: str, value: float, sd: float, tol: dict[str, Any]) -> str:
    """"a_1 -0.197 ± 0.196 mm (0.39 τ)": one deviation (rad or mm) with its posterior SD,
    angles in degrees, and its size in tolerance units τ."""
    length = str(name).rpartition("_")[0] in ("d", "a")
    if length:
        v, s, unit, t = value, sd, " mm", tol.get("length_mm")
    else:
        v, s, unit, t = math.degrees(value), math.degrees(sd), "°", tol.get("angle_deg")
    rel = f" ({abs(v) / float(t):.2g} τ)" if t else ""
    return f"{visible(name)} {number(v, '+.3g')} ± {number(s, '.2g')}{unit}{rel}"


def largest_deviations(arm: dict[str, Any], k: int = 3) -> list[tuple[str, float, float]]:
    """The ``k`` deviations (name, estimate, posterior SD; rad or mm) of an estimated arm
    largest in tolerance units (|δ| / τ, τ the prior's length or angle tolerance), largest
    first; empty for an arm without deviations."""
    dev, sd = arm.get("deviations") or {}, arm.get("sd") or {}
    tol = arm.get("tolerances") or {}
    t_len = float(tol.get("length_mm") or 1.0)
    t_ang = math.radians(float(tol.get("angle_deg") or math.degrees(1.0)))

    def size(n: str) -> float:
        length = str(n).rpartition("_")[0] in ("d", "a")
        return abs(float(dev[n])) / (t_len if length else t_ang)

    names = sorted(dev, key=size, reverse=True)[:k]
    return [(n, float(dev[n]), float(sd.get(n, float("nan")))) for n in names]


def arm_summary_rows(res: SolveResult) -> list[str]:
    """The first lines of ``tmscal solve --kinematics estimate``, for a reader at the rig
    (docs/kinematics.md, "Solving"): the arm and the level chosen; the held-out total e_t
    before (the controller's poses, nominal kinematics) and after (with the estimated arm);
    the coil placement: the session's prediction (``SolveResult.prediction``, whose
    calibration does not estimate the arm) and, for a simulated session, against the truth
    before and after; the three largest deviations in tolerance units. mm and degrees. Empty
    unless the result's arm was estimated."""
    arm = res.arm
    if not arm or arm.get("source") != "estimated":
        return []
    lines = _wrap(f"summary: arm {arm['nominal']} estimated with X, Y, Z; level "
                  f"{arm.get('level')} ({arm.get('reason', '')})", "", "    ")
    b = res.nominal or {}
    e0, e1 = (b.get("errors") or {}).get("e_t_mm"), res.errors.get("e_t_mm")
    if e0 is not None and e1 is not None:
        lines += _wrap(f"held-out total e_t ({res.errors_on}): {e0:.4f} mm on the "
                       f"controller's poses → {e1:.4f} mm with the estimated arm", "    ",
                       "        ")
    p = res.prediction or {}
    if p.get("coil_placement_mm") is not None:
        lines += _wrap(f"coil placement predicted {p['coil_placement_mm']:.3g} mm at "
                       f"{p['confidence'] * 100:g} % for the {prediction_subject(p)} "
                       f"(model error: {p.get('model_error', '?')})", "    ", "        ")
    t0, t1 = b.get("truth") or {}, res.truth or {}
    if "coil_placement_mm" in t0 and "coil_placement_mm" in t1:
        lines.append(f"    coil placement against the truth (simulated): "
                     f"{t0['coil_placement_mm']:.4f} mm before → "
                     f"{t1['coil_placement_mm']:.4f} mm after")
    top = largest_deviations(arm)
    if top:
        tol = arm.get("tolerances") or {}
        lines += _wrap("largest deviations (estimate ± σ, τ: the prior's tolerance): "
                       + ", ".join(_deviation_text(n, v, s, tol) for n, v, s in top),
                       "    ", "        ")
    return lines


def wrench_fit_rows(w: dict[str, Any] | None) -> list[str]:
    """The wrench rows of an estimated arm (docs/kinematics.md, "Wrench rows"): how many,
    their χ², and the tool, bias, base tilt and sensor rotation identified with the arm
    (angles in degrees, ± posterior SD). Empty without wrench rows."""
    if not w:
        return []
    e, sd = w["estimate"], w["sd"]

    def show(names: list[str], unit: str, scale: float = 1.0) -> str:
        return ", ".join(f"{n} {e[n] * scale:+.4g} ± {sd[n] * scale:.2g}" for n in names) \
            + f" {unit}"

    lines = _wrap(f"wrench rows: {w['rows']} (every pose's averaged wrist wrench in the same "
                  f"likelihood; their χ² {w['chi2']:.4g})")
    lines += _wrap(f"tool: mass {w['tool_mass_kg']:.4g} kg (mg {e['mg']:.4g} ± "
                   f"{sd['mg']:.2g} N); centre of gravity "
                   + show(["cog_x", "cog_y", "cog_z"], "mm"), "    ")
    lines += _wrap("bias: " + show(["f0_x", "f0_y", "f0_z"], "N") + "; "
                   + show(["t0_x", "t0_y", "t0_z"], "N·m"), "    ")
    lines += _wrap("base tilt: " + show(["base_roll", "base_pitch"], "deg", 180 / math.pi)
                   + "; sensor rotation (rotation vector): "
                   + show(["sensor_rx", "sensor_ry", "sensor_rz"], "deg", 180 / math.pi),
                   "    ")
    return lines


def before_after_rows(res: SolveResult) -> list[str]:
    """With an arm (``res.nominal``): the hold-out errors, and the coil placement against the
    truth of a simulated session, on the controller's poses as recorded (before) beside
    those with the arm (after); mm and degrees. Empty without an arm."""
    b = res.nominal
    if not b or res.arm is None:
        return []
    src = res.arm.get("source")
    how = ("its deviations estimated with X, Y, Z" if src == "estimated"
           else f"A recomputed from the joints with {src}")
    lines = _wrap(f"before → after: the controller's poses as recorded (nominal "
                  f"{res.arm['nominal']} kinematics) → with the arm ({how}); errors "
                  f"{res.errors_on} in both")
    lines.append(f"  {'':<{_W - 8}}{'before mm':>11}{'after mm':>11}{'before deg':>12}"
                 f"{'after deg':>11}")

    def row(label: str, before: tuple[float, float], after: tuple[float, float]) -> str:
        return (f"  {label:<{_W - 8}}{before[0]:>11.4f}{after[0]:>11.4f}{before[1]:>12.4f}"
                f"{after[1]:>11.4f}")

    e0, e1 = b["errors"], res.errors
    for body in ("marker", "probe"):
        if body in e0 and body in e1:
            lines.append(row(body, (e0[body]["trans_mm"], e0[body]["rot_deg"]),
                             (e1[body]["trans_mm"], e1[body]["rot_deg"])))
    lines.append(row("total  e_t, θ_t", (e0["e_t_mm"], e0["theta_t_deg"]),
                     (e1["e_t_mm"], e1["theta_t_deg"])))
    t0, t1 = b.get("truth") or {}, res.truth or {}
    if "coil_placement_mm" in t0 and "coil_placement_mm" in t1:
        lines.append(f"  {'coil placement vs the truth, mean mm':<{_W - 8}}"
                     f"{t0['coil_placement_mm']:>11.4f}{t1['coil_placement_mm']:>11.4f}")
    return lines


def truth_rows(res: SolveResult) -> list[str]:
    """The errors against the truth of a simulated session (translation mm, rotation deg)."""
    t = res.truth or {}
    lines = [f"  {'against the truth (simulated session)':<{_W}}{'translation mm':>15}"
             f"{'rotation deg':>15}"]
    for k, name in (("X", "flange_from_marker"), ("Y", "flange_from_probe"),
                    ("Z", "base_from_tracker")):
        if k in t:
            lines.append(_row(f"{k} = {name}", t[k]["trans_mm"], t[k]["rot_deg"]))
    if "coil_placement_mm" in t:
        n = t.get("coil_placement_n")
        over = f" over {n} targets" if n else ""
        lines.append(f"  coil placement error, mm{over}: mean {t['coil_placement_mm']:.4f}, "
                     f"max {t['coil_placement_max_mm']:.4f}")
        if t.get("coil_placement_region"):
            lines.append(f"    targets: {t['coil_placement_region']}")
    return lines


def prediction_rows(res: SolveResult) -> list[str]:
    """The predicted coil-placement error of the calibration solved
    (``SolveResult.prediction``: its method and arm, how it was obtained; the solve service
    decides which prediction it is, docs/methods.md)."""
    p = res.prediction or {}
    if not p:
        return []
    whose = f"{visible(str(p.get('method', res.method)).upper())} calibration"
    arm = p.get("arm")
    if arm:
        whose += f" with the {visible(str(arm['source']))} {visible(str(arm['nominal']))} arm"
    if p.get("coil_placement_mm") is None:
        return _wrap(f"predicted coil-placement error of the {whose}: none ({p['reason']})")
    lines = [f"  predicted coil-placement error of the {whose}: {p['coil_placement_mm']:.3g} mm"
             f" at {p['confidence'] * 100:g} % (RMS {p['sigma_mm']:.3g} mm)"]
    lines += _wrap(f"how: {p['how']}", "    ")
    lines += _wrap(f"robot noise from the residuals {p['robot_sigma_mm']:.3g} mm, "
                   f"{p['robot_sigma_deg']:.3g}° per axis; model error: {p['model_error']}",
                   "    ")
    lines += _wrap(f"mean over {p['region']}", "    ")
    return lines


def _pct(v: float) -> str:
    return f"{v:+.3f} %"


def distortion_text(d: dict[str, Any]) -> str:
    """The tracker distortion a solver found, in one line: "tracker scale +0.080 %" for an
    isotropic scale, per-axis percentages, or the 3×3 matrix of an affine model."""
    model = visible(d.get("model", "?"))
    if model == "none":
        return "tracker distortion: none (a rigid tracker model)"
    if model == "scale" and "scale_percent" in d:
        return f"tracker scale {_pct(float(d['scale_percent']))}"
    if model == "axis" and d.get("axis_scale_percent") is not None:
        x, y, z = (float(v) for v in d["axis_scale_percent"])
        return f"tracker scale per axis: x {_pct(x)}, y {_pct(y)}, z {_pct(z)}"
    if d.get("matrix") is not None:
        M = np.asarray(d["matrix"], dtype=float)
        rows = "; ".join(" ".join(f"{v:.6f}" for v in r) for r in M)
        mean = f", mean scale {_pct(float(d['scale_percent']))}" if "scale_percent" in d \
            else ""
        return f"tracker distortion ({model}): D = [{rows}]{mean}"
    return f"tracker distortion: {model}"


def uncertainty_rows(res: SolveResult) -> list[str]:
    """The predicted uncertainty (1-σ and 95 %) of a statistical solver, and the distortion.
    The coil centre's row is left out when the result has a predicted coil-placement error
    (``prediction_rows``): the coil centre's error is stated once, there."""
    lines: list[str] = []
    u = res.uncertainty or {}
    placed = (res.prediction or {}).get("coil_placement_mm") is not None
    rows = [(k, v) for k, v in u.items()
            if isinstance(v, dict) and "sigma" in v and "p95" in v
            and not (placed and k == "coil_centre_mm")]
    if rows:
        where = u.get("target_note")
        lines.append(f"  {'predicted uncertainty (' + visible(res.method) + ')':<{_W}}"
                     f"{'1-σ':>15}{'95 %':>15}")
        for k, v in rows:
            name, _, unit = k.rpartition("_")
            label = visible(f"{name.replace('_', ' ')} ({unit})")
            lines.append(_row(label, float(v["sigma"]), float(v["p95"])))
        if where:
            lines.append(f"  (at {visible(where)}; from the solver's linearised covariance)")
    if res.distortion:
        lines.append(f"  {distortion_text(res.distortion)}")
    return lines


def outlier_lines(res: SolveResult) -> list[str]:
    """The outlier poses by the solve service's rule, or a line saying there are none."""
    from ..solving.outliers import RULE
    if not res.outliers:
        return textwrap.wrap(f"outlier poses (session pose index): none (rule: {RULE})", 98,
                             subsequent_indent="  ")
    lines = textwrap.wrap(f"outlier poses (session pose index; rule: {RULE}):", 98,
                          subsequent_indent="  ")
    for o in res.outliers:
        why = "; ".join(f"{f['body']} {f['metric']} {f['value']:.4f} {f['unit']} > "
                        f"{f['threshold']:.4f} {f['unit']}" for f in o["flags"])
        lines.append(f"  pose index {o['index']}: {why}")
    return lines


def legend_lines(res: SolveResult) -> list[str]:
    """The legend of the solve table: which matrices the errors apply, what the metrics are."""
    applied = ("raw matrices applied: the errors use the solver's general (non-orthogonal) "
               "3×4 X, Y, Z, the paper's way (--orthonormal applies the orthonormal ones "
               "instead)"
               if res.applied == "raw" else
               "orthonormal matrices applied: the errors use the orthonormal X, Y, Z printed "
               "below")
    leaves = ("the matrices below are the orthonormal X, Y, Z (rotations projected to SO(3), "
              "translations re-solved): the ones the calibration file's X, Y, Z, every "
              "export and tmscal stream carry (docs/exports.md)")
    lines = [
        "legend (docs/methods.md):",
        "  E: what is left of A X = Z B (marker) or A Y = Z C (probe) on one pose; e_trans ="
        " ‖t(E⊥)‖ in mm, θ = the rotation angle of E⊥ in degrees (E⊥: rotation projected to"
        " SO(3)), each averaged over the test poses (Wang et al. 2018)",
        f"  e_t, θ_t: the total error, the sum of the rows above it ({_parts(res.errors)})",
    ]
    if "e_z_mm" in res.errors:
        lines.append("  e_z, θ_z: QR24 solves a separate Z for marker (Z_M) and probe (Z_P);"
                     " e_z = ‖t(Z_P) − t(Z_M)‖ mm, θ_z = the angle between their rotations")
    if res.truth and "coil_placement_mm" in res.truth:
        lines.append("  coil placement: to put the coil at a tracked pose C the robot "
                     "commands A = Ẑ C Ŷ⁻¹ (with an identified arm, the pose its controller "
                     "must be told for the real arm to reach A); the error is how far the coil "
                     "centre then lands from where it was wanted, with the true Y, Z (and the "
                     "true arm, when the simulated rig has one) (mm)")
    if res.uncertainty:
        lines.append("  predicted uncertainty: propagated from the solver's parameter "
                     "covariance (linearised); 1-σ is the RMS error, 95 % the radius holding "
                     "95 % of the predicted errors, of where the coil centre (mm) and its axis "
                     "(deg) land when the robot places it")
    if res.distortion:
        lines.append("  tracker distortion: the map D of tracker-frame positions the solver "
                     "found (measured = D · true), as a scale in %; the calibration file (raw, "
                     "distortion) carries it, and stream's CoilToRobotBase applies it")
    lines.append("  " + applied)
    lines.append("  " + leaves)
    return [w for ln in lines for w in textwrap.wrap(ln, 98, subsequent_indent="      ",
                                                    break_on_hyphens=False) or [""]]


def format_result(res: SolveResult, show_matrices: bool = True, verbose: bool = False) -> str:
    """The ``tmscal solve`` human output: what was solved, the error table (mean ± SD over
    folds when cross-validated), the errors against the truth (simulated sessions), the
    outlier poses, a legend defining each number, and the calibration matrices. With an
    estimated arm it opens with :func:`arm_summary_rows` and counts the combinations of
    deviations; ``verbose`` lists them (:func:`arm_rows`)."""
    lines = arm_summary_rows(res)
    if lines:
        lines.append("")
    lines += [f"{visible(res.method.upper())} calibration solved on {res.n_solve} poses "
              f"({res.applied} matrices applied; see legend)", _errors_on_text(res)]
    if res.n_skipped:
        lines.append(f"({res.n_skipped} poses of the session were skipped at acquisition "
                     "and are not used)")
    lines += [""] + error_rows(res)
    extra = uncertainty_rows(res)
    if extra:
        lines += [""] + extra
    if res.arm is not None:
        lines += [""] + arm_rows(res.arm, verbose)
    extra = before_after_rows(res)
    if extra:
        lines += [""] + extra
    if res.prediction:
        lines += [""] + prediction_rows(res)
    if res.truth is not None:
        lines += [""] + truth_rows(res)
    lines += [""] + outlier_lines(res) + [""] + legend_lines(res)
    if show_matrices:
        for k, name in (("X", "flange_from_marker"), ("Y", "flange_from_probe"),
                        ("Z", "base_from_tracker")):
            M = getattr(res, k)
            if M is not None:
                lines.append("")
                lines.append(f"  {k} = {name} (orthonormal, mm)")
                lines.append(format_matrix(M))
    return "\n".join(lines)


def format_study(study: dict[str, Any], paper: dict[str, Any] | None = None) -> str:
    """Tables 1 and 3 of Wang et al. (2018) for a study result."""
    out = [f"convergence study: train on the first n poses (n = {study['n'][0]}…"
           f"{study['n'][-1]}), test on {study['n_test']} later poses", ""]
    hdr = f"  {'method':<7}{'metric':<16}" + "".join(
        f"{h:>16}" for h in ("min (n)", "25% (n)", "median (n)", "75% (n)", "max (n)"))
    out.append(hdr)
    for m, t in study["table"].items():
        for metric in ("e_t_mm", "theta_t_deg", "e_z_mm", "marker_trans_mm", "probe_trans_mm"):
            s = t["stats"].get(metric)
            if not s:
                continue
            cells = "".join(f"{s[k]['value']:>10.4f} ({s[k]['n']:>3})"
                            for k in ("min", "p25", "median", "p75", "max"))
            out.append(f"  {m:<7}{metric:<16}{cells}")
    out.append("")
    out.append("  smallest n after which e_t stays below:")
    for m, t in study["table"].items():
        thr = ", ".join(f"{k} mm: {'never' if v is None else v}"
                        for k, v in t["n_below_mm"].items())
        out.append(f"    {m:<7}{thr}")
    floor = study.get("noise_floor")
    if floor:
        out.append("")
        out.append(f"  noise floor (the true X, Y, Z on the same test poses): e_t "
                   f"{floor['e_t_mm']:.4f} mm, θ_t {floor['theta_t_deg']:.4f} deg")
    out.append("")
    out.append("  e_t, θ_t: hold-out translation (mm) and rotation (deg) errors, marker + probe "
               "(+ e_z, θ_z for QR24); docs/methods.md")
    return "\n".join(out)


def format_robot_time(rt: dict[str, float]) -> str:
    """Robot time by phase (s) on one line: moving, settling, sampling and the total."""
    return (f"robot time {rt['total']:.1f} s: moving {rt['moving']:.1f} s, settling "
            f"{rt['settling']:.1f} s, sampling {rt['sampling']:.1f} s")


def format_prediction(pred: Any, region: str) -> str:
    """The adaptive prediction (``calib.prediction.Prediction``) in two lines: the predicted
    coil-placement error (mm) at its confidence and its RMS, the calibration it is about (its
    method and distortion) and its poses, and the region it is averaged over (``region``, a
    description)."""
    return (f"predicted coil-placement error of the {pred.calibration.method} calibration "
            f"(distortion {pred.problem.model}, {pred.n_poses} poses) {pred.coil_mm:.3g} mm at "
            f"{pred.confidence * 100:g} % (RMS {pred.sigma_mm:.3g} mm)\n"
            f"  mean over {region}")


def prediction_subject(p: dict[str, Any]) -> str:
    """What a ``prediction`` (``solving.predict.calibration_prediction``) is of, for a line:
    "QR36 calibration", "ML calibration with the estimated vs060 arm"."""
    arm = p.get("arm")
    out = f"{str(p.get('method', '?')).upper()} calibration"
    if arm:
        out += f" with the {arm.get('source', '?')} {arm.get('nominal', '?')} arm"
    return out
