"""Calibration solvers (pure numerics, no I/O): QR24, QR36, error metrics, convergence study.

Use without any hardware code::

    from tmscal.calib import solve
    cal = solve(A, B, C, method="qr36")      # A, B, C: (n, 4, 4) mm
    cal.X, cal.Y, cal.Z                      # orthonormal 4×4 mm
    cal.errors(A_test, B_test, C_test)       # hold-out metrics (docs/methods.md)

Frames: A = base_from_flange, B = tracker_from_marker, C = tracker_from_probe,
X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np

from ..errors import CalibrationError
from ..geometry import RIGID_TOL_DEFAULT, check_poses
from .linear import design_matrix, orthonormal_from_raw, solve_linear
from .metrics import coil_placement_errors, holdout_errors, noise_floor, truth_errors

#: method name → solver ``fn(A, B, C, orthonormal: bool, **options) -> Calibration`` (inputs
#: already checked by ``check_inputs``); filled by ``register_method``. ``METHODS`` iterates
#: over the names.
SOLVERS: dict[str, Callable[..., Calibration]] = {}
METHODS = SOLVERS

__all__ = ["solve", "register_method", "SOLVERS", "Applied", "Calibration", "METHODS",
           "design_matrix", "holdout_errors", "truth_errors", "coil_placement_errors",
           "noise_floor", "check_inputs"]


class Applied(StrEnum):
    """Which matrices a calibration applies: the raw linear solution (the paper's way: raw
    matrices, the product orthonormalised) or the orthonormal ones."""

    RAW = "raw"
    ORTHONORMAL = "orthonormal"


@dataclass
class Calibration:
    """Result of a solve. All 4×4, mm.

    ``X``, ``Y``, ``Z``: orthonormal (rotations projected to SO(3), translations re-solved).
    ``X_raw``, ``Y_raw``, ``Z_raw``: the linear solution, general 3×4 (last row 0001).
    ``Z_probe_raw`` / ``Z_probe``: QR24 on two bodies solves the probe separately; this is its Z.
    ``applied``: "raw" (the paper's way: raw matrices, orthonormalise the product) or
    "orthonormal" — which set :meth:`used` returns and :meth:`errors` applies.
    Y is None for marker-only data.
    """

    method: str
    n_poses: int
    X: np.ndarray
    Z: np.ndarray
    X_raw: np.ndarray
    Z_raw: np.ndarray
    Y: np.ndarray | None = None
    Y_raw: np.ndarray | None = None
    Z_probe: np.ndarray | None = None
    Z_probe_raw: np.ndarray | None = None
    applied: Applied = Applied.RAW
    #: parameter covariance of a statistical solver (e.g. ``ml``), in the order and units its
    #: ``extra["parameters"]`` names; None for the closed-form methods
    covariance: np.ndarray | None = None
    #: predicted uncertainty, e.g. {"coil_centre_mm": {"sigma": …, "p95": …},
    #: "coil_axis_deg": {…}}; None when the method gives none
    uncertainty: dict[str, Any] | None = None
    #: the tracker distortion a solver found, e.g. {"model": "scale", "matrix": 3×3,
    #: "scale_percent": 0.08}; None when not modelled
    distortion: dict[str, Any] | None = None
    #: method-specific facts (iterations, restarts, the information criterion, …)
    extra: dict[str, Any] = field(default_factory=dict)

    def used(self) -> dict[str, np.ndarray | None]:
        """The matrices applied: {"X", "Y", "Z", "Z_probe"} (raw or orthonormal).

        With a tracker ``distortion`` (measured positions = D · true), the applied Z undoes
        it: Z · G with G = D⁻¹ on the 3×3 block (a solver that reports a distortion already
        puts G into its Z_raw), so Z N of a measured N is the undistorted pose."""
        if self.applied == Applied.RAW:
            return {"X": self.X_raw, "Y": self.Y_raw, "Z": self.Z_raw,
                    "Z_probe": self.Z_probe_raw}
        out = {"X": self.X, "Y": self.Y, "Z": self.Z, "Z_probe": self.Z_probe}
        if self.distortion is not None and self.distortion.get("matrix") is not None:
            G4 = np.eye(4)
            G4[:3, :3] = np.linalg.inv(np.asarray(self.distortion["matrix"], dtype=float))
            out = {k: (None if v is None else v @ G4) if k in ("Z", "Z_probe") else v
                   for k, v in out.items()}
        return out

    def placement(self, C: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(targets, Y, Z) with which a robot places the coil at measured probe poses C
        (n, 4, 4) mm: the applied Y and Z; with a tracker ``distortion``, the targets
        undistorted first (``ml.undistort``) and the rigid Y, Z, so that no scale of the
        distortion leaks into the commanded flange pose Z C Y⁻¹."""
        d = self.distortion
        if d and d.get("matrix") is not None and d.get("model") != "none":
            from .ml import undistort
            G = np.linalg.inv(np.asarray(d["matrix"], dtype=float))
            return undistort(C, G, "affine"), self.Y, self.Z
        u = self.used()
        return C, u["Y"], u["Z"]

    def errors(self, A: np.ndarray, B: np.ndarray, C: np.ndarray | None = None
               ) -> dict[str, Any]:
        """Hold-out errors of Wang et al. (2018) on the poses given (n, 4, 4), as defined in
        docs/methods.md: per body "trans_mm", "rot_deg";
        with a ``distortion`` the measured poses are undistorted first (positions by D⁻¹,
        orientations as the tracker's rigid fit of the tool distorted them, with the tool
        moments when the solver had them) and Z is applied without the G it carries;
        "e_t_mm", "theta_t_deg"; "e_z_mm", "theta_z_deg" for QR24 on two bodies."""
        u = self.used()
        d = self.distortion
        if d is not None and d.get("matrix") is not None and d.get("model") != "none":
            from .ml import undistort  # the tracker's rigid fit of distorted fiducials, undone
            G = np.linalg.inv(np.asarray(d["matrix"], dtype=float))
            G4 = np.eye(4)
            G4[:3, :3] = np.linalg.inv(G)
            M = d.get("tool_moments") or {}
            B = undistort(B, G, "affine", M.get("marker"))
            C = None if C is None else undistort(C, G, "affine", M.get("probe"))
            u = {k: v @ G4 if k in ("Z", "Z_probe") and v is not None else v
                 for k, v in u.items()}  # Z without the G it carries
        bodies = {"marker": B}
        X_of = {"marker": u["X"]}
        Z_of = {"marker": u["Z"]}
        if C is not None and u["Y"] is not None:
            bodies["probe"] = C
            X_of["probe"] = u["Y"]
            Z_of["probe"] = u["Z_probe"] if u["Z_probe"] is not None else u["Z"]
        return holdout_errors(A, bodies, X_of, Z_of)


def check_inputs(A: Any, B: Any, C: Any = None) -> tuple[np.ndarray, np.ndarray,
                                                         np.ndarray | None]:
    """Validate pose arrays (n, 4, 4) mm: equal counts, finite, rigid (within
    :data:`tmscal.geometry.RIGID_TOL_DEFAULT`). Raises CalibrationError naming the array and
    pose."""
    try:
        A = check_poses(A, "A (base_from_flange)", tol=RIGID_TOL_DEFAULT)
        B = check_poses(B, "B (tracker_from_marker)", tol=RIGID_TOL_DEFAULT)
        C = None if C is None else check_poses(C, "C (tracker_from_probe)",
                                               tol=RIGID_TOL_DEFAULT)
    except ValueError as e:
        raise CalibrationError(str(e)) from None
    for name, arr in (("B", B), ("C", C)):
        if arr is not None and len(arr) != len(A):
            raise CalibrationError(f"{name} has {len(arr)} poses but A has {len(A)}")
    return A, B, C


def register_method(name: str) -> Callable[[Callable[..., Calibration]],
                                           Callable[..., Calibration]]:
    """Decorator: register ``fn(A, B, C, orthonormal, **options) -> Calibration`` as
    ``solve(..., method=name)`` and ``tmscal solve --method name``."""
    def deco(fn: Callable[..., Calibration]) -> Callable[..., Calibration]:
        SOLVERS[name] = fn
        return fn
    return deco


def solve(A: Any, B: Any, C: Any = None, method: str = "qr36", orthonormal: bool = False,
          **options: Any) -> Calibration:
    """Solve the calibration from poses A (base_from_flange), B (tracker_from_marker) and
    optionally C (tracker_from_probe), each (n, 4, 4) in mm.

    method "qr36" (needs C): X, Y, Z jointly (Wang et al. 2018). "qr24": marker alone (X, Z),
    and, if C is given, the probe separately (Y, Z_probe). Other registered methods are
    listed in ``METHODS`` (docs/methods.md); ``options`` go to the method. ``orthonormal``
    selects which matrices are applied by :meth:`Calibration.errors` (default: the raw
    matrices, the paper's way).
    Raises CalibrationError for unusable data (fewer than 3 poses, degenerate rotations,
    non-rigid or NaN poses, qr36 without C) and for an unknown method or option.
    """
    method = method.lower()
    if method not in SOLVERS:
        raise CalibrationError(f"unknown method {method!r}; known: {', '.join(SOLVERS)}")
    A, B, C = check_inputs(A, B, C)
    try:
        return SOLVERS[method](A, B, C, orthonormal, **options)
    except TypeError as e:
        if options and "argument" in str(e):
            raise CalibrationError(f"method {method!r}: {e}") from None
        raise


def _qr(method: str) -> Callable[..., Calibration]:
    def run(A: np.ndarray, B: np.ndarray, C: np.ndarray | None, orthonormal: bool
            ) -> Calibration:
        return _solve_qr_impl(A, B, C, method, orthonormal)
    run.__doc__ = f"{method.upper()} (Wang et al. 2018; Ernst et al. 2012)."
    return run


def _solve_qr_impl(A: np.ndarray, B: np.ndarray, C: np.ndarray | None, method: str,
                   orthonormal: bool) -> Calibration:
    """QR36 (X, Y, Z jointly) or QR24 (each body on its own), as ``solve`` describes."""
    if method == "qr36":
        if C is None:
            raise CalibrationError("qr36 needs probe poses C (this data is marker-only); "
                                   "use method qr24")
        Z_raw, (X_raw, Y_raw) = solve_linear(A, B, C)
        Z, (X, Y) = orthonormal_from_raw(A, [B, C], Z_raw, [X_raw, Y_raw])
        return Calibration("qr36", len(A), X=X, Z=Z, X_raw=X_raw, Z_raw=Z_raw, Y=Y,
                           Y_raw=Y_raw,
                           applied=Applied.ORTHONORMAL if orthonormal else Applied.RAW)
    Z_raw, (X_raw,) = solve_linear(A, B)
    Z, (X,) = orthonormal_from_raw(A, [B], Z_raw, [X_raw])
    cal = Calibration("qr24", len(A), X=X, Z=Z, X_raw=X_raw, Z_raw=Z_raw,
                      applied=Applied.ORTHONORMAL if orthonormal else Applied.RAW)
    if C is not None:
        ZP_raw, (Y_raw,) = solve_linear(A, C)
        ZP, (Y,) = orthonormal_from_raw(A, [C], ZP_raw, [Y_raw])
        cal.Y, cal.Y_raw, cal.Z_probe, cal.Z_probe_raw = Y, Y_raw, ZP, ZP_raw
    return cal


SOLVERS["qr24"] = _qr("qr24")
SOLVERS["qr36"] = _qr("qr36")

from . import classic, ml, sgo  # noqa: E402,F401,I001  (register their methods)
