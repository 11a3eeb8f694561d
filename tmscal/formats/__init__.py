"""tmscal's own file formats beside the session file (docs/exports.md, docs/kinematics.md).

- :mod:`.calibfile`: the calibration file that ``tmscal solve -o`` writes
  (``calibration_yaml``, of a :class:`tmscal.calib.Calibration` and its evaluation as plain
  types) and its reader (``read_calibration``, ``load_calibration``; also of the ``json``
  export), with the partial re-registration's file (``updated_calibration_yaml``);
- :mod:`.armfile`: a calibration's identified arm (the ``arm`` section);
- :mod:`.kinfile`: the kinematics file (of ``selfcal identify``, and inside the ``arm``
  section), which is also the tmscal arm file (docs/kinematics.md, "Arm files");
- :mod:`.urdf`: a serial arm from a URDF chain; :mod:`.armdef`: what ``--arm`` names (a
  registry name, a shipped arm file, a URDF or an arm file) and the definition a session or a
  calibration records;
- :mod:`.textfile`: what the readers share (a bounded UTF-8 file, YAML or JSON, a checked 4×4
  matrix in mm), each problem one ``CalibrationError`` naming the file and the dotted key.

The formats depend on the calibration types (:mod:`tmscal.calib`) and the session, not on the
solve service: they sit below it (docs/architecture.md), so that the service and the daily
check may read a stored calibration. The session file itself stays in :mod:`tmscal.session`
(its reader builds the ``Session`` every layer from the simulation up takes).

Frames: X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker; 4×4 mm.
"""

from __future__ import annotations

from .calibfile import CalibrationFile, calibration_yaml, load_calibration, read_calibration
from .kinfile import KinematicsFile, load_arm, read_kinematics

__all__ = ["CalibrationFile", "calibration_yaml", "load_calibration", "read_calibration",
           "KinematicsFile", "load_arm", "read_kinematics"]
