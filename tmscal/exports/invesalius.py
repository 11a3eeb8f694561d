"""InVesalius robot co-registration file (``.rbtf``; ``tmscal export --format invesalius``).

InVesalius' robot dialog (RobotCoregistrationDialog, "Registration file: Save") writes the
matrices tms-robot-control estimated, tab-separated CSV with one number per line: 48 numbers,
three 4×4 matrices row by row, in this order (tms-robot-control splits them back with
``np.split(np.array(data).reshape(12, 4), 3)``):

1. X — the robot TCP ← coil marker transform of its AX = YB (tmscal's X = flange_from_marker)
2. Y — robot base ← tracker (tmscal's Z = base_from_tracker)
3. affine — robot base ← tracker from a point fit, used for the target's POSITION
   (tmscal's Z again: a rigid calibration needs no separate affine fit)

tms-robot-control takes a tracked coil pose N (tracker, mm) into the robot as the rotation of
Y N X⁻¹ and the position of affine · N (the marker's origin in the base frame); both are the
robot's TCP pose when the TCP is set at the marker's origin with the flange's orientation,
i.e. TCP offset = t(X) (as its own registration requires: "robot TCP calibrated to the centre
of the tracker marker"). Units mm. The file has no slot for tmscal's Y (flange_from_probe: the
coil's effective centre and axis) nor for marker ← coil (X⁻¹ · Y): it is exactly three
matrices, which tms-robot-control splits in three. InVesalius takes the coil from its own coil
(object) registration instead, which is not a transform but what the user measured: the
tracked stylus at three fiducials of InVesalius' coil model and the coil marker's pose at the
time (positions and Euler angles), from which InVesalius builds the coil's frame on its model
(docs/exports.md says why tmscal cannot write one). The file format allows no comments.
"""

from __future__ import annotations

import numpy as np

from ..formats.calibfile import CalibrationFile

__all__ = ["matrices", "render", "tcp_offset_mm"]


def matrices(cf: CalibrationFile) -> list[np.ndarray]:
    """[X, Y, affine] in tms-robot-control's order, from tmscal's X and Z (4×4, mm)."""
    m = cf.calibration.exported()  # rigid, as every export (docs/exports.md)
    X, Z = np.asarray(m["X"], dtype=float), np.asarray(m["Z"], dtype=float)
    return [X, Z, Z.copy()]


def tcp_offset_mm(cf: CalibrationFile) -> list[float]:
    """The robot TCP offset (flange frame, mm, no rotation) the file assumes: t(X)."""
    return [float(v) for v in np.asarray(cf.calibration.exported()["X"], dtype=float)[:3, 3]]


def render(cf: CalibrationFile) -> str:
    """The ``.rbtf`` text: 48 lines, one number each, CRLF line ends (as Python's csv module
    writes them for InVesalius)."""
    flat = np.concatenate([m.ravel() for m in matrices(cf)])
    return "".join(f"{float(v)!r}\r\n" for v in flat)
