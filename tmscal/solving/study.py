"""The convergence study of a session (``tmscal study``): Wang et al. (2018)'s curves, tables
and the noise floor, on a session's usable poses (docs/methods.md).

Frames: A = base_from_flange, B = tracker_from_marker, C = tracker_from_probe; mm, degrees.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..calib import noise_floor
from ..calib.study import convergence, summarize, threshold_n
from ..errors import CalibrationError
from ..session import Session
from .solve import session_arrays

__all__ = ["study_session"]


def study_session(session: Session, methods: list[str], n_max: int = 250, n_min: int = 5,
                  thresholds_mm: tuple[float, ...] = (0.4, 0.3), orthonormal: bool = False,
                  progress: Any = None) -> dict[str, Any]:
    """The convergence study of Wang et al. (2018) on a session: curves (their Figure 3),
    statistics with the n of each (Tables 1 and 2) and the n after which e_t stays below each
    threshold (Table 3); "noise_floor" ({e_t_mm, theta_t_deg}: the true X, Y, Z on the
    same test poses) when the session knows the truth."""
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
    out = {"n": ns, "n_test": curves["n_test"], "curves": curves["methods"], "table": table}
    floor = _study_floor(session, A[n_max:], B[n_max:], None if C is None else C[n_max:])
    if floor is not None:
        out["noise_floor"] = floor
    return out


def _study_floor(session: Session, A: np.ndarray, B: np.ndarray,
                 C: np.ndarray | None) -> dict[str, float] | None:
    """The noise floor of a study (docs/methods.md): e_t (mm) and θ_t (deg) of the true X, Y,
    Z on the study's test poses; None when the session has no truth."""
    truth = session.truth
    if not truth or "X" not in truth or "Z" not in truth:
        return None
    bodies, Xs = {"marker": B}, {"marker": truth["X"]}
    if C is not None and "Y" in truth:
        bodies["probe"], Xs["probe"] = C, truth["Y"]
    f = noise_floor(A, bodies, Xs, truth["Z"])
    return {"e_t_mm": f["e_t_mm"], "theta_t_deg": f["theta_t_deg"]}
