"""ITK transform file (``.tfm``) of Z for 3D Slicer (``tmscal export --format itk``).

Conventions (docs/exports.md works them out): the tracker and robot-base frames are taken as
RAS, i.e. Slicer shows tmscal's numbers unchanged. ITK files are in LPS and hold the
resampling direction (from parent to child); Slicer converts LPS ↔ RAS with C = diag(−1, −1, 1)
and inverts, so that a node loaded from this file has the to-parent transform Z = base ←
tracker (tracker points into the robot base, mm). The file therefore holds

    T = C · Z⁻¹ · C      (LPS, base → tracker: the resampling direction)

as ``AffineTransform_double_3_3``: the 3×3 block row by row, then the translation (mm),
FixedParameters 0 0 0 (centre of rotation at the origin). Z is the orthonormal (rigid) one,
``Calibration.exported()``, as in every export and in ``tmscal stream``'s TrackerToRobotBase
(docs/exports.md, "Which matrices leave tmscal").
"""

from __future__ import annotations

import numpy as np

from ..calib import Calibration
from ..escape import visible
from ..formats.calibfile import CalibrationFile

__all__ = ["LPS", "itk_matrix", "render"]

#: RAS ↔ LPS: x and y change sign
LPS = np.diag([-1.0, -1.0, 1.0, 1.0])


def itk_matrix(Z: np.ndarray) -> np.ndarray:
    """The 4×4 the ITK file stores for Z (base ← tracker, RAS, mm): C Z⁻¹ C (LPS, base →
    tracker)."""
    return LPS @ np.linalg.inv(np.asarray(Z, dtype=float)) @ LPS


def _num(v: float) -> str:
    return repr(float(v))


def _kind(cal: Calibration) -> str:
    what = "rigid: the orthonormal Z, as every export and tmscal stream carry"
    if cal.distortion:
        return f"{what} (the tracker distortion the solver found is not corrected here)"
    return what


def render(cf: CalibrationFile) -> str:
    """The ``.tfm`` text for the orthonormal Z of ``cf`` (comment lines name frames and
    units)."""
    cal = cf.calibration
    Z = cal.exported()["Z"]
    T = itk_matrix(Z)
    params = [*T[:3, :3].ravel(), *T[:3, 3]]
    src = cf.session.get("path", "?")
    return "\n".join([
        "#Insight Transform File V1.0",
        visible(f"# tmscal {cal.method} calibration {cf.path.name} (session {src}), units mm"),
        "# Z = base_from_tracker (robot base <- NDI tracker), frames taken as RAS; stored as ITK",
        "# does: LPS, resampling direction = C Z^-1 C, C = diag(-1,-1,1). Load in 3D Slicer: the",
        "# transform node's to-parent maps tracker points into the robot base (docs/exports.md).",
        f"# {_kind(cal)}",
        "#Transform 0",
        "Transform: AffineTransform_double_3_3",
        "Parameters: " + " ".join(_num(v) for v in params),
        "FixedParameters: 0 0 0",
        "",
    ])
