"""QR24 and QR36 (Wang et al. 2018; Ernst et al. 2012): the linear solution of
:mod:`.linear`, orthonormalised, as a ``Calibration``; registered as the methods "qr24" and
"qr36".

Frames: A = base_from_flange, B = tracker_from_marker, C = tracker_from_probe,
X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker; 4×4 mm.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..errors import CalibrationError
from .calibration import Applied, Calibration
from .linear import orthonormal_from_raw, solve_linear
from .methods import register_method

__all__: list[str] = []


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


register_method("qr24")(_qr("qr24"))
register_method("qr36")(_qr("qr36"))
