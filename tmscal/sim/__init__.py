"""The simulated rig: ground truth X, Y, Z, robot motion, tool geometry and noise models.

Used by ``tmscal simulate`` and served by every mock device.
"""

from .rig import (
    TMS_RIG_P0,
    TOOL_8700340_MM,
    Noise,
    Settle,
    SimRig,
    Truth,
    facing_start,
    simulate,
    tms_rig_truth,
)

__all__ = ["Noise", "Settle", "SimRig", "Truth", "simulate", "facing_start", "tms_rig_truth",
           "TMS_RIG_P0", "TOOL_8700340_MM"]
