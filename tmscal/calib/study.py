"""Convergence study (Wang et al. 2018, Tables 1 and 3, Figure 3; docs/methods.md): train on
the first n poses for n = n_min … n_max, test on the poses after n_max, and summarise the
error curve; and k-fold cross-validation (:func:`cross_validate`), the default hold-out
estimate of ``tmscal solve``.

Frames as everywhere: A = base_from_flange, B = tracker_from_marker, C = tracker_from_probe;
(n, 4, 4) mm. Errors in mm and degrees.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..errors import CalibrationError
from .methods import solve

__all__ = ["convergence", "summarize", "threshold_n", "cross_validate", "per_pose_options",
           "PER_POSE_OPTIONS"]


def convergence(A: np.ndarray, B: np.ndarray, C: np.ndarray | None,
                methods: Sequence[str] = ("qr24", "qr36"), n_min: int = 5, n_max: int = 250,
                orthonormal: bool = False, progress: Any = None) -> dict[str, Any]:
    """Error curves for each method. The test set is every pose from index ``n_max`` on
    (Wang et al. 2018: train on P1…Pn, test on P251…P500); needs more than ``n_max`` poses.

    Returns {"n": [..], "n_test": int, "methods": {name: {"e_t_mm": [..], "theta_t_deg": [..],
    "marker_trans_mm": [..], …, "e_z_mm": [..] (qr24 with probe)}}}. ``progress`` is an
    optional callable taking the number of solves done (for a progress bar)."""
    N = len(A)
    if n_max >= N:
        raise CalibrationError(f"the study needs more than n_max = {n_max} poses to keep a "
                               f"test set; the data has {N} (lower --n-max)")
    if n_min < 3 or n_min > n_max:
        raise CalibrationError(f"n_min must be in 3…n_max, got {n_min}")
    At, Bt = A[n_max:], B[n_max:]
    Ct = None if C is None else C[n_max:]
    ns = list(range(n_min, n_max + 1))
    out: dict[str, Any] = {"n": ns, "n_test": int(N - n_max), "methods": {}}
    for m in methods:
        rows: list[dict[str, float]] = []
        last_error: CalibrationError | None = None
        for n in ns:
            try:
                cal = solve(A[:n], B[:n], None if C is None else C[:n], method=m,
                            orthonormal=orthonormal)
                rows.append(_flatten(cal.errors(At, Bt, Ct)))
            except CalibrationError as e:
                rows.append({})
                last_error = e
            if progress is not None:
                progress(1)
        if not any(rows):
            raise CalibrationError(f"{m}: no training size from {n_min} to {n_max} gave a "
                                   f"solution ({last_error})")
        keys = sorted({k for r in rows for k in r})
        curves = {k: [r.get(k, float("nan")) for r in rows] for k in keys}
        out["methods"][m] = curves
    return out


def _flatten(err: dict[str, Any]) -> dict[str, float]:
    flat = {"e_t_mm": err["e_t_mm"], "theta_t_deg": err["theta_t_deg"]}
    for b, d in err["bodies"].items():
        flat[f"{b}_trans_mm"] = d["trans_mm"]
        flat[f"{b}_rot_deg"] = d["rot_deg"]
    if "e_z_mm" in err:
        flat["e_z_mm"] = err["e_z_mm"]
        flat["theta_z_deg"] = err["theta_z_deg"]
    return flat


def summarize(values: Sequence[float], ns: Sequence[int]) -> dict[str, dict[str, float]]:
    """Min, 25th percentile, median, 75th percentile and max of an error curve, each with
    the n at which it occurs (for percentiles: the n whose value is nearest). NaNs ignored."""
    v = np.asarray(values, dtype=float)
    n = np.asarray(ns)
    ok = np.isfinite(v)
    if not ok.any():
        return {}
    v, n = v[ok], n[ok]
    out = {}
    for name, q in (("min", 0), ("p25", 25), ("median", 50), ("p75", 75), ("max", 100)):
        val = float(np.percentile(v, q))
        i = int(np.argmin(np.abs(v - val)))
        out[name] = {"value": val, "n": int(n[i])}
    return out


def threshold_n(values: Sequence[float], ns: Sequence[int], threshold: float) -> int | None:
    """Smallest n from which on the error stays below ``threshold`` (None if it never
    does by the last n)."""
    v = np.asarray(values, dtype=float)
    above = ~(v < threshold)
    if above[-1]:
        return None
    idx = np.nonzero(above)[0]
    return int(ns[0] if len(idx) == 0 else ns[idx[-1] + 1])


#: method options with one entry per pose, cut with the poses when they are split
PER_POSE_OPTIONS = ("joints", "spreads", "wrench", "wrench_sigma")


def per_pose_options(options: dict[str, Any], keep: Any, n: int) -> dict[str, Any]:
    """``options`` with its per-pose entries (:data:`PER_POSE_OPTIONS`, when they have one
    entry for each of the ``n`` poses) cut to the poses ``keep`` (indices or a slice)."""
    out = dict(options)
    idx = np.arange(n)[keep]
    for k in PER_POSE_OPTIONS:
        v = out.get(k)
        if v is not None and np.ndim(v) > 0 and len(v) == n:
            out[k] = np.asarray(v)[idx] if k != "spreads" else [v[i] for i in idx]
    return out


def cross_validate(A: np.ndarray, B: np.ndarray, C: np.ndarray | None, method: str = "qr36",
                   k: int = 5, orthonormal: bool = False, **options: Any) -> dict[str, Any]:
    """k-fold cross-validated hold-out errors (docs/methods.md). The poses, in their order,
    are cut into ``k`` contiguous folds of near-equal size (``numpy.array_split``: no seed, the
    same folds every run); each fold is held out in turn, the calibration solved on the other
    poses, and the errors of Wang et al. (2018) computed on the held-out fold. Contiguous
    folds also expose drift during a session (a block of late poses is tested against a
    calibration that did not see them).

    Options with one entry per pose (``joints`` (n, dof) rad, ``spreads``) are cut with the
    poses; a calibration that carries an identified arm (``Calibration.arm``: ``ml`` with
    ``kinematics="estimate"``) is tested on the robot poses it computes from the held-out
    poses' joints (``Calibration.robot_poses``, docs/kinematics.md).

    Returns {"folds": k, "split": "contiguous", "fold_sizes": [..], "per_fold": [{flat
    errors}], "mean": {flat errors}, "sd": {flat errors}}; flat keys as in :func:`convergence`
    ("e_t_mm", "theta_t_deg", "<body>_trans_mm", "<body>_rot_deg", "e_z_mm", "theta_z_deg"),
    mm and degrees; "sd" is the sample standard deviation over folds (ddof = 1).
    Raises CalibrationError when a fold would train on fewer than 3 poses or a fold's solve
    fails (naming the fold and its poses)."""
    n = len(A)
    k = int(k)
    if k < 2:
        raise CalibrationError(f"cross-validation needs at least 2 folds, got {k}")
    k = min(k, n)
    folds = np.array_split(np.arange(n), k)
    if n - max(len(f) for f in folds) < 3:
        raise CalibrationError(f"{n} poses are too few for {k}-fold cross-validation (each "
                               "fold must be solved on at least 3 poses); use --in-sample or "
                               "--train")
    rows = []
    for j, test in enumerate(folds):
        train = np.setdiff1d(np.arange(n), test)
        Ct = None if C is None else C[test]
        try:
            cal = solve(A[train], B[train], None if C is None else C[train], method=method,
                        orthonormal=orthonormal, **per_pose_options(options, train, n))
        except CalibrationError as e:
            raise CalibrationError(f"cross-validation fold {j + 1} of {k} (poses "
                                   f"{test[0]}–{test[-1]} held out): {e}; use --in-sample or "
                                   "--train") from None
        q = options.get("joints")
        At = cal.robot_poses(A[test], None if q is None else np.asarray(q)[test])
        rows.append(_flatten(cal.errors(At, B[test], Ct)))
    keys = list(rows[0])
    vals = {key: np.array([r[key] for r in rows]) for key in keys}
    return {"folds": k, "split": "contiguous", "fold_sizes": [len(f) for f in folds],
            "per_fold": rows,
            "mean": {key: float(v.mean()) for key, v in vals.items()},
            "sd": {key: float(v.std(ddof=1)) for key, v in vals.items()}}
