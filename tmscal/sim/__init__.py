"""The simulated rig: ground truth X, Y, Z, robot motion (optionally a serial arm with hidden
kinematic errors, ``arm``), tool geometry and noise models, and what can move on the rig after
a calibration (``changes``: the tracker, the marker, the coil, the coil's centre).

Used by ``tmscal simulate`` and served by every mock device.
"""

from .arm import ArmPair, Unreachable, make_arm
from .changes import MOVES, Change, Event, apply_changes, changed
from .rig import (
    TMS_RIG_P0,
    TOOL_8700340_MM,
    Noise,
    Settle,
    SimRig,
    Truth,
    facing_start,
    tms_rig_truth,
)
from .study import simulate

__all__ = ["ArmPair", "Unreachable", "make_arm", "MOVES", "Change", "Event", "changed",
           "apply_changes", "Noise", "Settle", "SimRig", "Truth",
           "simulate", "facing_start", "tms_rig_truth", "TMS_RIG_P0", "TOOL_8700340_MM"]
