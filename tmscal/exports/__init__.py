"""Exports of a calibration for the lab's other software (docs/exports.md), one module per
export format, each rendering a calibration file read by :mod:`tmscal.formats.calibfile`
(tmscal's own formats, re-exported here as ``load_calibration`` / ``read_calibration``):
:mod:`.itk` (3D Slicer / ITK ``.tfm``), :mod:`.plus` (PLUS toolkit device set),
:mod:`.easy_handeye` (ROS easy_handeye / easy_handeye2), :mod:`.invesalius` (InVesalius'
robot co-registration) and :mod:`.jsonfmt` (everything, for scripts).

Frames: X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker; 4×4 mm.
Which matrices leave tmscal: the orthonormal (rigid) X, Y, Z, ``Calibration.exported()``, in
every format; the raw matrices and a tracker distortion's correction only in the calibration
file itself and the ``json`` export, which describe the calibration for tmscal
(docs/exports.md).
"""

from __future__ import annotations

from typing import Any, NamedTuple

from ..errors import ConfigError
from ..formats.calibfile import load_calibration, read_calibration

__all__ = ["FORMATS", "ExportFormat", "export_format", "render", "load_calibration",
           "read_calibration"]


class ExportFormat(NamedTuple):
    """One export format: ``module`` (in :mod:`tmscal.exports`, imported when the format is
    rendered; its ``render(cf, **options) -> str``) and ``help`` (one line for the help
    text)."""

    module: str
    help: str


#: export format name → its entry, in the order the help lists them
FORMATS: dict[str, ExportFormat] = {
    "itk": ExportFormat("itk", "ITK .tfm of Z for 3D Slicer (LPS, resampling direction; "
                        "rigid)"),
    "plus": ExportFormat("plus", "PLUS device set: NDITracker block + CoordinateDefinitions "
                         "(mm)"),
    "easy-handeye": ExportFormat("easy_handeye", "ROS easy_handeye YAML, eye-on-base (m, "
                                 "quaternion)"),
    "invesalius": ExportFormat("invesalius", "InVesalius robot co-registration .rbtf (X, Z; "
                               "mm)"),
    "json": ExportFormat("jsonfmt", "everything, for scripts; tmscal.exports.load_calibration "
                         "reads it back"),
}


def export_format(name: str) -> ExportFormat:
    """The export format ``name``; an unknown name is a ConfigError listing the known ones."""
    fmt = FORMATS.get(name) if isinstance(name, str) else None
    if fmt is None:
        raise ConfigError(f"unknown export format {name!r}; known formats: "
                          f"{', '.join(FORMATS)}")
    return fmt


def render(fmt: str, cf: Any, **options: Any) -> str:
    """The text of export ``fmt`` (a name of :data:`FORMATS`; ConfigError otherwise) for a
    calibration file read by :func:`tmscal.formats.calibfile.read_calibration`."""
    import importlib

    module = importlib.import_module(f".{export_format(fmt).module}", __name__)
    return module.render(cf, **options)
