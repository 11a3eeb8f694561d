"""Calibration files and exports for the lab's other software (docs/exports.md).

:mod:`.calibfile` reads the calibration file ``tmscal solve -o`` writes (and the ``json``
export) back into a :class:`tmscal.calib.Calibration`; one module per export format:
:mod:`.itk` (3D Slicer / ITK ``.tfm``), :mod:`.plus` (PLUS toolkit device set),
:mod:`.easy_handeye` (ROS easy_handeye / easy_handeye2), :mod:`.invesalius` (InVesalius'
robot co-registration) and :mod:`.jsonfmt` (everything, for scripts).

Frames: X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker; 4×4 mm.
"""
