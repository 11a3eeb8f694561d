"""tmscal: calibration of robotized, navigated TMS rigs.

Frames (everywhere): A = base_from_flange, B = tracker_from_marker, C = tracker_from_probe,
X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker; A X = Z B, A Y = Z C.
Poses are 4×4 float64 in millimetres.
"""

__version__ = "0.1.0"
