"""The method comparison of ``tmscal compare`` (docs/methods.md, "Comparing the methods"): on
one session, every registered method's held-out position and orientation error (mean ± SD over
folds) and its solve time against the number of poses solved on, as the Panda/Vicra TMS study
compared QR24, SGO and QUAT; with a truth in the session, the ground-truth errors (and the
Cramér–Rao bound when ``tmscal.calib.bound`` offers one) beside them.

Protocol: the usable poses, in order, are cut into k contiguous folds (``numpy.array_split``);
for each n and each fold, a method is solved on the first n poses that are not in the fold and
tested on the fold. Frames and metrics as in docs/methods.md: A = base_from_flange,
B = tracker_from_marker, C = tracker_from_probe; mm and degrees.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from .. import calib
from ..calib import solve, truth_errors
from ..errors import CalibrationError
from ..session import Session
from .kinematics import coil_placement, truth_arm_of, usable_joints

__all__ = ["compare_session", "compare_arrays", "default_ns", "find_bound",
           "handheld_options", "session_noise"]

_DEFAULT_NS = (5, 7, 10, 14, 20, 30, 50, 100, 150, 250, 500)


def default_ns(n_train_max: int) -> list[int]:
    """The pose counts compared by default: 5, 7, 10, 14, 20, 30, 50, 100, 150, 250, 500 up to
    the largest training set, and that set itself."""
    ns = [n for n in _DEFAULT_NS if n <= n_train_max]
    if n_train_max >= 3 and (not ns or ns[-1] != n_train_max):
        ns.append(n_train_max)
    return ns


def find_bound() -> Callable[..., dict[str, float]] | None:
    """The Cramér–Rao bound of ``tmscal.calib.bound`` (``crb`` and ``translation_rms_bound``)
    as ``fn(A, B, C, truth, noise) -> {"X_trans_mm": …[, "Y_trans_mm": …]}`` (the smallest RMS
    translation error, mm, an unbiased method can have), or None when tmscal.calib has no
    bound: the comparison then leaves it out."""
    import importlib

    try:
        b = importlib.import_module("tmscal.calib.bound")
    except ImportError:
        return None
    if not all(hasattr(b, n) for n in ("crb", "translation_rms_bound")):
        return None

    def fn(A: np.ndarray, B: np.ndarray, C: np.ndarray | None, truth: dict[str, Any],
           noise: dict[str, Any]) -> dict[str, float]:
        cov = b.crb(A, B, C, truth, noise)
        nb = 2 if C is not None and truth.get("Y") is not None else 1
        out = {"X_trans_mm": b.translation_rms_bound(cov, "X", nb)}
        if nb == 2:
            out["Y_trans_mm"] = b.translation_rms_bound(cov, "Y", nb)
        return out
    return fn


def session_noise(session: Session) -> dict[str, Any] | None:
    """The noise of a session written by ``tmscal simulate`` in the terms of the bound (and of
    ``ml``'s options), from its header (``config.simulate``); None for other sessions or when
    tmscal.calib has no ``bound.sim_noise_options``."""
    import importlib

    from ..sim import TOOL_8700340_MM

    sim = (session.header.get("config") or {}).get("simulate")
    if not isinstance(sim, dict):
        return None
    try:
        b = importlib.import_module("tmscal.calib.bound")
        return dict(b.sim_noise_options(float(sim["fiducial_sigma_mm"]),
                                        float(sim["robot_rot_sigma_deg"]),
                                        float(sim["robot_trans_sigma_mm"]), TOOL_8700340_MM,
                                        int(sim.get("samples", 1))))
    except (ImportError, AttributeError, KeyError, TypeError, ValueError):
        return None


def compare_session(session: Session, methods: Sequence[str] | None = None,
                    ns: Sequence[int] | None = None, folds: int = 5,
                    progress: Callable[[int], Any] | None = None) -> dict[str, Any]:
    """The comparison on a session's usable poses (probe poses when every one has them).
    Returns the dict of :func:`compare_arrays` with "session" (its path) added."""
    need_probe = "probe" in session.bodies
    A, B, C, idx = session.arrays(need_probe=need_probe)
    if len(A) == 0:
        raise CalibrationError(f"{session.path}: no usable poses in the session")
    out = compare_arrays(A, B, C, methods, ns=ns, folds=folds, truth=session.truth,
                         noise=session_noise(session), progress=progress,
                         truth_arm=truth_arm_of(session), joints=usable_joints(session, idx))
    out["session"] = str(session.path)
    return out


def _folds(n: int, k: int) -> list[np.ndarray]:
    if k < 2:
        raise CalibrationError(f"folds={k}: the comparison needs at least 2 folds")
    folds = np.array_split(np.arange(n), min(k, n))
    if n - max(len(f) for f in folds) < 3:
        raise CalibrationError(f"{n} poses are too few for {k} folds (each fold must leave at "
                               "least 3 poses to solve on)")
    return folds


def compare_arrays(A: np.ndarray, B: np.ndarray, C: np.ndarray | None,
                   methods: Sequence[str] | None = None, ns: Sequence[int] | None = None,
                   folds: int = 5, truth: dict[str, np.ndarray] | None = None,
                   noise: dict[str, Any] | None = None,
                   progress: Callable[[int], Any] | None = None,
                   truth_arm: dict[str, Any] | None = None,
                   joints: np.ndarray | None = None) -> dict[str, Any]:
    """Compare methods on poses A, B[, C] (n, 4, 4) mm.

    Returns {"n_poses", "folds", "fold_sizes", "ns", "bodies", "methods": {name: {"n": [..],
    "e_t_mm": {"mean", "sd"}, "theta_t_deg": {…}, "time_ms": {…}, "failed": {n: reason},
    ["truth": {"X_trans_mm", "Y_trans_mm", "coil_placement_mm", …: {"mean", "sd"}}]}},
    "skipped": {name: reason} (e.g. a method that needs probe poses on a marker-only session),
    "bound": {"n", "X_trans_mm", ["Y_trans_mm"]} (the Cramér–Rao bound of the RMS
    translation error, mm, on the first fold's training poses) or None, "truth": bool}; the
    bound needs ``truth`` and ``noise`` (the robot and tracker noise as ``ml``'s options).
    Errors are the hold-out errors of docs/methods.md
    (e_t = marker + probe (+ e_z for QR24), θ_t likewise); time is wall time per solve. The
    coil placement commands ``Calibration.flange_command``; with the truth's arm
    (``truth_arm``, ``Session.truth_arm``) and the poses' ``joints`` (n, dof) rad, the flange
    goes where that arm's controller takes it (``solving.kinematics.coil_placement``)."""
    methods = list(calib.METHODS) if methods is None else [m.lower() for m in methods]
    for m in methods:
        calib.get_method(m)
    fs = _folds(len(A), folds)
    n_train_max = len(A) - max(len(f) for f in fs)
    ns = default_ns(n_train_max) if ns is None else sorted(set(int(n) for n in ns))
    too_big = [n for n in ns if n > n_train_max or n < 3]
    if too_big:
        raise CalibrationError(f"ns={too_big[0]}: each fold leaves {n_train_max} poses to "
                               f"solve on (and a solve needs at least 3); use n in 3…"
                               f"{n_train_max} or fewer folds")
    out: dict[str, Any] = {"n_poses": len(A), "folds": len(fs),
                           "fold_sizes": [len(f) for f in fs], "ns": ns,
                           "bodies": ["marker"] + ([] if C is None else ["probe"]),
                           "methods": {}, "skipped": {}, "truth": bool(truth), "bound": None}
    for m in methods:
        try:
            res = _compare_method(m, A, B, C, fs, ns, truth, progress, truth_arm, joints)
        except CalibrationError as e:
            out["skipped"][m] = str(e)
            continue
        out["methods"][m] = res
    if truth and noise:
        out["bound"] = _bound(A, B, C, fs, ns, truth, noise)
    return out


def _compare_method(m: str, A: np.ndarray, B: np.ndarray, C: np.ndarray | None,
                    fs: list[np.ndarray], ns: Sequence[int], truth: dict[str, Any] | None,
                    progress: Callable[[int], Any] | None,
                    truth_arm: dict[str, Any] | None = None,
                    joints: np.ndarray | None = None) -> dict[str, Any]:
    """One method's curves. Raises CalibrationError (the method is skipped) when it fails at
    every n, e.g. a method that needs probe poses on a marker-only session."""
    rows: dict[str, list[list[float]]] = {}
    failed: dict[int, str] = {}
    for n in ns:
        per_fold: dict[str, list[float]] = {}
        for test in fs:
            train = np.setdiff1d(np.arange(len(A)), test)[:n]
            try:
                vals = _one_solve(m, A, B, C, train, test, truth, truth_arm, joints)
            except CalibrationError as e:
                failed[n] = str(e)
                vals = {}
            for k, v in vals.items():
                per_fold.setdefault(k, []).append(v)
            if progress is not None:
                progress(1)
        for k, series in per_fold.items():
            rows.setdefault(k, [[] for _ in ns])[ns.index(n)] = series
    if len(failed) == len(ns) and not rows:
        raise CalibrationError(next(iter(failed.values())))
    res: dict[str, Any] = {"n": list(ns), "failed": failed}
    for k, per_n in rows.items():
        stats = {"mean": [float(np.mean(v)) if v else float("nan") for v in per_n],
                 "sd": [float(np.std(v, ddof=1)) if len(v) > 1 else float("nan")
                        for v in per_n]}
        if k.startswith("truth:"):
            res.setdefault("truth", {})[k[6:]] = stats
        else:
            res[k] = stats
    return res


def _one_solve(m: str, A: np.ndarray, B: np.ndarray, C: np.ndarray | None,
               train: np.ndarray, test: np.ndarray, truth: dict[str, Any] | None,
               truth_arm: dict[str, Any] | None = None, joints: np.ndarray | None = None
               ) -> dict[str, float]:
    """Solve on ``train``, test on ``test``: {"e_t_mm", "theta_t_deg", "time_ms",
    "truth:<k>"…}."""
    Ctr = None if C is None else C[train]
    opts = handheld_options(m, B[train[:1]], None if Ctr is None else Ctr[:1])
    t0 = time.perf_counter()
    cal = solve(A[train], B[train], Ctr, method=m, **opts)
    dt = time.perf_counter() - t0
    err = cal.errors(A[test], B[test], None if C is None else C[test])
    vals = {"e_t_mm": err["e_t_mm"], "theta_t_deg": err["theta_t_deg"], "time_ms": 1e3 * dt}
    if truth:
        te = truth_errors({"X": cal.X, "Y": cal.Y, "Z": cal.Z}, truth)
        for k, d in te.items():
            vals[f"truth:{k}_trans_mm"] = d["trans_mm"]
            vals[f"truth:{k}_rot_deg"] = d["rot_deg"]
        if C is not None and cal.Y is not None and truth.get("Y") is not None:
            coil = coil_placement(cal, C[test], truth, truth_arm,
                                  None if joints is None else joints[test])
            vals["truth:coil_placement_mm"] = float(coil.mean())
    return vals


def handheld_options(method: str, B_a: np.ndarray, C_a: np.ndarray | None) -> dict[str, Any]:
    """The options that give a method which takes the handheld measurement (``handheld_B``,
    ``handheld_C``: the marker and the probe at the coil centre seen together, as in the
    handheld coil calibration Wang et al. 2018 compare against) the poses B_a[0], C_a[0];
    {} for other methods or without probe poses."""
    import inspect

    fn = calib.METHODS.get(method)
    if fn is None or C_a is None or len(C_a) == 0:
        return {}
    params = inspect.signature(fn).parameters
    if "handheld_B" in params and "handheld_C" in params:
        return {"handheld_B": B_a[0], "handheld_C": C_a[0]}
    return {}


def _bound(A: np.ndarray, B: np.ndarray, C: np.ndarray | None, fs: list[np.ndarray],
           ns: Sequence[int], truth: dict[str, Any], noise: dict[str, Any]
           ) -> dict[str, Any] | None:
    """The bound at each n, on the first fold's training poses: {"n": [..], "<X|Y>_trans_mm":
    [..]}; None when there is no bound function or it cannot be evaluated."""
    fn = find_bound()
    if fn is None:
        return None
    out: dict[str, Any] = {"n": list(ns)}
    for i, n in enumerate(ns):
        train = np.setdiff1d(np.arange(len(A)), fs[0])[:n]
        try:
            b = fn(A[train], B[train], None if C is None else C[train], truth, noise)
        except (CalibrationError, TypeError, ValueError, KeyError, np.linalg.LinAlgError):
            b = {}
        for k, v in b.items():
            out.setdefault(k, [float("nan")] * len(ns))[i] = float(v)
    return out if len(out) > 1 else None
