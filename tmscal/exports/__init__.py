"""Calibration files and exports for the lab's other software (docs/exports.md).

:mod:`.calibfile` writes the calibration file of ``tmscal solve -o`` and reads it (and the
``json`` export) back into a :class:`tmscal.calib.Calibration` (``load_calibration``; calib
itself does no I/O), its identified arm in the ``arm`` section of :mod:`.armfile`;
:mod:`.kinfile` is the kinematics file (the arm's kinematics, of ``selfcal identify`` and of
that section), :mod:`.textfile` what the readers share; :mod:`.check` the daily check; one
module per export format:
:mod:`.itk` (3D Slicer / ITK ``.tfm``), :mod:`.plus` (PLUS toolkit device set),
:mod:`.easy_handeye` (ROS easy_handeye / easy_handeye2), :mod:`.invesalius` (InVesalius'
robot co-registration) and :mod:`.jsonfmt` (everything, for scripts).

Frames: X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker; 4×4 mm.
"""

from __future__ import annotations

from typing import Any

from .calibfile import load_calibration, read_calibration

__all__ = ["FORMATS", "render", "load_calibration", "read_calibration"]

#: export format → (module, one line for the help text)
FORMATS = {
    "itk": ("itk", "ITK .tfm of Z for 3D Slicer (LPS, resampling direction; affine kept)"),
    "plus": ("plus", "PLUS device set: NDITracker block + CoordinateDefinitions (mm)"),
    "easy-handeye": ("easy_handeye", "ROS easy_handeye YAML, eye-on-base (m, quaternion)"),
    "invesalius": ("invesalius", "InVesalius robot co-registration .rbtf (X, Z; mm)"),
    "json": ("jsonfmt", "everything, for scripts; tmscal.exports.load_calibration reads it back"),
}


def render(fmt: str, cf: Any, **options: Any) -> str:
    """The text of export ``fmt`` (a key of :data:`FORMATS`) for a calibration file read by
    :func:`tmscal.exports.calibfile.read_calibration`."""
    import importlib

    module = importlib.import_module(f".{FORMATS[fmt][0]}", __name__)
    return module.render(cf, **options)
