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

from .calibration import Applied, Calibration
from .linear import design_matrix
from .methods import METHODS, check_inputs, get_method, register_method, solve
from .metrics import coil_placement_errors, holdout_errors, noise_floor, truth_errors

__all__ = ["solve", "register_method", "get_method", "Applied", "Calibration", "METHODS",
           "design_matrix", "holdout_errors", "truth_errors", "coil_placement_errors",
           "noise_floor", "check_inputs"]

# the built-in methods register themselves, in this order (METHODS lists them so)
from . import qr, classic, ml, sgo  # noqa: E402,F401,I001
