"""Solve a session and assemble the result object that ``tmscal solve --json`` prints.

Frames: A = base_from_flange, B = tracker_from_marker, C = tracker_from_probe,
X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker; 4×4 mm.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..calib import Calibration, coil_placement_errors, solve, truth_errors
from ..calib.metrics import body_errors
from ..calib.study import convergence, summarize, threshold_n
from ..errors import CalibrationError
from ..session import Session

__all__ = ["solve_session", "study_session", "session_arrays", "pose_residuals"]


def session_arrays(session: Session, method: str) -> tuple[np.ndarray, np.ndarray,
                                                           np.ndarray | None]:
    """(A, B, C) of the usable poses of a session, in index order; C None for marker-only
    sessions. Raises CalibrationError when qr36 is asked of marker-only data."""
    need_probe = method == "qr36"
    if need_probe and "probe" not in session.bodies:
        raise CalibrationError(f"{session.path}: marker-only session (bodies: "
                               f"{', '.join(session.bodies)}); qr36 needs a probe — use "
                               "--method qr24")
    A, B, C, _ = session.arrays(need_probe=need_probe)
    return A, B, C


def _mat(M: np.ndarray | None) -> list | None:
    return None if M is None else np.asarray(M, dtype=float).tolist()


def solve_session(session: Session, method: str = "qr36", train: int | None = None,
                  orthonormal: bool = False) -> tuple[Calibration, dict[str, Any]]:
    """Solve on poses [0, train) (default: all) and evaluate on the rest (in-sample when
    nothing is left). Returns the Calibration and the result object: method, n_solve,
    n_test, errors_on ("held-out" or "in-sample"), X, Y, Z (orthonormal 4×4 mm lists),
    raw matrices, errors {e_t_mm, theta_t_deg, bodies…, e_z_mm, theta_z_deg}, and truth
    {X/Y/Z: {trans_mm, rot_deg}, coil_placement_mm (mean over the evaluated poses),
    coil_placement_max_mm} when the session has truth.
    """
    A, B, C = session_arrays(session, method)
    n = len(A)
    if n == 0:
        raise CalibrationError(f"{session.path}: no usable poses in the session")
    if train is None:
        train = n
    if train < 3:
        raise CalibrationError(f"--train {train}: need at least 3 poses to solve")
    if train > n:
        raise CalibrationError(f"--train {train}: the session has only {n} usable poses")
    cal = solve(A[:train], B[:train], None if C is None else C[:train], method=method,
                orthonormal=orthonormal)
    held_out = train < n
    sl = slice(train, n) if held_out else slice(0, n)
    errors = cal.errors(A[sl], B[sl], None if C is None else C[sl])
    res: dict[str, Any] = {
        "method": cal.method,
        "applied": cal.applied,
        "n_solve": int(train),
        "n_test": int(n - train) if held_out else int(n),
        "errors_on": "held-out" if held_out else "in-sample",
        "n_skipped": sum(p.skipped is not None for p in session.poses),
        "X": _mat(cal.X), "Y": _mat(cal.Y), "Z": _mat(cal.Z),
        "raw": {"X": _mat(cal.X_raw), "Y": _mat(cal.Y_raw), "Z": _mat(cal.Z_raw)},
        "errors": _flat_errors(errors),
    }
    if cal.Z_probe is not None:
        res["Z_probe"] = _mat(cal.Z_probe)
        res["raw"]["Z_probe"] = _mat(cal.Z_probe_raw)
    truth = session.truth
    if truth:
        te = truth_errors({"X": cal.X, "Y": cal.Y, "Z": cal.Z}, truth)
        res["truth"] = dict(te)
        if C is not None and cal.Y is not None and "Y" in truth:
            u = cal.used()
            coil = coil_placement_errors(C[sl], u["Y"], u["Z"], truth["Y"], truth["Z"])
            res["truth"]["coil_placement_mm"] = float(coil.mean())
            res["truth"]["coil_placement_max_mm"] = float(coil.max())
    return cal, res


def _flat_errors(err: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {"e_t_mm": err["e_t_mm"], "theta_t_deg": err["theta_t_deg"]}
    for b, d in err["bodies"].items():
        out[b] = {"trans_mm": d["trans_mm"], "rot_deg": d["rot_deg"]}
    for k in ("e_z_mm", "theta_z_deg"):
        if k in err:
            out[k] = err[k]
    return out


def study_session(session: Session, methods: list[str], n_max: int = 250, n_min: int = 5,
                  thresholds_mm: tuple[float, ...] = (0.4, 0.3), orthonormal: bool = False,
                  progress: Any = None) -> dict[str, Any]:
    """The convergence study of Wang et al. (2018) on a session: curves (their Figure 3),
    statistics with the n of each (Tables 1 and 2) and the n after which e_t stays below each
    threshold (Table 3)."""
    need_probe = "qr36" in methods
    for m in methods:
        session_arrays(session, m)
    A, B, C, _ = session.arrays(need_probe=need_probe)
    if len(A) == 0:
        raise CalibrationError(f"{session.path}: no usable poses in the session")
    if "probe" not in session.bodies:
        C = None
    curves = convergence(A, B, C, methods, n_min=n_min, n_max=n_max, orthonormal=orthonormal,
                         progress=progress)
    ns = curves["n"]
    table: dict[str, Any] = {}
    for m, c in curves["methods"].items():
        stats = {k: summarize(v, ns) for k, v in c.items()}
        thr = {f"{t:g}": threshold_n(c["e_t_mm"], ns, t) for t in thresholds_mm} \
            if "e_t_mm" in c else {}
        table[m] = {"stats": stats, "n_below_mm": thr}
    return {"n": ns, "n_test": curves["n_test"], "curves": curves["methods"], "table": table}


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
