"""The ``json`` export: the whole calibration for scripts (``tmscal export --format json``).

The calibration document of ``tmscal solve -o`` (format "tmscal-calibration", version 1: X, Y,
Z and Z_probe orthonormal, ``raw`` matrices, method, applied, poses, errors with their SD
over folds, outlier poses, uncertainty, distortion, covariance with its parameter names,
session path and SHA-256, provenance: versions, the session's config and devices) as JSON,
plus ``used`` (the matrices ``Calibration.errors`` applies, distortion included),
``CoilToMarker`` (marker ← coil centre, X⁻¹ · Y of the orthonormal X and Y:
``Calibration.marker_from_coil``, what a navigation system needs to show the coil from the
marker alone; null for a marker-only calibration) and ``exported`` (tmscal version, the source
file and its SHA-256). 4×4 in mm. ``tmscal.exports.load_calibration`` reads it back (and
ignores ``CoilToMarker``, which X and Y determine).
"""

from __future__ import annotations

import hashlib
import json

import numpy as np

from .. import __version__
from ..formats.calibfile import CalibrationFile
from ..session import plain

__all__ = ["render"]


def render(cf: CalibrationFile) -> str:
    """The JSON text (one object, indented)."""
    doc = dict(cf.doc)
    used = cf.calibration.used()
    doc["used"] = {k: None if v is None else np.asarray(v, dtype=float).tolist()
                   for k, v in used.items()}
    cal = cf.calibration
    doc["CoilToMarker"] = None if cal.Y is None else cal.marker_from_coil().tolist()
    frames = doc.get("frames")
    doc["frames"] = {**(frames if isinstance(frames, dict) else {}),
                     "CoilToMarker": "marker_from_coil (X⁻¹·Y)"}
    doc["exported"] = {"tmscal": __version__, "from": str(cf.path),
                       "sha256": hashlib.sha256(cf.path.read_bytes()).hexdigest()}
    return json.dumps(plain(doc), indent=1, allow_nan=False) + "\n"
