"""The calibration methods by name: ``solve`` checks the poses and hands them to the method
registered under that name (``register_method``; the built-in ones are registered when
:mod:`tmscal.calib` is imported: QR24 and QR36 (:mod:`.qr`), the classic ones
(:mod:`.classic`), ``ml`` (:mod:`.ml`) and ``sgo`` (:mod:`.sgo`); docs/methods.md).

Frames: A = base_from_flange, B = tracker_from_marker, C = tracker_from_probe; (n, 4, 4) mm.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from ..errors import CalibrationError
from ..geometry import RIGID_TOL_DEFAULT, check_poses
from .calibration import Calibration

#: method name → solver ``fn(A, B, C, orthonormal: bool, **options) -> Calibration`` (inputs
#: already checked by ``check_inputs``), in registration order; filled by ``register_method``,
#: read by ``get_method``
METHODS: dict[str, Callable[..., Calibration]] = {}

__all__ = ["METHODS", "solve", "register_method", "get_method", "check_inputs"]


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
        METHODS[name] = fn
        return fn
    return deco


def get_method(name: str, where: str = "") -> Callable[..., Calibration]:
    """The solver registered as ``name`` (case-insensitive); an unknown name is a
    CalibrationError listing the known ones, prefixed with ``where`` (e.g. an option) when
    given."""
    fn = METHODS.get(name.lower()) if isinstance(name, str) else None
    if fn is None:
        pre = f"{where}: " if where else ""
        raise CalibrationError(f"{pre}unknown method {name!r}; known: {', '.join(METHODS)}")
    return fn


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
    fn = get_method(method)
    A, B, C = check_inputs(A, B, C)
    try:
        return fn(A, B, C, orthonormal, **options)
    except TypeError as e:
        if options and "argument" in str(e):
            raise CalibrationError(f"method {method!r}: {e}") from None
        raise
